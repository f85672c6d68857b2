//! Training data: every view's camera and the order views are visited in (the ground-truth
//! images are in `image_cache`).

use anyhow::ensure;
use rand::seq::SliceRandom;
use rand::SeedableRng;

use crate::render::layout::CameraGpu;
use crate::scene::Scene;

/// All views' cameras, in scene order.
pub fn scene_cameras(scene: &Scene) -> Vec<CameraGpu> {
    scene
        .views
        .iter()
        .map(|v| CameraGpu::new(&v.camera, &v.pose))
        .collect()
}

/// Visits the training views in a fresh random order each epoch (without replacement), as the
/// reference does; deterministic for a seed, and its position can be saved and restored.
#[derive(Debug, Clone)]
pub struct ViewSchedule {
    views: Vec<usize>,
    seed: u64,
    epoch: u64,
    order: Vec<usize>,
    next: usize,
}

impl ViewSchedule {
    pub fn new(views: Vec<usize>, seed: u64) -> anyhow::Result<Self> {
        ensure!(
            !views.is_empty(),
            "the scene has no training views. Fix: check the split (a scene needs at least one \
             training image)"
        );
        let mut s = Self {
            views,
            seed,
            epoch: 0,
            order: Vec::new(),
            next: 0,
        };
        s.shuffle();
        Ok(s)
    }

    fn shuffle(&mut self) {
        let mut rng = rand_pcg::Pcg64::seed_from_u64(
            self.seed ^ self.epoch.wrapping_mul(0x9E37_79B9_7F4A_7C15),
        );
        self.order = self.views.clone();
        self.order.shuffle(&mut rng);
        self.next = 0;
    }

    /// The next view (an index into `scene.views`).
    pub fn next_view(&mut self) -> usize {
        if self.next == self.order.len() {
            self.epoch += 1;
            self.shuffle();
        }
        self.next += 1;
        self.order[self.next - 1]
    }

    /// (epoch, position in the epoch): enough to restore the schedule exactly.
    pub fn position(&self) -> (u64, usize) {
        (self.epoch, self.next)
    }

    pub fn restore(&mut self, epoch: u64, next: usize) {
        self.epoch = epoch;
        self.shuffle();
        self.next = next.min(self.order.len());
    }
}
