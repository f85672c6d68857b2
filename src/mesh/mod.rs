//! Meshes from rendered depth (2DGS's bounded mesh extraction, docs/algorithms/base-models.md §1.8): fuse the
//! training views' surface depth into a truncated signed distance volume ([`tsdf`]), extract
//! its zero level set ([`extract`]), drop small disconnected pieces, write a PLY that MeshLab
//! and Blender open ([`ply`]).

pub mod extract;
pub mod ply;
pub mod preview;
pub mod tsdf;

/// A triangle mesh with per-vertex colours.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct Mesh {
    pub vertices: Vec<[f32; 3]>,
    /// Linear RGB in [0, 1].
    pub colors: Vec<[f32; 3]>,
    /// Counter-clockwise seen from outside (the free-space side).
    pub triangles: Vec<[u32; 3]>,
}

impl Mesh {
    /// Keeps the connected pieces (triangles sharing a vertex) of at least `min_triangles`
    /// triangles, and of those at most the `max_pieces` largest; drops unused vertices.
    pub fn keep_large_pieces(&self, min_triangles: usize, max_pieces: usize) -> Mesh {
        let n = self.vertices.len();
        let mut parent: Vec<u32> = (0..n as u32).collect();
        fn find(p: &mut [u32], mut x: u32) -> u32 {
            while p[x as usize] != x {
                p[x as usize] = p[p[x as usize] as usize];
                x = p[x as usize];
            }
            x
        }
        for t in &self.triangles {
            let a = find(&mut parent, t[0]);
            for &v in &t[1..] {
                let b = find(&mut parent, v);
                if a != b {
                    parent[b as usize] = a;
                }
            }
        }
        let mut size = std::collections::HashMap::<u32, usize>::new();
        let roots: Vec<u32> = self
            .triangles
            .iter()
            .map(|t| find(&mut parent, t[0]))
            .collect();
        for &r in &roots {
            *size.entry(r).or_default() += 1;
        }
        let mut pieces: Vec<(u32, usize)> = size.into_iter().collect();
        pieces.sort_by(|a, b| b.1.cmp(&a.1).then(a.0.cmp(&b.0)));
        let keep: std::collections::HashSet<u32> = pieces
            .iter()
            .filter(|p| p.1 >= min_triangles)
            .take(max_pieces)
            .map(|p| p.0)
            .collect();
        let mut remap = vec![u32::MAX; n];
        let mut out = Mesh::default();
        for (t, r) in self.triangles.iter().zip(&roots) {
            if !keep.contains(r) {
                continue;
            }
            let mut tri = [0u32; 3];
            for (k, &v) in t.iter().enumerate() {
                if remap[v as usize] == u32::MAX {
                    remap[v as usize] = out.vertices.len() as u32;
                    out.vertices.push(self.vertices[v as usize]);
                    out.colors.push(self.colors[v as usize]);
                }
                tri[k] = remap[v as usize];
            }
            out.triangles.push(tri);
        }
        out
    }
}
