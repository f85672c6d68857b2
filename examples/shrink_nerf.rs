//! Makes a small copy of a NeRF-synthetic scene: a few spread-out train and val views, images
//! area-averaged down to a square size, the same `camera_angle_x` and matrices.
//!
//! `cargo run --example shrink_nerf -- ../shared/data/lego tests/data/lego_small --train 8 --val 3 --size 100`

use anyhow::Context;
use clap::Parser;
use lpmsplat::error::{bad_input, write_atomic};
use lpmsplat::scene::images::{decode_image, resize_area, save_png};
use lpmsplat::scene::transforms::read_json;
use std::path::{Path, PathBuf};

#[derive(Parser)]
struct Args {
    /// The NeRF-synthetic scene folder (with transforms_train.json and transforms_val.json).
    src: PathBuf,
    /// Where to write the small copy (created if missing).
    dst: PathBuf,
    #[arg(long, default_value_t = 8)]
    train: usize,
    #[arg(long, default_value_t = 3)]
    val: usize,
    /// Width and height of the output images in pixels.
    #[arg(long, default_value_t = 100)]
    size: u32,
}

fn main() -> anyhow::Result<()> {
    let args = Args::parse();
    for (split, count) in [("train", args.train), ("val", args.val)] {
        shrink_split(&args, split, count)?;
    }
    Ok(())
}

fn shrink_split(args: &Args, split: &str, count: usize) -> anyhow::Result<()> {
    let name = format!("transforms_{split}.json");
    let src_json = args.src.join(&name);
    let mut json = read_json(&src_json)?;
    let frames = match json.get("frames").and_then(|f| f.as_array()) {
        Some(f) if f.len() >= count && count > 0 => f.clone(),
        _ => {
            return bad_input(
                &src_json,
                "frames",
                format!("fewer than {count} frames"),
                "ask for fewer views",
            )
        }
    };
    // Evenly spread over the file's order, which for NeRF-synthetic walks around the object.
    let picked: Vec<serde_json::Value> = (0..count)
        .map(|k| frames[k * frames.len() / count].clone())
        .collect();
    for (k, frame) in picked.iter().enumerate() {
        let Some(file_path) = frame.get("file_path").and_then(|p| p.as_str()) else {
            return bad_input(
                &src_json,
                format!("frames[{k}].file_path"),
                "missing",
                "add it",
            );
        };
        let rel = if Path::new(file_path).extension().is_some() {
            file_path.to_string()
        } else {
            format!("{file_path}.png")
        };
        let img = decode_image(&args.src.join(&rel))?;
        let small = resize_area(&img, args.size, args.size);
        let out = args.dst.join(&rel);
        std::fs::create_dir_all(out.parent().unwrap_or(&args.dst))
            .with_context(|| format!("{}: cannot create the folder", out.display()))?;
        save_png(&out, &small)?;
        println!("{} -> {}", rel, out.display());
    }
    json["frames"] = serde_json::Value::Array(picked);
    let text = serde_json::to_string_pretty(&json)?;
    write_atomic(&args.dst.join(&name), |f| {
        use std::io::Write;
        Ok(f.write_all(text.as_bytes())?)
    })
}
