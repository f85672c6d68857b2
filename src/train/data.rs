//! Training data on the GPU: every view's camera in one buffer, the ground-truth images packed
//! as RGBA8 (one u32 a pixel, r in the low byte) in as few buffers as the device's binding limit
//! allows, and the order views are visited in.
//!
//! Images are stored at 8 bits a channel: the sources are 8-bit files, and the area-filtered
//! downscale is rounded back to 8 bits (at most half a level, 0.002, of error) to keep a
//! 100-view NeRF-synthetic scene in a few tens of MiB.

use std::sync::Arc;

use anyhow::ensure;
use rand::seq::SliceRandom;
use rand::SeedableRng;

use crate::gpu::{BufferKind, GpuBuffer, GpuContext};
use crate::render::layout::CameraGpu;
use crate::scene::{Image, Scene};

/// Where one image lives: buffer index and first pixel.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct ImageSlot {
    pub buffer: usize,
    pub offset_px: u32,
    pub width: u32,
    pub height: u32,
}

/// Packs an image as RGBA8 (alpha 255 when the image has none).
pub fn pack_rgba8(img: &Image) -> Vec<u32> {
    let q = |v: f32| (v.clamp(0.0, 1.0) * 255.0).round() as u32;
    (0..img.len())
        .map(|i| {
            let a = img.alpha.as_ref().map_or(255, |a| q(a[i]));
            q(img.rgb[3 * i])
                | (q(img.rgb[3 * i + 1]) << 8)
                | (q(img.rgb[3 * i + 2]) << 16)
                | (a << 24)
        })
        .collect()
}

/// Ground-truth images on the GPU.
pub struct GpuImages {
    pub buffers: Vec<GpuBuffer<u32>>,
    pub slots: Vec<ImageSlot>,
}

impl GpuImages {
    /// Uploads `images`, filling each buffer up to the device's binding limit.
    pub fn upload(ctx: &Arc<GpuContext>, images: &[Image]) -> anyhow::Result<Self> {
        let limit_px = (ctx.info.max_storage_buffer_range / 4).min(u32::MAX as u64) as usize;
        let mut groups: Vec<Vec<usize>> = vec![Vec::new()];
        let mut used = 0usize;
        for (i, img) in images.iter().enumerate() {
            let n = img.len();
            ensure!(
                n <= limit_px,
                "image {i} ({}×{}) alone exceeds the device's {} MiB storage binding limit. \
                 Fix: train at a lower resolution (-r 2, 4 or 8)",
                img.width,
                img.height,
                ctx.info.max_storage_buffer_range >> 20
            );
            if used + n > limit_px {
                groups.push(Vec::new());
                used = 0;
            }
            groups.last_mut().unwrap().push(i);
            used += n;
        }
        let mut slots = vec![
            ImageSlot {
                buffer: 0,
                offset_px: 0,
                width: 0,
                height: 0
            };
            images.len()
        ];
        let mut buffers = Vec::new();
        for (b, group) in groups.iter().enumerate() {
            let mut data = Vec::new();
            for &i in group {
                slots[i] = ImageSlot {
                    buffer: b,
                    offset_px: data.len() as u32,
                    width: images[i].width,
                    height: images[i].height,
                };
                data.extend(pack_rgba8(&images[i]));
            }
            let buf = GpuBuffer::new(
                ctx,
                "ground truth",
                data.len().max(1),
                BufferKind::DeviceLocal,
            )?;
            if !data.is_empty() {
                buf.upload(&data)?;
            }
            buffers.push(buf);
        }
        Ok(Self { buffers, slots })
    }
}

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
