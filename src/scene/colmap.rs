//! COLMAP sparse models (binary and text). (Skeleton: being written.)
use super::{LoadOptions, Scene};
use std::path::{Path, PathBuf};

/// `root/sparse/0` or `root/sparse` when it holds `cameras.bin` or `cameras.txt`.
pub fn find_sparse_dir(root: &Path) -> Option<PathBuf> {
    [root.join("sparse").join("0"), root.join("sparse")]
        .into_iter()
        .find(|d| d.join("cameras.bin").exists() || d.join("cameras.txt").exists())
}

pub fn load_scene(_root: &Path, _sparse: &Path, _opts: &LoadOptions) -> anyhow::Result<Scene> {
    anyhow::bail!("COLMAP loading is not written yet")
}
