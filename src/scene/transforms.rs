//! transforms.json scenes (NeRF-synthetic and nerfstudio forms). (Skeleton: being written.)
use super::{LoadOptions, Scene};
use std::path::Path;

pub fn load_scene(_root: &Path, _opts: &LoadOptions) -> anyhow::Result<Scene> {
    anyhow::bail!("transforms.json loading is not written yet")
}
