//! SpacetimeGaussians' angular-velocity / rotation split on the GPU
//! ([`crate::train::passes::spacetime_settings::OmegaFreeze`]; kernels `glsl/spacetime/omega_{select,masks}.comp`,
//! oracle [`crate::reference::spacetime::omega_marked`]): at the selection step the unmarked
//! Gaussians' angular velocities become 0 and the group's Adam moments are cleared (the
//! official code replaces the tensor in the optimizer); at every later step, before Adam, the
//! angular-velocity gradient of Gaussians with ω = 0 and the rotation gradient of the others
//! are zeroed. "ω = 0" is the mark, so it follows every density change (a Gaussian added later
//! has ω = 0: it learns a rotation, as every Gaussian did before the split).

use std::sync::Arc;

use anyhow::{ensure, Result};

use super::spacetime_settings::OmegaFreeze;
use crate::gpu::{ComputePipeline, GpuContext, Recorder};
use crate::shaders;
use crate::splats::gpu::GpuSplats;
use crate::train::adam::SplatState;

const WG: u32 = 256;

#[repr(C)]
#[derive(Clone, Copy, bytemuck::Pod, bytemuck::Zeroable)]
struct SelectPush {
    count: u32,
    motion_above: f32,
    scale_lo: f32,
    scale_hi: f32,
    opacity_above: f32,
}

pub struct OmegaFreezer {
    ctx: Arc<GpuContext>,
    select: ComputePipeline,
    masks: ComputePipeline,
    pub settings: OmegaFreeze,
    /// The selection has been made (checkpoints keep this).
    pub selected: bool,
}

fn group<'a>(s: &'a GpuSplats, name: &str) -> Result<&'a crate::gpu::GpuBuffer<f32>> {
    s.extra_group(name)
        .ok_or_else(|| anyhow::anyhow!("SpacetimeGaussians: the model has no '{name}' group"))
}

impl OmegaFreezer {
    pub fn new(ctx: &Arc<GpuContext>, settings: OmegaFreeze) -> Result<Self> {
        ensure!(
            settings.scale_between[0] < settings.scale_between[1],
            "angular-velocity split: the scale range {:?} is empty",
            settings.scale_between
        );
        Ok(Self {
            ctx: ctx.clone(),
            select: ComputePipeline::new(
                ctx,
                "spacetime/omega_select",
                shaders::SPACETIME_OMEGA_SELECT,
                4,
                std::mem::size_of::<SelectPush>() as u32,
                WG,
                &[],
            )?,
            masks: ComputePipeline::new(
                ctx,
                "spacetime/omega_masks",
                shaders::SPACETIME_OMEGA_MASKS,
                3,
                4,
                WG,
                &[],
            )?,
            settings,
            selected: false,
        })
    }

    /// Records the selection on the model (ω of the unmarked set to 0, the ω group's Adam
    /// moments cleared). Barriers around.
    pub fn record_select(&self, rec: &mut Recorder, state: &SplatState) -> Result<()> {
        let n = state.count();
        let p = &state.params;
        let f = &self.settings;
        rec.barrier();
        if n > 0 {
            rec.dispatch_named(
                &self.select,
                &[
                    ("motion", group(p, "motion")?),
                    ("log_scales", &p.log_scales),
                    ("opacity_logits", &p.opacity_logits),
                    ("omega", group(p, "omega")?),
                ],
                &SelectPush {
                    count: n as u32,
                    motion_above: f.motion_above as f32,
                    scale_lo: f.scale_between[0] as f32,
                    scale_hi: f.scale_between[1] as f32,
                    opacity_above: f.opacity_above as f32,
                },
                self.ctx.groups_1d(n as u64, WG),
            );
        }
        rec.fill(group(&state.m, "omega")?, 0);
        rec.fill(group(&state.v, "omega")?, 0);
        rec.barrier();
        Ok(())
    }

    /// Records the gradient masks of Gaussians `0..count` (ω = 0: no ω gradient; else no
    /// rotation gradient). Barriers around.
    pub fn record_masks(
        &self,
        rec: &mut Recorder,
        params: &GpuSplats,
        grads: &GpuSplats,
        count: usize,
    ) -> Result<()> {
        rec.barrier();
        if count > 0 {
            rec.dispatch_named(
                &self.masks,
                &[
                    ("omega", group(params, "omega")?),
                    ("g_omega", group(grads, "omega")?),
                    ("g_rotations", &grads.rotations),
                ],
                &(count as u32),
                self.ctx.groups_1d(count as u64, WG),
            );
        }
        rec.barrier();
        Ok(())
    }

    /// The work before iteration `iteration`'s optimizer step: the selection at the first step
    /// from `from` on (a densify step that rebuilt the model has no optimizer step, so the
    /// selection waits for the next one), then the masks, at that step and every later one.
    ///
    /// The official code masks only from the step after the selection, so its unmarked angular
    /// velocities get one more Adam step from fresh moments (and drift on with the momentum,
    /// ending near 1e-3 instead of 0): an artefact of its order that this engine does not copy,
    /// because here ω = 0 is the mark itself.
    pub fn record(
        &mut self,
        rec: &mut Recorder,
        state: &SplatState,
        grads: &GpuSplats,
        iteration: u32,
    ) -> Result<()> {
        if iteration < self.settings.from {
            return Ok(());
        }
        if !self.selected {
            self.record_select(rec, state)?;
            self.selected = true;
        }
        self.record_masks(rec, &state.params, grads, state.count())
    }
}
