//! Frees held back while recorded work may still use the buffers.
//!
//! A buffer dropped on the host is normally destroyed at once, which is right when nothing on
//! the queue still reads it. The trainer records iteration N+1 while iteration N runs on the GPU
//! (`Trainer::step_ahead`); if that recording replaces a buffer (a larger view grows the render
//! buffers, say, and the sorts' pipelines with them), the old ones are still bound in N's
//! command buffer. While a [`HoldFrees`] guard lives, dropped buffers and pipelines are kept
//! here (buffers still booked against the device memory) and destroyed when the last guard goes
//! (the holder drops it only after N's fence).

use super::GpuContext;
use ash::vk;
use gpu_allocator::vulkan::Allocation;
use std::sync::Arc;

/// A buffer or pipeline whose destruction may wait for the last [`HoldFrees`] guard.
pub(crate) enum Retired {
    Buffer {
        buffer: vk::Buffer,
        allocation: Option<Allocation>,
        /// Device-local bytes still booked in the context's `DeviceMemory`.
        booked: u64,
    },
    Pipeline {
        pipeline: vk::Pipeline,
        layout: vk::PipelineLayout,
        set_layout: vk::DescriptorSetLayout,
    },
}

/// The context's held frees: how many guards are alive, and what they hold.
#[derive(Default)]
pub(crate) struct HeldFrees {
    pub guards: usize,
    pub retired: Vec<Retired>,
    /// Objects retired under a guard since the context was made (to tell whether any was
    /// retired while a given guard lived).
    pub total: u64,
}

/// Destroys a buffer or pipeline now (no guard alive) or keeps it for the last guard.
pub(crate) fn retire(ctx: &GpuContext, r: Retired) {
    {
        let mut held = ctx.held_frees.lock().unwrap_or_else(|e| e.into_inner());
        if held.guards > 0 {
            held.retired.push(r);
            held.total += 1;
            return;
        }
    }
    destroy(ctx, r);
}

pub(crate) fn destroy(ctx: &GpuContext, r: Retired) {
    match r {
        Retired::Buffer {
            buffer,
            allocation,
            booked,
        } => {
            unsafe { ctx.device.destroy_buffer(buffer, None) };
            if let Some(a) = allocation {
                let _ = ctx.allocator.lock().map(|mut al| al.free(a));
            }
            ctx.memory.release(booked);
        }
        Retired::Pipeline {
            pipeline,
            layout,
            set_layout,
        } => unsafe {
            ctx.device.destroy_pipeline(pipeline, None);
            ctx.device.destroy_pipeline_layout(layout, None);
            ctx.device.destroy_descriptor_set_layout(set_layout, None);
        },
    }
}

/// While alive, buffers and pipelines dropped anywhere on this context are destroyed only when
/// the last guard is dropped. Drop it only once the GPU work recorded before it has completed.
pub struct HoldFrees {
    ctx: Arc<GpuContext>,
    /// `HeldFrees::total` when the guard was made.
    start: u64,
}

impl HoldFrees {
    pub fn new(ctx: &Arc<GpuContext>) -> Self {
        let mut held = ctx.held_frees.lock().unwrap_or_else(|e| e.into_inner());
        held.guards += 1;
        Self {
            ctx: ctx.clone(),
            start: held.total,
        }
    }

    /// Whether any buffer or pipeline was dropped while this guard lived (so a command
    /// buffer recorded before may name a destroyed object once the guard goes).
    pub fn retired_any(&self) -> bool {
        let held = self
            .ctx
            .held_frees
            .lock()
            .unwrap_or_else(|e| e.into_inner());
        held.total > self.start
    }
}

impl Drop for HoldFrees {
    fn drop(&mut self) {
        let freed = {
            let mut held = self
                .ctx
                .held_frees
                .lock()
                .unwrap_or_else(|e| e.into_inner());
            held.guards -= 1;
            if held.guards == 0 {
                std::mem::take(&mut held.retired)
            } else {
                Vec::new()
            }
        };
        for r in freed {
            destroy(&self.ctx, r);
        }
    }
}
