//! The zero level set of a [`Tsdf`] by marching tetrahedra: every cell between eight voxel
//! centres is cut into six tetrahedra around its main diagonal (the Kuhn decomposition, whose
//! face diagonals agree between neighbouring cells, so the surface has no cracks); a tetrahedron
//! whose four corners were all observed and whose values change sign gives one triangle (one
//! corner apart) or two (two and two), with vertices interpolated linearly on the edges and
//! shared between the cells that cut the same edge. Tetrahedra need no case tables, at the
//! price of about twice marching cubes' triangles. Triangles face the free space (positive
//! values).

use std::collections::HashMap;

use rayon::prelude::*;

use super::tsdf::Tsdf;
use super::Mesh;

/// Corners of a cell as (dx, dy, dz) bits: corner c is (c & 1, (c >> 1) & 1, (c >> 2) & 1).
const TETRAHEDRA: [[usize; 4]; 6] = [
    [0, 1, 3, 7],
    [0, 3, 2, 7],
    [0, 2, 6, 7],
    [0, 6, 4, 7],
    [0, 4, 5, 7],
    [0, 5, 1, 7],
];

/// A triangle whose vertices are still edges (pairs of voxel indices).
type EdgeTriangle = [(usize, usize); 3];

/// Extracts the surface where the fused value crosses 0.
pub fn extract(v: &Tsdf) -> Mesh {
    let [nx, ny, nz] = v.dims;
    if nx < 2 || ny < 2 || nz < 2 {
        return Mesh::default();
    }
    let slabs: Vec<Vec<EdgeTriangle>> = (0..nz - 1)
        .into_par_iter()
        .map(|k| {
            let mut out = Vec::new();
            for j in 0..ny - 1 {
                for i in 0..nx - 1 {
                    cell(v, i, j, k, &mut out);
                }
            }
            out
        })
        .collect();
    let mut mesh = Mesh::default();
    let mut ids: HashMap<(usize, usize), u32> = HashMap::new();
    for tri in slabs.into_iter().flatten() {
        let mut t = [0u32; 3];
        for (k, &(a, b)) in tri.iter().enumerate() {
            t[k] = *ids.entry((a, b)).or_insert_with(|| {
                let (pa, pb) = (position(v, a), position(v, b));
                let (va, vb) = (v.tsdf[a] as f64, v.tsdf[b] as f64);
                let s = va / (va - vb);
                mesh.vertices
                    .push([0, 1, 2].map(|c| (pa[c] + s * (pb[c] - pa[c])) as f32));
                let (ca, cb) = (v.color[a], v.color[b]);
                mesh.colors
                    .push([0, 1, 2].map(|c| ca[c] + s as f32 * (cb[c] - ca[c])));
                (mesh.vertices.len() - 1) as u32
            });
        }
        // Edges shared by the three vertices can collapse onto one point: skip degenerate ones.
        if t[0] != t[1] && t[1] != t[2] && t[0] != t[2] {
            mesh.triangles.push(t);
        }
    }
    mesh
}

fn position(v: &Tsdf, index: usize) -> [f64; 3] {
    let [nx, ny, _] = v.dims;
    let (i, j, k) = (index % nx, (index / nx) % ny, index / (nx * ny));
    v.center(i, j, k)
}

fn cell(v: &Tsdf, i: usize, j: usize, k: usize, out: &mut Vec<EdgeTriangle>) {
    let corner = |c: usize| v.index(i + (c & 1), j + ((c >> 1) & 1), k + ((c >> 2) & 1));
    let idx: [usize; 8] = std::array::from_fn(corner);
    if idx.iter().any(|&q| v.weight[q] <= 0.0) {
        return;
    }
    let inside = idx.map(|q| v.tsdf[q] < 0.0);
    if inside.iter().all(|&b| b) || inside.iter().all(|&b| !b) {
        return;
    }
    for tet in TETRAHEDRA {
        let q = tet.map(|c| idx[c]);
        let (ins, outs): (Vec<usize>, Vec<usize>) = q.iter().partition(|&&g| v.tsdf[g] < 0.0);
        let edge = |a: usize, b: usize| if a < b { (a, b) } else { (b, a) };
        let tris: Vec<EdgeTriangle> = match (ins.len(), outs.len()) {
            (1, 3) => vec![[
                edge(ins[0], outs[0]),
                edge(ins[0], outs[1]),
                edge(ins[0], outs[2]),
            ]],
            (3, 1) => vec![[
                edge(outs[0], ins[0]),
                edge(outs[0], ins[1]),
                edge(outs[0], ins[2]),
            ]],
            (2, 2) => {
                // The quad a0-b0, a0-b1, a1-b1, a1-b0 (in that cyclic order).
                let (a, b) = ((ins[0], ins[1]), (outs[0], outs[1]));
                let e = [
                    edge(a.0, b.0),
                    edge(a.0, b.1),
                    edge(a.1, b.1),
                    edge(a.1, b.0),
                ];
                vec![[e[0], e[1], e[2]], [e[0], e[2], e[3]]]
            }
            _ => Vec::new(),
        };
        // Orient each triangle towards the outside corners.
        let centroid = |set: &[usize]| {
            let mut c = [0.0; 3];
            for &g in set {
                let p = position(v, g);
                for a in 0..3 {
                    c[a] += p[a] / set.len() as f64;
                }
            }
            c
        };
        let (ci, co) = (centroid(&ins), centroid(&outs));
        let g = [co[0] - ci[0], co[1] - ci[1], co[2] - ci[2]];
        for mut t in tris {
            let p: Vec<[f64; 3]> = t
                .iter()
                .map(|&(a, b)| {
                    let (pa, pb) = (position(v, a), position(v, b));
                    [0, 1, 2].map(|c| 0.5 * (pa[c] + pb[c]))
                })
                .collect();
            let (u, w) = (
                [0, 1, 2].map(|c| p[1][c] - p[0][c]),
                [0, 1, 2].map(|c| p[2][c] - p[0][c]),
            );
            let n = [
                u[1] * w[2] - u[2] * w[1],
                u[2] * w[0] - u[0] * w[2],
                u[0] * w[1] - u[1] * w[0],
            ];
            if n[0] * g[0] + n[1] * g[1] + n[2] * g[2] < 0.0 {
                t.swap(1, 2);
            }
            out.push(t);
        }
    }
}
