//! The ground-truth images on the GPU, packed as RGBA8 (one u32 a pixel, r in the low byte), in
//! as few buffers as the device's binding limit allows.
//!
//! Images are stored at 8 bits a channel: the sources are 8-bit files, and the area-filtered
//! downscale is rounded back to 8 bits (at most half a level, 0.002, of error) to keep a
//! 100-view NeRF-synthetic scene in a few tens of MiB.
//!
//! When every training image fits the cache's budget they are all uploaded once, as they always
//! were. When they do not (a video: 31 cameras × 300 frames is thousands of images), the cache
//! holds a fixed number of slots of the largest image's size and streams: before each step the
//! trainer names the images the step reads (made resident, the least recently used slot giving
//! way, copied from a host-visible staging buffer inside the step's own command buffer) and the
//! images of the next steps, which a loader thread decodes while the GPU works. GPU memory is
//! the budget; host memory is the staging buffer (two steps' images) and the few decoded
//! frames waiting for their step, whatever the number of frames.

use std::collections::{HashMap, HashSet};
use std::sync::mpsc::{channel, Receiver, Sender};
use std::sync::Arc;
use std::thread::JoinHandle;
use std::time::Instant;

use anyhow::{ensure, Context};

use crate::gpu::{BufferKind, GpuBuffer, GpuContext, Recorder};
use crate::scene::image_source::{load_range, ImageSource, TrainImages};
use crate::scene::Image;

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

/// What the cache did so far (the trainer's summary and the tests read it).
#[derive(Debug, Clone, Copy, Default, PartialEq, serde::Serialize)]
pub struct CacheStats {
    /// Images in the set.
    pub images: usize,
    /// Slots on the GPU (= `images` when all are resident).
    pub slots: usize,
    /// GPU bytes the slots take.
    pub bytes: u64,
    /// Every image uploaded once at the start (no streaming).
    pub resident: bool,
    /// Images copied into a slot during training.
    pub uploads: u64,
    /// Of those, how many were not decoded ahead and made the step wait.
    pub waited: u64,
    /// Host seconds steps spent waiting for images to be decoded.
    pub wait_seconds: f64,
}

impl CacheStats {
    /// One line for the console: how the images are held.
    pub fn describe(&self) -> String {
        let mib = self.bytes as f64 / (1u64 << 20) as f64;
        if self.resident {
            format!("all {} resident ({mib:.1} MiB)", self.images)
        } else {
            format!(
                "streamed from disk, {} slots for {} images ({mib:.1} MiB)",
                self.slots, self.images
            )
        }
    }
}

/// Images decoded at most this many at a time while filling a resident cache, so that the
/// host holds one chunk of f32 pixels rather than the whole set.
const RESIDENT_CHUNK: usize = 32;

/// The cache's slot bookkeeping: what recording a step's uploads changes on the host, kept
/// together so that a step recorded ahead and then dropped can be undone
/// ([`ImageCache::book`]).
#[derive(Clone)]
pub struct CacheBook {
    /// Each slot's place; width and height are those of the image it holds.
    slots: Vec<ImageSlot>,
    /// Image held by each slot, and the slot of each image.
    holder: Vec<Option<usize>>,
    slot_of: Vec<Option<usize>>,
    /// The `prepare` call that last used each slot (least recently used gives way).
    last_used: Vec<u64>,
    tick: u64,
    /// Which half of the staging buffer the next uploads use: consecutive steps alternate, so
    /// the host writes one step's images while the previous step's copies may still read the
    /// other half (the trainer records a step while the previous one runs).
    staging_half: usize,
    stats: CacheStats,
}

pub struct ImageCache {
    source: Arc<dyn ImageSource>,
    buffers: Vec<GpuBuffer<u32>>,
    book: CacheBook,
    /// Streaming only: pixels of the largest image, the staging buffer (`staging_images` of
    /// them) and the loader.
    slot_px: usize,
    staging: Option<GpuBuffer<u32>>,
    loader: Option<Loader>,
}

impl ImageCache {
    /// The cache of `images`; a step reads at most `per_step` of them at once (the streaming
    /// cache needs at least that many slots).
    pub fn new(
        ctx: &Arc<GpuContext>,
        images: &TrainImages,
        per_step: usize,
    ) -> anyhow::Result<Self> {
        let source = images.source.clone();
        let n = source.count();
        let limit_px = (ctx.info.max_storage_buffer_range / 4).min(u32::MAX as u64) as usize;
        let sizes: Vec<(u32, u32)> = (0..n).map(|k| source.size(k)).collect();
        for (k, &(w, h)) in sizes.iter().enumerate() {
            ensure!(
                (w as usize * h as usize) <= limit_px,
                "{} ({w}×{h}) alone exceeds the device's {} MiB storage binding limit. \
                 Fix: train at a lower resolution (-r 2, 4 or 8)",
                source.name(k),
                ctx.info.max_storage_buffer_range >> 20
            );
        }
        let total_bytes: u64 = sizes.iter().map(|&(w, h)| 4 * w as u64 * h as u64).sum();
        let max_px = sizes
            .iter()
            .map(|&(w, h)| w as usize * h as usize)
            .max()
            .unwrap_or(1)
            .max(1);
        match images.cache_bytes {
            Some(budget) if total_bytes > budget => {
                Self::streaming(ctx, source, &sizes, max_px, limit_px, budget, per_step)
            }
            _ => Self::resident(ctx, source, &sizes, limit_px),
        }
    }

    /// Every image in a slot of its own size, uploaded now.
    fn resident(
        ctx: &Arc<GpuContext>,
        source: Arc<dyn ImageSource>,
        sizes: &[(u32, u32)],
        limit_px: usize,
    ) -> anyhow::Result<Self> {
        let px: Vec<usize> = sizes.iter().map(|&(w, h)| (w * h) as usize).collect();
        let (slots, buffer_px) = place(&px, limit_px);
        let mut slots: Vec<ImageSlot> = slots;
        for (s, &(w, h)) in slots.iter_mut().zip(sizes) {
            (s.width, s.height) = (w, h);
        }
        let buffers = buffer_px
            .iter()
            .map(|&len| GpuBuffer::new(ctx, "ground truth", len.max(1), BufferKind::DeviceLocal))
            .collect::<anyhow::Result<Vec<_>>>()?;
        let n = sizes.len();
        for start in (0..n).step_by(RESIDENT_CHUNK) {
            let chunk = load_range(source.as_ref(), start..(start + RESIDENT_CHUNK).min(n))?;
            for (i, img) in chunk.iter().enumerate() {
                let k = start + i;
                check_size(source.as_ref(), k, img, sizes[k])?;
                let s = slots[k];
                buffers[s.buffer].upload_at(s.offset_px as usize, &pack_rgba8(img))?;
            }
        }
        let bytes = 4 * buffer_px.iter().map(|&p| p as u64).sum::<u64>();
        Ok(Self {
            source,
            buffers,
            book: CacheBook {
                holder: (0..n).map(Some).collect(),
                slot_of: (0..n).map(Some).collect(),
                last_used: vec![0; n],
                tick: 0,
                staging_half: 0,
                stats: CacheStats {
                    images: n,
                    slots: n,
                    bytes,
                    resident: true,
                    ..Default::default()
                },
                slots,
            },
            slot_px: 0,
            staging: None,
            loader: None,
        })
    }

    /// As many slots of the largest image's size as `budget` bytes hold (at least `per_step`).
    fn streaming(
        ctx: &Arc<GpuContext>,
        source: Arc<dyn ImageSource>,
        sizes: &[(u32, u32)],
        max_px: usize,
        limit_px: usize,
        budget: u64,
        per_step: usize,
    ) -> anyhow::Result<Self> {
        let per_step = per_step.max(1);
        let count = (budget / (4 * max_px as u64)) as usize;
        ensure!(
            count >= per_step,
            "the image cache of {} MiB holds {count} training image(s) of {} pixels, but a \
             training step reads {per_step}. Fix: raise --image-cache to at least {} MiB",
            budget >> 20,
            max_px,
            (4 * max_px as u64 * per_step as u64).div_ceil(1 << 20)
        );
        let count = count.min(sizes.len());
        let (slots, buffer_px) = place(&vec![max_px; count], limit_px);
        let buffers = buffer_px
            .iter()
            .map(|&len| GpuBuffer::new(ctx, "ground truth", len, BufferKind::DeviceLocal))
            .collect::<anyhow::Result<Vec<_>>>()?;
        let staging = GpuBuffer::new(
            ctx,
            "ground truth staging",
            2 * max_px * per_step,
            BufferKind::Upload,
        )?;
        let bytes = 4 * (max_px * count) as u64;
        Ok(Self {
            loader: Some(Loader::start(source.clone())?),
            source,
            buffers,
            book: CacheBook {
                holder: vec![None; count],
                slot_of: vec![None; sizes.len()],
                last_used: vec![0; count],
                tick: 0,
                staging_half: 0,
                stats: CacheStats {
                    images: sizes.len(),
                    slots: count,
                    bytes,
                    resident: false,
                    ..Default::default()
                },
                slots,
            },
            slot_px: max_px,
            staging: Some(staging),
        })
    }

    /// The slot bookkeeping, to restore if the copies recorded after it are never submitted.
    pub fn book(&self) -> CacheBook {
        self.book.clone()
    }

    /// Restores the bookkeeping of [`ImageCache::book`] (the uploads recorded since were
    /// dropped unsubmitted; the images they took from the loader are decoded again).
    pub fn restore_book(&mut self, b: CacheBook) {
        self.book = b;
    }

    /// Whether the next step's uploads can be recorded while this step runs: a resident cache
    /// uploads nothing; a streaming one needs slots for two steps' images, so that the next
    /// step's evict none of this step's (which its density control still reads).
    pub fn holds_two_steps(&self, per_step: usize) -> bool {
        !self.streams() || self.book.slots.len() >= 2 * per_step
    }

    /// Whether images are streamed (the trainer then names the next steps' images).
    pub fn streams(&self) -> bool {
        self.loader.is_some()
    }

    pub fn stats(&self) -> CacheStats {
        self.book.stats
    }

    pub fn buffer(&self, slot: &ImageSlot) -> &GpuBuffer<u32> {
        &self.buffers[slot.buffer]
    }

    /// Where image `k` is, if it is on the GPU.
    pub fn slot(&self, k: usize) -> Option<ImageSlot> {
        self.book
            .slot_of
            .get(k)
            .copied()
            .flatten()
            .map(|s| self.book.slots[s])
    }

    /// Makes images `needed` resident for the step being recorded into `rec` (copies and a
    /// barrier recorded first, so record this before the step's kernels), and asks the loader
    /// for `upcoming`, the images of the next steps. The host writes the staging buffer now,
    /// into the half the previous call did not use: the submission before the previous one
    /// must have completed (the trainer records at most one step ahead).
    pub fn prepare(
        &mut self,
        rec: &mut Recorder,
        needed: &[usize],
        upcoming: &[usize],
    ) -> anyhow::Result<()> {
        self.book.tick += 1;
        let tick = self.book.tick;
        let mut copies = 0usize;
        for &k in needed {
            ensure!(
                k < self.book.slot_of.len(),
                "image cache: image {k} of {}",
                self.book.slot_of.len()
            );
            if let Some(s) = self.book.slot_of[k] {
                self.book.last_used[s] = tick;
                continue;
            }
            ensure!(
                copies < self.staging_images(),
                "image cache: a step reads more images than the {} it was sized for",
                self.staging_images()
            );
            let s = (0..self.book.slots.len())
                .filter(|&s| self.book.last_used[s] != tick)
                .min_by_key(|&s| self.book.last_used[s])
                .context("image cache: no free slot")?;
            let loader = self.loader.as_mut().context("image cache: not streaming")?;
            let t0 = Instant::now();
            let (pixels, was_ready) = loader.take(k)?;
            if !was_ready {
                self.book.stats.waited += 1;
            }
            self.book.stats.wait_seconds += t0.elapsed().as_secs_f64();
            let (w, h) = self.source.size(k);
            ensure!(
                pixels.len() == (w * h) as usize,
                "{}: decoded {} pixels, expected {w}×{h}",
                self.source.name(k),
                pixels.len()
            );
            let staging = self.staging.as_ref().context("image cache: no staging")?;
            let at = (self.book.staging_half * self.staging_images() + copies) * self.slot_px;
            staging.upload_at(at, &pixels)?;
            if let Some(old) = self.book.holder[s] {
                self.book.slot_of[old] = None;
            }
            self.book.holder[s] = Some(k);
            self.book.slot_of[k] = Some(s);
            self.book.last_used[s] = tick;
            let slot = &mut self.book.slots[s];
            (slot.width, slot.height) = (w, h);
            let slot = *slot;
            rec.copy_region(
                staging,
                at,
                &self.buffers[slot.buffer],
                slot.offset_px as usize,
                pixels.len(),
            );
            copies += 1;
            self.book.stats.uploads += 1;
        }
        if copies > 0 {
            rec.barrier();
            self.book.staging_half ^= 1;
        }
        if let Some(loader) = self.loader.as_mut() {
            let wanted: Vec<usize> = upcoming
                .iter()
                .copied()
                .filter(|&k| k < self.book.slot_of.len() && self.book.slot_of[k].is_none())
                .collect();
            loader.keep_only(&wanted);
            for k in wanted {
                loader.request(k)?;
            }
        }
        Ok(())
    }

    /// Images one half of the staging buffer holds (a step's).
    fn staging_images(&self) -> usize {
        self.staging
            .as_ref()
            .map_or(0, |s| s.len() / 2 / self.slot_px.max(1))
    }
}

fn check_size(
    source: &dyn ImageSource,
    k: usize,
    img: &Image,
    (w, h): (u32, u32),
) -> anyhow::Result<()> {
    ensure!(
        (img.width, img.height) == (w, h),
        "{}: decoded {}×{}, expected {w}×{h}",
        source.name(k),
        img.width,
        img.height
    );
    Ok(())
}

/// Places slots of `px` pixels in buffers of at most `limit_px`: each slot's buffer and offset
/// (width and height left 0) and each buffer's length.
fn place(px: &[usize], limit_px: usize) -> (Vec<ImageSlot>, Vec<usize>) {
    let mut slots = Vec::with_capacity(px.len());
    let mut buffers = vec![0usize];
    for &n in px {
        if *buffers.last().unwrap() + n > limit_px {
            buffers.push(0);
        }
        let b = buffers.len() - 1;
        slots.push(ImageSlot {
            buffer: b,
            offset_px: buffers[b] as u32,
            width: 0,
            height: 0,
        });
        buffers[b] += n;
    }
    (slots, buffers)
}

type Loaded = anyhow::Result<Vec<u32>>;

/// Decodes and packs images on a thread of its own, in the order asked.
struct Loader {
    source: Arc<dyn ImageSource>,
    requests: Option<Sender<usize>>,
    results: Receiver<(usize, Loaded)>,
    /// Asked for, not yet received.
    pending: HashSet<usize>,
    /// Received, not yet taken.
    ready: HashMap<usize, Loaded>,
    thread: Option<JoinHandle<()>>,
}

impl Loader {
    fn start(source: Arc<dyn ImageSource>) -> anyhow::Result<Self> {
        let (req_tx, req_rx) = channel::<usize>();
        let (res_tx, res_rx) = channel::<(usize, Loaded)>();
        let worker = source.clone();
        let thread = std::thread::Builder::new()
            .name("image loader".into())
            .spawn(move || {
                for k in req_rx {
                    let r = worker.load(k).map(|img| pack_rgba8(&img));
                    if res_tx.send((k, r)).is_err() {
                        break;
                    }
                }
            })
            .context("starting the image loader thread")?;
        Ok(Self {
            source,
            requests: Some(req_tx),
            results: res_rx,
            pending: HashSet::new(),
            ready: HashMap::new(),
            thread: Some(thread),
        })
    }

    fn request(&mut self, k: usize) -> anyhow::Result<()> {
        if self.pending.contains(&k) || self.ready.contains_key(&k) {
            return Ok(());
        }
        self.requests
            .as_ref()
            .context("image loader stopped")?
            .send(k)
            .map_err(|_| anyhow::anyhow!("the image loader thread stopped"))?;
        self.pending.insert(k);
        Ok(())
    }

    /// Forgets decoded images nobody is going to ask for (the host keeps only what is coming).
    fn keep_only(&mut self, wanted: &[usize]) {
        self.ready.retain(|k, _| wanted.contains(k));
    }

    /// Image `k` packed, and whether it was decoded before it was asked for: received, waited
    /// for if asked, loaded here if never asked.
    fn take(&mut self, k: usize) -> anyhow::Result<(Vec<u32>, bool)> {
        while let Ok((j, r)) = self.results.try_recv() {
            self.pending.remove(&j);
            self.ready.insert(j, r);
        }
        if let Some(r) = self.ready.remove(&k) {
            return Ok((r?, true));
        }
        if !self.pending.contains(&k) {
            let img = self.source.load(k)?;
            return Ok((pack_rgba8(&img), false));
        }
        loop {
            let (j, r) = self
                .results
                .recv()
                .map_err(|_| anyhow::anyhow!("the image loader thread stopped"))?;
            self.pending.remove(&j);
            if j == k {
                return Ok((r?, false));
            }
            self.ready.insert(j, r);
        }
    }
}

impl Drop for Loader {
    fn drop(&mut self) {
        // Closing the request channel ends the thread's loop once its current image is done.
        self.requests = None;
        if let Some(t) = self.thread.take() {
            let _ = t.join();
        }
    }
}
