//! Step 4 of the density step (see [`super`]): every per-Gaussian buffer moved into the new
//! layout in place, through two scratch buffers of the widest group's size, with the split
//! children's positions and log-scales written by the split kernel.

use super::{DensityControl, SplitPush, WG};
use crate::gpu::{BufferKind, GpuBuffer, Recorder};
use crate::train::adam::SplatState;

#[repr(C)]
#[derive(Clone, Copy, bytemuck::Pod, bytemuck::Zeroable)]
pub(super) struct ScatterPush {
    count: u32,
    stride: u32,
    mode: u32,
}

const SCATTER_COPY: u32 = 0;
const SCATTER_ZERO_NEW: u32 = 1;
const SCATTER_SKIP_CHILDREN: u32 = 2;

/// The per-Gaussian groups of a state: parameters, first and second moments.
fn groups(s: &SplatState) -> [Vec<(&GpuBuffer<f32>, usize)>; 3] {
    [s.params.groups(), s.m.groups(), s.v.groups()]
}

/// Floats in each move scratch buffer for `state`: its widest group at its capacity.
pub(super) fn move_scratch_floats(state: &SplatState) -> usize {
    let widest = groups(state)
        .iter()
        .flatten()
        .map(|g| g.1)
        .max()
        .unwrap_or(1);
    widest * state.capacity()
}

/// How group `k` of set `set` (0 parameters, 1–2 moments) moves: moments start at zero for new
/// Gaussians; the split kernel writes the children's positions and log-scales (groups 0 and 1);
/// every other group, the model's extra groups included, is copied from the parent.
fn scatter_mode(set: usize, k: usize) -> u32 {
    if set > 0 {
        SCATTER_ZERO_NEW
    } else if k < 2 {
        SCATTER_SKIP_CHILDREN
    } else {
        SCATTER_COPY
    }
}

impl DensityControl {
    /// Records the move of every per-Gaussian buffer of `state` into its new layout in the same
    /// buffers: each group is scattered into one of the two move scratch buffers and copied back,
    /// pipelined so one barrier separates the steps (group j's copy-back runs beside group
    /// j+1's scatter into the other scratch). Positions and log-scales go first, together,
    /// because the split kernel reads the parents' positions, log-scales and rotations.
    pub(super) fn record_move_in_place(
        &self,
        rec: &mut Recorder,
        state: &SplatState,
        count: usize,
        after: usize,
        split: &SplitPush,
    ) {
        let [a, b] = &self.move_scratch;
        let p = &state.params;
        self.record_scatter(rec, &p.positions, a, 3, SCATTER_SKIP_CHILDREN, count);
        self.record_scatter(rec, &p.log_scales, b, 3, SCATTER_SKIP_CHILDREN, count);
        self.record_split(rec, state, a, b, count, split);
        rec.barrier();
        rec.copy(a, &p.positions, 3 * after);
        rec.copy(b, &p.log_scales, 3 * after);
        let rest: Vec<_> = groups(state)
            .iter()
            .enumerate()
            .flat_map(|(set, g)| {
                g.iter()
                    .enumerate()
                    .filter(move |&(k, e)| e.1 > 0 && (set > 0 || k >= 2))
                    .map(move |(k, e)| (e.0, e.1, scatter_mode(set, k)))
            })
            .collect();
        // `pending`: the group whose scatter the last barrier completed, still to copy back.
        let mut pending: Option<(&GpuBuffer<f32>, &GpuBuffer<f32>, usize)> = None;
        for (j, &(buf, stride, mode)) in rest.iter().enumerate() {
            rec.barrier();
            if let Some((scratch, to, n)) = pending.take() {
                rec.copy(scratch, to, n);
            }
            let scratch = if j % 2 == 0 { a } else { b };
            self.record_scatter(rec, buf, scratch, stride, mode, count);
            pending = Some((scratch, buf, stride * after));
        }
        rec.barrier();
        if let Some((scratch, to, n)) = pending {
            rec.copy(scratch, to, n);
        }
        rec.barrier();
    }

    fn record_scatter(
        &self,
        rec: &mut Recorder,
        src: &GpuBuffer<f32>,
        dst: &GpuBuffer<f32>,
        stride: usize,
        mode: u32,
        count: usize,
    ) {
        rec.dispatch_named(
            &self.scatter,
            &[
                ("decisions", &self.decisions),
                ("offsets", &self.slots),
                ("src", src),
                ("dst", dst),
            ],
            &ScatterPush {
                count: count as u32,
                stride: stride as u32,
                mode,
            },
            self.ctx.groups_1d(count as u64, WG),
        );
    }

    /// The split children's positions and log-scales, from the parents in `src`.
    fn record_split(
        &self,
        rec: &mut Recorder,
        src: &SplatState,
        positions: &GpuBuffer<f32>,
        log_scales: &GpuBuffer<f32>,
        count: usize,
        push: &SplitPush,
    ) {
        rec.dispatch_named(
            &self.split,
            &[
                ("decisions", &self.decisions),
                ("offsets", &self.slots),
                ("positions", &src.params.positions),
                ("log_scales", &src.params.log_scales),
                ("rotations", &src.params.rotations),
                ("dst_positions", positions),
                ("dst_log_scales", log_scales),
            ],
            push,
            self.ctx.groups_1d(count as u64, WG),
        );
    }

    /// Fills the move scratch buffers (sized for `state`) with `bits`, so that a test sees any
    /// row an in-place step forgets to write: they are what is copied back into the state.
    pub fn poison_move_scratch(&mut self, state: &SplatState, bits: u32) -> anyhow::Result<()> {
        self.ensure_move_scratch(move_scratch_floats(state))?;
        let mut rec = Recorder::new(&self.ctx)?;
        for b in &self.move_scratch {
            rec.fill(b, bits);
        }
        rec.submit_and_wait()
    }

    /// Frees the move scratch once a step is done with it: kept between steps, its 72 bytes a
    /// Gaussian of capacity were held all run, and on a growing step they sat beside the
    /// gradients' reallocation at the run's peak. Allocating it again every step costs little
    /// (density steps come every 100 iterations).
    pub(super) fn release_move_scratch(&mut self) -> anyhow::Result<()> {
        let empty = || {
            GpuBuffer::new(
                &self.ctx,
                "density move scratch",
                0,
                BufferKind::DeviceLocal,
            )
        };
        self.move_scratch = [empty()?, empty()?];
        Ok(())
    }

    /// The two move scratch buffers hold at least `floats` each.
    pub(super) fn ensure_move_scratch(&mut self, floats: usize) -> anyhow::Result<()> {
        if self.move_scratch[0].len() >= floats {
            return Ok(());
        }
        let new = || {
            GpuBuffer::new(
                &self.ctx,
                "density move scratch",
                floats,
                BufferKind::DeviceLocal,
            )
        };
        self.move_scratch = [new()?, new()?];
        Ok(())
    }
}
