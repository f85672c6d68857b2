//! Rendering one frame and waiting, for tools and tests (the trainer records its frames into
//! its own command buffers): the frame is drawn again after the pair buffers grow when they
//! were too small, and in bands of tile rows (`super::bands`) when its pairs pass what one
//! storage binding holds. One loop for every renderer built on [`Renderer`]'s binding.

use anyhow::Result;

use super::bands::{plan_bands, FrameWork};
use super::forward::{Capacity, FrameSettings, Renderer};
use super::layout::CameraGpu;
use crate::gpu::{GpuBuffer, Recorder};
use crate::splats::gpu::GpuSplats;

/// A renderer that can be drawn in bands: the 3D-Gaussian renderer, or one built on its
/// binning (surfels).
pub trait BandedRenderer {
    /// The binning stages and buffers.
    fn base(&mut self) -> &mut Renderer;
    /// Grows every buffer the renderer sizes by `need` ([`Renderer::ensure_capacity`]).
    fn grow(&mut self, need: Capacity) -> Result<bool>;
}

impl BandedRenderer for Renderer {
    fn base(&mut self) -> &mut Renderer {
        self
    }
    fn grow(&mut self, need: Capacity) -> Result<bool> {
        self.ensure_capacity(need)
    }
}

/// Renders one frame and waits: `record` records the frame's work into the given command
/// buffer. The frame is redrawn after growing the pair buffers when they were too small, and in
/// bands of tile rows (planned by one counting pass) when its pairs pass what one binding holds.
pub fn render_blocking<R: BandedRenderer>(
    r: &mut R,
    camera: &CameraGpu,
    mut record: impl FnMut(&mut R, &mut Recorder, &FrameWork) -> Result<()>,
) -> Result<()> {
    let ctx = r.base().context().clone();
    let mut planned = false;
    loop {
        let bands = r.base().bands_for(camera);
        let mut rec = Recorder::new(&ctx)?;
        record(r, &mut rec, &FrameWork::Bands(bands))?;
        rec.submit_and_wait()?;
        let totals = r.base().last_band_totals()?;
        let most = totals.iter().copied().max().unwrap_or(0);
        let base = r.base();
        let capacity = base.capacity();
        let limit = base.pair_limit();
        if most <= capacity.intersections as u64 {
            // A frame drawn in bands that would fit whole: the next frames of this size are
            // drawn whole again (planned again if one does not fit).
            if totals.len() > 1 && totals.iter().sum::<u64>() <= limit {
                base.clear_plan();
            }
            return Ok(());
        }
        if most <= limit {
            r.grow(Capacity {
                intersections: most as usize,
                ..capacity
            })?;
            continue;
        }
        // The planned bands were counted exactly: one past the limit would mean the count and
        // the binning disagree.
        anyhow::ensure!(
            !planned,
            "a band of tile rows has {most} (tile, Gaussian) pairs after planning for at most \
             {limit}: the planning pass and the binning disagree (a bug; please report it)"
        );
        let total: u64 = totals.iter().sum();
        let mut rec = Recorder::new(&ctx)?;
        r.base().reserve_row_totals(camera)?;
        record(r, &mut rec, &FrameWork::RowTotals)?;
        rec.submit_and_wait()?;
        let base = r.base();
        let rows = base.last_row_totals(camera)?;
        let plan = plan_bands(&rows, limit).map_err(|full| {
            anyhow::anyhow!(
                "a frame has {total} (tile, Gaussian) intersections, and its row {} of 16-px \
                 tiles alone has {}, more than the {limit} one storage binding holds on this \
                 device ({} MiB maxStorageBufferRange, 4 bytes a pair): it cannot be drawn even \
                 in bands of tile rows. Fix: render at a lower resolution (-r, \
                 --width/--height) or with fewer Gaussians",
                full.row,
                full.pairs,
                base.context().info.max_storage_buffer_range >> 20
            )
        })?;
        let most = plan.iter().map(|b| b.pairs).max().unwrap_or(0);
        base.set_plan(camera, plan)?;
        let capacity = base.capacity();
        r.grow(Capacity {
            intersections: most as usize,
            ..capacity
        })?;
        planned = true;
    }
}

impl Renderer {
    /// Renders one frame and waits, regrowing and re-rendering when the intersections did not
    /// fit, in bands of tile rows when they pass one binding. For tools and tests; the trainer
    /// records frames into its own command buffers.
    pub fn render_blocking(
        &mut self,
        splats: &GpuSplats,
        cameras: &GpuBuffer<CameraGpu>,
        camera_index: u32,
        camera: &CameraGpu,
        settings: &FrameSettings,
    ) -> Result<()> {
        self.ensure_capacity(Capacity::for_frame(splats.count, camera))?;
        render_blocking(self, camera, |r, rec, work| {
            r.record_work(
                rec,
                splats,
                cameras,
                camera_index,
                camera,
                settings,
                work,
                None,
            )
        })
    }
}
