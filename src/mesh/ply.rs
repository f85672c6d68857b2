//! Binary little-endian PLY of a [`Mesh`]: vertices (float x, y, z; uchar red, green, blue)
//! and faces (uchar count, int indices), the layout MeshLab, Blender and Open3D read.

use std::path::Path;

use anyhow::Context;

use super::Mesh;

/// Writes `mesh` with `comments` as extra header comment lines (one line each), atomically.
pub fn write_mesh_ply(path: &Path, mesh: &Mesh, comments: &[String]) -> anyhow::Result<()> {
    anyhow::ensure!(
        comments.iter().all(|c| !c.contains(['\n', '\r'])),
        "{}: a PLY comment must be one line",
        path.display()
    );
    let extra: String = comments.iter().map(|c| format!("comment {c}\n")).collect();
    let mut bytes = format!(
        "ply\nformat binary_little_endian 1.0\ncomment lpmsplat 2DGS TSDF mesh\n{extra}\
         element vertex {}\nproperty float x\nproperty float y\nproperty float z\n\
         property uchar red\nproperty uchar green\nproperty uchar blue\n\
         element face {}\nproperty list uchar int vertex_indices\nend_header\n",
        mesh.vertices.len(),
        mesh.triangles.len()
    )
    .into_bytes();
    for (p, c) in mesh.vertices.iter().zip(&mesh.colors) {
        for v in p {
            bytes.extend_from_slice(&v.to_le_bytes());
        }
        bytes.extend(c.map(|v| (v.clamp(0.0, 1.0) * 255.0).round() as u8));
    }
    for t in &mesh.triangles {
        bytes.push(3);
        for &v in t {
            bytes.extend_from_slice(&(v as i32).to_le_bytes());
        }
    }
    crate::error::write_atomic(path, |f| {
        use std::io::Write;
        Ok(f.write_all(&bytes)?)
    })
    .with_context(|| format!("{}: writing the mesh failed", path.display()))
}
