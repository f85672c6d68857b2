//! Where a set of images comes from: decoded on demand from the scene's files ([`ViewImages`]),
//! or already in memory (a `Vec<Image>`). Training reads its ground truth through this so that a
//! video of thousands of frames never has to sit in memory whole: the trainer's image cache
//! (`train::image_cache`) asks for the frames it is about to use.

use std::sync::Arc;

use anyhow::Context;
use rayon::prelude::*;

use super::images::{load_view_image, Image};
use super::{Scene, View};

/// A numbered set of images, readable from several threads.
pub trait ImageSource: Send + Sync {
    /// How many images the set holds.
    fn count(&self) -> usize;
    /// Width and height of image `k`, known without decoding it.
    fn size(&self, k: usize) -> (u32, u32);
    /// Image `k` (decoded, undistorted and resized for a file-backed source).
    fn load(&self, k: usize) -> anyhow::Result<Image>;
    /// A name for image `k` in messages.
    fn name(&self, k: usize) -> String {
        format!("image {k}")
    }
}

/// The images of some of a scene's views, read from their files each time they are asked for.
#[derive(Debug, Clone)]
pub struct ViewImages {
    views: Vec<View>,
}

impl ViewImages {
    /// The images of `scene.views[i]` for each `i` in `indices`, in that order.
    pub fn new(scene: &Scene, indices: &[usize]) -> anyhow::Result<Self> {
        if let Some(&bad) = indices.iter().find(|&&i| i >= scene.views.len()) {
            anyhow::bail!(
                "view index {bad} is out of range: the scene has {} views",
                scene.views.len()
            );
        }
        Ok(Self {
            views: indices.iter().map(|&i| scene.views[i].clone()).collect(),
        })
    }
}

impl ImageSource for ViewImages {
    fn count(&self) -> usize {
        self.views.len()
    }
    fn size(&self, k: usize) -> (u32, u32) {
        let c = &self.views[k].camera;
        (c.width, c.height)
    }
    fn load(&self, k: usize) -> anyhow::Result<Image> {
        let v = &self.views[k];
        load_view_image(v).with_context(|| format!("loading view {}", v.name))
    }
    fn name(&self, k: usize) -> String {
        self.views[k].name.clone()
    }
}

impl ImageSource for Vec<Image> {
    fn count(&self) -> usize {
        self.len()
    }
    fn size(&self, k: usize) -> (u32, u32) {
        (self[k].width, self[k].height)
    }
    fn load(&self, k: usize) -> anyhow::Result<Image> {
        Ok(self[k].clone())
    }
}

/// Images `range` of `source`, loaded in parallel, in order.
pub fn load_range(
    source: &dyn ImageSource,
    range: std::ops::Range<usize>,
) -> anyhow::Result<Vec<Image>> {
    range.into_par_iter().map(|k| source.load(k)).collect()
}

/// The training images given to the trainer (and to a density strategy that reads them): a
/// shared source and how many bytes of GPU memory their cache may hold.
#[derive(Clone)]
pub struct TrainImages {
    pub source: Arc<dyn ImageSource>,
    /// GPU bytes the cache may use (`None`: every image stays resident, whatever the size).
    pub cache_bytes: Option<u64>,
}

impl TrainImages {
    /// Images read from the scene's files as training needs them, within `cache_bytes`.
    pub fn streamed(source: Arc<dyn ImageSource>, cache_bytes: u64) -> Self {
        Self {
            source,
            cache_bytes: Some(cache_bytes),
        }
    }

    /// `scene`'s training images, read from their files within a cache of `cache_mib` MiB of
    /// GPU memory (`--image-cache`, shared by `train` and the `bench trade` harness).
    pub fn within_cache(scene: &Scene, cache_mib: f64) -> anyhow::Result<Self> {
        anyhow::ensure!(
            cache_mib.is_finite() && cache_mib > 0.0,
            "--image-cache {}: the cache must hold at least one step's images. Fix: pass a size \
             in MiB, e.g. --image-cache 512",
            cache_mib
        );
        Ok(Self::streamed(
            Arc::new(ViewImages::new(scene, &scene.train)?),
            (cache_mib * (1u64 << 20) as f64) as u64,
        ))
    }
}

impl From<&Vec<Image>> for TrainImages {
    /// Images already in memory (copied), all resident on the GPU.
    fn from(images: &Vec<Image>) -> Self {
        Self {
            source: Arc::new(images.clone()),
            cache_bytes: None,
        }
    }
}

impl From<&[Image]> for TrainImages {
    fn from(images: &[Image]) -> Self {
        Self::from(&images.to_vec())
    }
}
