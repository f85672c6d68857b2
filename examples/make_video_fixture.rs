//! Writes the tiny multi-view video the tests train on, in the Neural 3D Video layout
//! (`poses_bounds.npy` + `camNN/<frame>.png`): five forward-facing cameras filming eight frames
//! of a known SpacetimeGaussians scene (a still backdrop and coloured blobs that move, spin,
//! appear and fade), rendered by the f64 reference at each frame's time.
//!
//! `cargo run --release --example make_video_fixture -- tests/data/n3v_tiny`

use std::path::PathBuf;

use clap::Parser;
use lpmsplat::reference::spacetime::{instant, Temporal};
use lpmsplat::reference::{render, RefGaussians, RenderSettings};
use lpmsplat::scene::images::save_png;
use lpmsplat::scene::video::npy;
use lpmsplat::scene::{Image, PinholeCamera, Pose};
use rand::{Rng, SeedableRng};

#[derive(Parser)]
struct Args {
    /// Output folder (created if missing).
    out: PathBuf,
    #[arg(long, default_value_t = 64)]
    width: u32,
    #[arg(long, default_value_t = 48)]
    height: u32,
    #[arg(long, default_value_t = 8)]
    frames: usize,
}

/// World-to-camera pose of a camera at `eye` looking at `target` (y down in the image).
fn look_at(eye: [f64; 3], target: [f64; 3]) -> Pose {
    let sub = |a: [f64; 3], b: [f64; 3]| [a[0] - b[0], a[1] - b[1], a[2] - b[2]];
    let norm = |v: [f64; 3]| {
        let l = (v[0] * v[0] + v[1] * v[1] + v[2] * v[2]).sqrt();
        v.map(|x| x / l)
    };
    let cross = |a: [f64; 3], b: [f64; 3]| {
        [
            a[1] * b[2] - a[2] * b[1],
            a[2] * b[0] - a[0] * b[2],
            a[0] * b[1] - a[1] * b[0],
        ]
    };
    let z = norm(sub(target, eye));
    let x = norm(cross([0.0, 1.0, 0.0], z));
    let y = cross(z, x);
    let rotation = [x, y, z];
    let translation = [0, 1, 2].map(|r| -(0..3).map(|c| rotation[r][c] * eye[c]).sum::<f64>());
    Pose {
        rotation,
        translation,
    }
}

fn main() -> anyhow::Result<()> {
    let args = Args::parse();
    let mut rng = rand_pcg::Pcg64::seed_from_u64(0x0F1D);
    let (w, h) = (args.width, args.height);
    let focal = 2.0 * w as f64;
    let eyes = [
        [0.0, 0.0, -4.0],
        [-0.8, -0.2, -4.0],
        [0.8, -0.2, -4.0],
        [-0.5, 0.3, -3.8],
        [0.5, 0.3, -3.8],
    ];
    let poses: Vec<Pose> = eyes.iter().map(|&e| look_at(e, [0.0, 0.0, 0.5])).collect();
    // The scene: a backdrop of still, long-lived Gaussians and moving blobs.
    let mut model: Vec<(Temporal, [f64; 3], [f64; 3])> = Vec::new();
    for gx in 0..9 {
        for gy in 0..7 {
            let p = [-0.8 + 0.2 * gx as f64, -0.6 + 0.2 * gy as f64, 0.9];
            let c = [
                0.3 + 0.4 * (gx as f64 / 8.0),
                0.25 + 0.2 * rng.gen::<f64>(),
                0.6 - 0.4 * (gy as f64 / 6.0),
            ];
            model.push((still(p), c, [-2.0, -2.0, -3.0]));
        }
    }
    for _ in 0..20 {
        let mut t = still([
            rng.gen_range(-0.5..0.5),
            rng.gen_range(-0.4..0.4),
            rng.gen_range(0.0..0.6),
        ]);
        for k in 0..3 {
            t.motion[k] = rng.gen_range(-0.8..0.8);
        }
        t.omega = [0.0, rng.gen_range(-2.0..2.0), 0.0, rng.gen_range(-2.0..2.0)];
        t.t_center = rng.gen_range(0.0..1.0);
        t.t_log_scale = rng.gen_range(-1.2..0.3);
        t.opacity_logit = 3.0;
        let c = [0; 3].map(|_| rng.gen_range(0.1..1.0));
        let l = [rng.gen_range(-2.8..-2.2), -2.7, rng.gen_range(-2.8..-2.2)];
        model.push((t, c, l));
    }
    let camera = PinholeCamera {
        fx: focal,
        fy: focal,
        cx: w as f64 / 2.0,
        cy: h as f64 / 2.0,
        width: w,
        height: h,
    };
    std::fs::create_dir_all(&args.out)?;
    for f in 0..args.frames {
        let time = f as f64 / args.frames as f64;
        let g = still_model(&model, time);
        for (c, pose) in poses.iter().enumerate() {
            let out = render(&g, &camera, pose, 0, [0.0; 3], &RenderSettings::default())?;
            let mut img = Image::new(w, h);
            for (i, px) in out.raster.image.iter().enumerate() {
                img.set_pixel(i as u32 % w, i as u32 / w, px.map(|v| v as f32));
            }
            let path = args.out.join(format!("cam{c:02}/{f}.png"));
            std::fs::create_dir_all(path.parent().unwrap())?;
            save_png(&path, &img)?;
        }
    }
    // LLFF rows: camera-to-world [down | right | back | centre | (h, w, focal)], then bounds.
    let mut rows = Vec::new();
    for pose in &poses {
        let r = pose.rotation; // rows: camera x, y, z axes in world coordinates
        let centre = pose.center();
        for k in 0..3 {
            rows.extend([r[1][k], r[0][k], -r[2][k], centre[k], [h, w, 0][k] as f64]);
        }
        let n = rows.len();
        rows[n - 1] = focal;
        rows.extend([1.0, 8.0]);
    }
    npy::write_array2(&args.out.join("poses_bounds.npy"), poses.len(), 17, &rows)?;
    eprintln!(
        "{}: {} cameras × {} frames at {w}×{h}, {} Gaussians",
        args.out.display(),
        poses.len(),
        args.frames,
        model.len()
    );
    Ok(())
}

/// A Gaussian that neither moves nor fades.
fn still(position: [f64; 3]) -> Temporal {
    Temporal {
        position,
        motion: [0.0; 9],
        rotation: [1.0, 0.0, 0.0, 0.0],
        omega: [0.0; 4],
        opacity_logit: 4.0,
        t_center: 0.5,
        t_log_scale: 3.0,
    }
}

/// The model at `time` as still reference Gaussians (SH degree 0 from linear colour).
fn still_model(model: &[(Temporal, [f64; 3], [f64; 3])], time: f64) -> RefGaussians {
    const C0: f64 = 0.282_094_791_773_878_14;
    let mut g = RefGaussians {
        positions: Vec::new(),
        log_scales: Vec::new(),
        rotations: Vec::new(),
        opacity_logits: Vec::new(),
        sh: Vec::new(),
    };
    for (t, colour, log_scale) in model {
        let i = instant(t, time);
        g.positions.push(i.position);
        g.rotations.push(i.rotation);
        g.opacity_logits.push(i.opacity_logit);
        g.log_scales.push(*log_scale);
        let mut sh = [[0.0; 3]; 16];
        sh[0] = colour.map(|c| (c - 0.5) / C0);
        g.sh.push(sh);
    }
    g
}
