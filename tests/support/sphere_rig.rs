//! The cameras of the constructed sphere scenes (`tests/train/mesh_tsdf.rs`, `tests/train/mesh_2dgs.rs`):
//! every part of a sphere at the origin is seen by several of them.

use lpmsplat::reference::scenes::look_at;
use lpmsplat::scene::Pose;

/// Twelve cameras on a ring at distance ~3.2 (alternately above and below the equator) and one
/// above and one below, all looking at the centre.
pub fn ring_poses() -> Vec<Pose> {
    let mut poses = Vec::new();
    for k in 0..12 {
        let a = k as f64 * std::f64::consts::TAU / 12.0;
        let h = if k % 2 == 0 { 1.2 } else { -1.0 };
        poses.push(look_at(
            [3.0 * a.cos(), h, 3.0 * a.sin()],
            [0.0; 3],
            [0.0, -1.0, 0.0],
        ));
    }
    poses.push(look_at([0.1, 3.2, 0.0], [0.0; 3], [1.0, 0.0, 0.0]));
    poses.push(look_at([0.1, -3.2, 0.0], [0.0; 3], [1.0, 0.0, 0.0]));
    poses
}

/// Whether a triangle mesh is closed: every edge shared by exactly two triangles (no border,
/// no non-manifold edge).
pub fn is_closed(triangles: &[[u32; 3]]) -> bool {
    let mut edges = std::collections::HashMap::<(u32, u32), u32>::new();
    for t in triangles {
        for k in 0..3 {
            let (a, b) = (t[k], t[(k + 1) % 3]);
            *edges.entry((a.min(b), a.max(b))).or_default() += 1;
        }
    }
    edges.values().all(|&n| n == 2)
}
