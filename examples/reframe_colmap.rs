//! Writes a COLMAP scene in another world frame: the same images and reconstruction with the
//! world scaled, rotated and moved (`x' = scale · rotate(x) + offset`), as a georeferenced or
//! survey-unit export of it would be. Images are linked, not copied.
//!
//! `cargo run --release --example reframe_colmap -- <src_scene> <dst_scene> <scale> <ox> <oy> <oz> [<qw> <qx> <qy> <qz>]`
//!
//! e.g. `... tests/data/lund_door_small /tmp/door_utm 1 510000 4000000 124` (UTM-like), or
//! `... 0.001 0 0 0` (kilometres). The model is written in text form (lossless).

use std::path::{Path, PathBuf};

use anyhow::Context;
use lpmsplat::scene::colmap;

fn main() -> anyhow::Result<()> {
    let a: Vec<String> = std::env::args().skip(1).collect();
    anyhow::ensure!(
        a.len() == 6 || a.len() == 10,
        "usage: reframe_colmap SRC DST SCALE OX OY OZ [QW QX QY QZ]"
    );
    let num = |i: usize| -> anyhow::Result<f64> {
        a[i].parse()
            .with_context(|| format!("argument {}: '{}' is not a number", i + 1, a[i]))
    };
    let (src, dst) = (PathBuf::from(&a[0]), PathBuf::from(&a[1]));
    let scale = num(2)?;
    let offset = [num(3)?, num(4)?, num(5)?];
    let rotation = if a.len() == 10 {
        [num(6)?, num(7)?, num(8)?, num(9)?]
    } else {
        [1.0, 0.0, 0.0, 0.0]
    };
    let sparse = colmap::find_sparse_dir(&src)
        .with_context(|| format!("{}: no COLMAP model (sparse/0 or sparse/)", src.display()))?;
    let binary = colmap::use_binary(&sparse, Default::default());
    let model = colmap::read_model(&sparse, binary)?.reframed(scale, rotation, offset);
    colmap::write_text(&dst.join("sparse").join("0"), &model)?;
    link_images(&src.join("images"), &dst.join("images"))?;
    println!(
        "{}: {} images, {} points",
        dst.display(),
        model.images.len(),
        model.points.len()
    );
    Ok(())
}

fn link_images(src: &Path, dst: &Path) -> anyhow::Result<()> {
    if dst.exists() {
        return Ok(());
    }
    let src = src
        .canonicalize()
        .with_context(|| format!("{}", src.display()))?;
    std::os::unix::fs::symlink(&src, dst).with_context(|| format!("linking {}", dst.display()))
}
