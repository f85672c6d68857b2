//! `--image-cache`: how much GPU memory the training images may take (shared by `train` and
//! `bench trade`; the cache itself is [`TrainImages::within_cache`]).

use clap::Args;
use lpmsplat::scene::image_source::TrainImages;
use lpmsplat::scene::Scene;

#[derive(Args, Debug, Clone)]
pub struct ImageCacheArgs {
    /// GPU memory for the training images, in MiB (8 bits a channel, 4 bytes a pixel). When
    /// they all fit they are uploaded once; when they do not (long videos, full-resolution
    /// multi-view video) they are read from disk as training reaches them, a loader thread
    /// decoding the next steps' frames ahead, and GPU and host memory stay within this budget
    /// whatever the number of frames.
    #[arg(long, value_name = "MIB", default_value_t = 2048.0)]
    pub image_cache: f64,
}

impl ImageCacheArgs {
    /// The scene's training images, read from their files within the budget.
    pub fn train_images(&self, scene: &Scene) -> anyhow::Result<TrainImages> {
        TrainImages::within_cache(scene, self.image_cache)
    }
}
