//! `--lpm-debug DIR`: PNGs of one LPM step, to see what it found. Per step `it`:
//! `lpm_<it>_error.png` (the error map, scaled to its maximum), `lpm_<it>_blocks.png` (kept
//! blocks in red and region boxes in yellow over V's ground truth), `lpm_<it>_pairs_view.png` and
//! `lpm_<it>_pairs_ref.png` (R_e in V and R_e' in V' in green, matched keypoints in cyan) and
//! `lpm_<it>_zones.png` (each zone's bounding sphere projected into V, magenta).

use std::path::Path;

use crate::lpm::correspondences::OrientedMatches;
use crate::lpm::gpu::LpmGpu;
use crate::lpm::pairing::{pair_regions_on, PixelBox};
use crate::lpm::regions::BlockOwners;
use crate::lpm::{BlockMask, Region, Zone};
use crate::scene::images::save_png;
use crate::scene::{Image, View};

fn dimmed(img: &Image) -> Image {
    Image {
        width: img.width,
        height: img.height,
        rgb: img.rgb.iter().map(|v| 0.6 * v).collect(),
        alpha: None,
    }
}

fn put(img: &mut Image, x: i64, y: i64, c: [f32; 3]) {
    if x >= 0 && y >= 0 && (x as u32) < img.width && (y as u32) < img.height {
        img.set_pixel(x as u32, y as u32, c);
    }
}

fn rect(img: &mut Image, b: &PixelBox, c: [f32; 3]) {
    let (x0, y0, x1, y1) = (
        b.x0.floor() as i64,
        b.y0.floor() as i64,
        b.x1.ceil() as i64 - 1,
        b.y1.ceil() as i64 - 1,
    );
    for x in x0..=x1 {
        put(img, x, y0, c);
        put(img, x, y1, c);
    }
    for y in y0..=y1 {
        put(img, x0, y, c);
        put(img, x1, y, c);
    }
}

fn region_box(r: &Region) -> PixelBox {
    PixelBox {
        x0: r.x0 as f64,
        y0: r.y0 as f64,
        x1: r.x1 as f64,
        y1: r.y1 as f64,
    }
}

fn dot(img: &mut Image, p: [f32; 2], c: [f32; 3]) {
    for dy in -1..=1 {
        for dx in -1..=1 {
            put(img, p[0] as i64 + dx, p[1] as i64 + dy, c);
        }
    }
}

#[allow(clippy::too_many_arguments)]
pub(super) fn dump_step(
    dir: &Path,
    it: u32,
    gpu: &LpmGpu,
    mask: &BlockMask,
    views: &[View],
    (gt_view, gt_reference): (Option<&Image>, Option<&Image>),
    view: usize,
    reference: Option<usize>,
    zones: &[Zone],
    regions: &[Region],
    owners: Option<&BlockOwners>,
    matches: Option<OrientedMatches>,
) -> anyhow::Result<()> {
    std::fs::create_dir_all(dir)
        .map_err(|e| anyhow::anyhow!("{}: cannot create --lpm-debug folder: {e}", dir.display()))?;
    let Some(gv) = gt_view else {
        return Ok(());
    };
    let (w, h) = (mask.width, mask.height);
    let name = |s: &str| dir.join(format!("lpm_{it:06}_{s}.png"));

    let err = gpu.error_map_buffer().read_range(0, (w * h) as usize)?;
    let max = err.iter().fold(0f32, |a, &b| a.max(b)).max(1e-12);
    let mut e = Image::new(w, h);
    for (i, v) in err.iter().enumerate() {
        let g = v / max;
        e.rgb[3 * i..3 * i + 3].copy_from_slice(&[g, g, g]);
    }
    save_png(&name("error"), &e)?;

    let mut b = dimmed(gv);
    for by in 0..mask.blocks_y {
        for bx in 0..mask.blocks_x {
            if !mask.is_kept(bx, by) {
                continue;
            }
            for y in by * mask.block..((by + 1) * mask.block).min(h) {
                for x in bx * mask.block..((bx + 1) * mask.block).min(w) {
                    let p = b.pixel(x, y);
                    b.set_pixel(x, y, [0.5 * p[0] + 0.5, 0.5 * p[1], 0.5 * p[2]]);
                }
            }
        }
    }
    for r in regions {
        rect(&mut b, &region_box(r), [1.0, 1.0, 0.0]);
    }
    save_png(&name("blocks"), &b)?;

    if let (Some(_), Some((xy_v, xy_r))) = (reference, matches) {
        let (pairs, _) = pair_regions_on(regions, owners, xy_v, xy_r);
        let mut pv = dimmed(gv);
        for p in xy_v {
            dot(&mut pv, *p, [0.0, 1.0, 1.0]);
        }
        for p in &pairs {
            rect(&mut pv, &region_box(&p.region), [1.0, 1.0, 0.0]);
            rect(&mut pv, &p.in_view, [0.0, 1.0, 0.0]);
        }
        save_png(&name("pairs_view"), &pv)?;
        if let Some(gr) = gt_reference {
            let mut pr = dimmed(gr);
            for p in xy_r {
                dot(&mut pr, *p, [0.0, 1.0, 1.0]);
            }
            for p in &pairs {
                rect(&mut pr, &p.in_reference, [0.0, 1.0, 0.0]);
            }
            save_png(&name("pairs_ref"), &pr)?;
        }
    }

    let mut z = dimmed(gv);
    let v = &views[view];
    for zone in zones {
        let s = zone.bounding_sphere();
        let pc = v.pose.transform(s.center);
        if pc[2] <= 0.0 {
            continue;
        }
        let [u, q] = v.camera.project(pc);
        let rad = v.camera.fx * s.radius / pc[2];
        let steps = ((rad * 8.0) as usize).clamp(16, 4096);
        for k in 0..steps {
            let a = std::f64::consts::TAU * k as f64 / steps as f64;
            put(
                &mut z,
                (u + rad * a.cos()) as i64,
                (q + rad * a.sin()) as i64,
                [1.0, 0.0, 1.0],
            );
        }
        dot(&mut z, [u as f32, q as f32], [1.0, 0.0, 1.0]);
    }
    save_png(&name("zones"), &z)?;
    Ok(())
}
