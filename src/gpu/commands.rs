//! Command recording with explicit barriers. A `Recorder` owns its command pool, command buffer
//! and fence, so it can be reused iteration after iteration (`begin` again after a wait) and
//! several recorders can live on different threads.

use super::buffer::Bindable;
use super::{ComputePipeline, GpuBuffer, GpuContext, TimestampPool};
use anyhow::{bail, Context as _};
use ash::vk;
use bytemuck::Pod;
use std::sync::Arc;

pub struct Recorder {
    ctx: Arc<GpuContext>,
    pool: vk::CommandPool,
    cmd: vk::CommandBuffer,
    fence: vk::Fence,
    recording: bool,
    in_flight: bool,
    dispatches: u32,
}

impl Recorder {
    /// A recorder that has already begun recording.
    pub fn new(ctx: &Arc<GpuContext>) -> anyhow::Result<Self> {
        let device = &ctx.device;
        let pool = unsafe {
            device.create_command_pool(
                &vk::CommandPoolCreateInfo::default()
                    .queue_family_index(ctx.queue_family)
                    .flags(vk::CommandPoolCreateFlags::TRANSIENT),
                None,
            )
        }
        .context("creating command pool")?;
        let cmd = unsafe {
            device.allocate_command_buffers(
                &vk::CommandBufferAllocateInfo::default()
                    .command_pool(pool)
                    .level(vk::CommandBufferLevel::PRIMARY)
                    .command_buffer_count(1),
            )
        }
        .context("allocating command buffer")?[0];
        let fence = unsafe { device.create_fence(&vk::FenceCreateInfo::default(), None) }
            .context("creating fence")?;
        let mut r = Self {
            ctx: ctx.clone(),
            pool,
            cmd,
            fence,
            recording: false,
            in_flight: false,
            dispatches: 0,
        };
        r.begin()?;
        Ok(r)
    }

    /// Starts a new recording (waits for the previous submission first if it is still running).
    pub fn begin(&mut self) -> anyhow::Result<()> {
        if self.in_flight {
            self.wait()?;
        }
        unsafe {
            self.ctx
                .device
                .reset_command_pool(self.pool, vk::CommandPoolResetFlags::empty())?;
            self.ctx.device.begin_command_buffer(
                self.cmd,
                &vk::CommandBufferBeginInfo::default()
                    .flags(vk::CommandBufferUsageFlags::ONE_TIME_SUBMIT),
            )?;
        }
        self.recording = true;
        self.dispatches = 0;
        Ok(())
    }

    fn check_recording(&self) {
        assert!(
            self.recording,
            "Recorder used while not recording: call begin() first"
        );
    }

    /// Number of dispatches recorded since `begin`.
    pub fn dispatch_count(&self) -> u32 {
        self.dispatches
    }

    fn bind(&mut self, p: &ComputePipeline, buffers: &[&dyn Bindable], push: &[u8]) {
        self.check_recording();
        assert_eq!(
            buffers.len() as u32,
            p.num_buffers,
            "kernel {} takes {} buffers, {} given",
            p.name,
            p.num_buffers,
            buffers.len()
        );
        assert_eq!(
            push.len() as u32,
            p.push_size,
            "kernel {}: push constant size mismatch",
            p.name
        );
        let infos: Vec<[vk::DescriptorBufferInfo; 1]> = buffers
            .iter()
            .map(|b| {
                [vk::DescriptorBufferInfo {
                    buffer: b.vk_buffer(),
                    offset: 0,
                    range: b.range(),
                }]
            })
            .collect();
        let writes: Vec<vk::WriteDescriptorSet> = infos
            .iter()
            .enumerate()
            .map(|(i, info)| {
                vk::WriteDescriptorSet::default()
                    .dst_binding(i as u32)
                    .descriptor_type(vk::DescriptorType::STORAGE_BUFFER)
                    .buffer_info(info)
            })
            .collect();
        unsafe {
            let d = &self.ctx.device;
            d.cmd_bind_pipeline(self.cmd, vk::PipelineBindPoint::COMPUTE, p.pipeline);
            if !writes.is_empty() {
                self.ctx.push_descriptor.cmd_push_descriptor_set(
                    self.cmd,
                    vk::PipelineBindPoint::COMPUTE,
                    p.layout,
                    0,
                    &writes,
                );
            }
            if !push.is_empty() {
                d.cmd_push_constants(self.cmd, p.layout, vk::ShaderStageFlags::COMPUTE, 0, push);
            }
        }
    }

    /// Records a dispatch of `groups` workgroups, each buffer given by the name the kernel's GLSL
    /// gives its binding (the block's member: `positions`, `g_sh_rest0`, …), in any order: the kernel's
    /// declaration is the one place binding numbers are written, and a list is never matched
    /// to it by position. Every binding must be named exactly once.
    pub fn dispatch_named<P: Pod>(
        &mut self,
        p: &ComputePipeline,
        buffers: &[(&str, &dyn Bindable)],
        push: &P,
        groups: [u32; 3],
    ) {
        let ordered = order_by_name(p, buffers);
        self.dispatch_ordered(p, &ordered, push, groups);
    }

    /// The dispatch itself, the buffers in binding order ([`order_by_name`]'s).
    fn dispatch_ordered<P: Pod>(
        &mut self,
        p: &ComputePipeline,
        buffers: &[&dyn Bindable],
        push: &P,
        groups: [u32; 3],
    ) {
        self.bind(p, buffers, bytemuck::bytes_of(push));
        if groups.iter().all(|&g| g > 0) {
            unsafe {
                self.ctx
                    .device
                    .cmd_dispatch(self.cmd, groups[0], groups[1], groups[2])
            };
            self.dispatches += 1;
        }
    }

    /// Records a dispatch whose group counts the GPU wrote into `args` at `offset` (3 × u32),
    /// the buffers by name as for [`Recorder::dispatch_named`].
    pub fn dispatch_indirect_named<P: Pod>(
        &mut self,
        p: &ComputePipeline,
        buffers: &[(&str, &dyn Bindable)],
        push: &P,
        args: &GpuBuffer<u32>,
        offset_elems: usize,
    ) {
        let ordered = order_by_name(p, buffers);
        self.bind(p, &ordered, bytemuck::bytes_of(push));
        unsafe {
            self.ctx
                .device
                .cmd_dispatch_indirect(self.cmd, args.buffer, (offset_elems * 4) as u64)
        };
        self.dispatches += 1;
    }

    /// Makes every earlier compute or transfer write visible to every later compute, transfer or
    /// indirect read. One global memory barrier: on the devices we target, finer barriers buy
    /// nothing for a compute-only queue.
    pub fn barrier(&mut self) {
        self.check_recording();
        let mb = vk::MemoryBarrier::default()
            .src_access_mask(
                vk::AccessFlags::SHADER_WRITE
                    | vk::AccessFlags::TRANSFER_WRITE
                    | vk::AccessFlags::SHADER_READ
                    | vk::AccessFlags::TRANSFER_READ,
            )
            .dst_access_mask(
                vk::AccessFlags::SHADER_READ
                    | vk::AccessFlags::SHADER_WRITE
                    | vk::AccessFlags::TRANSFER_READ
                    | vk::AccessFlags::TRANSFER_WRITE
                    | vk::AccessFlags::INDIRECT_COMMAND_READ,
            );
        let stages = vk::PipelineStageFlags::COMPUTE_SHADER | vk::PipelineStageFlags::TRANSFER;
        unsafe {
            self.ctx.device.cmd_pipeline_barrier(
                self.cmd,
                stages,
                stages | vk::PipelineStageFlags::DRAW_INDIRECT,
                vk::DependencyFlags::empty(),
                &[mb],
                &[],
                &[],
            )
        };
    }

    /// Fills a buffer of 32-bit elements with `value` (a transfer command).
    /// Fills the first `count` elements of `buf` with the 32-bit word `value` (a no-op for 0).
    pub fn fill_range<T: Pod>(&mut self, buf: &GpuBuffer<T>, count: usize, value: u32) {
        self.check_recording();
        let size = (count.min(buf.len()) * std::mem::size_of::<T>()) as u64;
        assert_eq!(
            std::mem::size_of::<T>() % 4,
            0,
            "fill needs 4-byte elements"
        );
        if size == 0 {
            return;
        }
        unsafe {
            self.ctx
                .device
                .cmd_fill_buffer(self.cmd, buf.buffer, 0, size, value)
        };
    }

    pub fn fill<T: Pod>(&mut self, buf: &GpuBuffer<T>, value: u32) {
        self.check_recording();
        assert_eq!(
            std::mem::size_of::<T>() % 4,
            0,
            "fill needs 4-byte elements"
        );
        unsafe {
            self.ctx
                .device
                .cmd_fill_buffer(self.cmd, buf.buffer, 0, vk::WHOLE_SIZE, value)
        };
    }

    /// Copies the first `count` elements of `src` into `dst`.
    pub fn copy<T: Pod>(&mut self, src: &GpuBuffer<T>, dst: &GpuBuffer<T>, count: usize) {
        self.copy_region(src, 0, dst, 0, count);
    }

    pub fn copy_region<T: Pod>(
        &mut self,
        src: &GpuBuffer<T>,
        src_first: usize,
        dst: &GpuBuffer<T>,
        dst_first: usize,
        count: usize,
    ) {
        self.check_recording();
        if count == 0 {
            return;
        }
        assert!(
            src_first + count <= src.len() && dst_first + count <= dst.len(),
            "copy out of range"
        );
        let e = std::mem::size_of::<T>() as u64;
        let region = vk::BufferCopy {
            src_offset: src_first as u64 * e,
            dst_offset: dst_first as u64 * e,
            size: count as u64 * e,
        };
        unsafe {
            self.ctx
                .device
                .cmd_copy_buffer(self.cmd, src.buffer, dst.buffer, &[region])
        };
    }

    /// Starts timing: resets the pool inside the command buffer and writes the first timestamp.
    pub fn start_timestamps(&mut self, pool: &mut TimestampPool) {
        self.check_recording();
        pool.labels.clear();
        unsafe {
            self.ctx
                .device
                .cmd_reset_query_pool(self.cmd, pool.pool, 0, pool.capacity())
        };
        self.timestamp(pool, "start");
    }

    /// Writes a timestamp after all earlier work; `label` names the stage that just ended.
    /// Silently ignored when the pool is full or the device has no timestamps.
    pub fn timestamp(&mut self, pool: &mut TimestampPool, label: &str) {
        self.check_recording();
        if !self.ctx.info.timestamps_supported || pool.labels.len() as u32 >= pool.capacity() {
            return;
        }
        let q = pool.labels.len() as u32;
        unsafe {
            self.ctx.device.cmd_write_timestamp(
                self.cmd,
                vk::PipelineStageFlags::BOTTOM_OF_PIPE,
                pool.pool,
                q,
            )
        };
        pool.labels.push(label.to_string());
    }

    /// Ends recording and submits; the host does not wait.
    pub fn submit(&mut self) -> anyhow::Result<()> {
        if !self.recording {
            bail!("submit without recording");
        }
        // Make device writes visible to the host for readbacks after the fence.
        let mb = vk::MemoryBarrier::default()
            .src_access_mask(vk::AccessFlags::SHADER_WRITE | vk::AccessFlags::TRANSFER_WRITE)
            .dst_access_mask(vk::AccessFlags::HOST_READ);
        unsafe {
            let d = &self.ctx.device;
            d.cmd_pipeline_barrier(
                self.cmd,
                vk::PipelineStageFlags::COMPUTE_SHADER | vk::PipelineStageFlags::TRANSFER,
                vk::PipelineStageFlags::HOST,
                vk::DependencyFlags::empty(),
                &[mb],
                &[],
                &[],
            );
            d.end_command_buffer(self.cmd)?;
            d.reset_fences(&[self.fence])?;
            let cmds = [self.cmd];
            let submit = vk::SubmitInfo::default().command_buffers(&cmds);
            let _guard = self.ctx.queue_lock.lock().unwrap();
            d.queue_submit(self.ctx.queue, &[submit], self.fence)
                .context("vkQueueSubmit failed (device lost?)")?;
        }
        self.recording = false;
        self.in_flight = true;
        Ok(())
    }

    /// Waits for the last submission.
    pub fn wait(&mut self) -> anyhow::Result<()> {
        if self.in_flight {
            unsafe {
                self.ctx
                    .device
                    .wait_for_fences(&[self.fence], true, u64::MAX)
            }
            .context("waiting for the GPU (device lost?)")?;
            self.in_flight = false;
        }
        Ok(())
    }

    pub fn submit_and_wait(&mut self) -> anyhow::Result<()> {
        self.submit()?;
        self.wait()
    }
}

impl Drop for Recorder {
    fn drop(&mut self) {
        unsafe {
            if self.in_flight {
                let _ = self
                    .ctx
                    .device
                    .wait_for_fences(&[self.fence], true, u64::MAX);
            }
            self.ctx.device.destroy_fence(self.fence, None);
            self.ctx.device.destroy_command_pool(self.pool, None);
        }
    }
}

/// `buffers` in the binding order of `p`'s declared names; panics (as a mismatched count does)
/// naming what is missing, unknown or given twice.
fn order_by_name<'b>(
    p: &ComputePipeline,
    buffers: &[(&str, &'b dyn Bindable)],
) -> Vec<&'b dyn Bindable> {
    let names = p.binding_names;
    assert!(
        !names.is_empty() || buffers.is_empty(),
        "kernel {}: its bindings' names are unknown (not one of glsl/'s kernels)",
        p.name
    );
    let mut slots: Vec<Option<&dyn Bindable>> = vec![None; names.len()];
    for &(name, buffer) in buffers {
        let Some(k) = names.iter().position(|n| *n == name) else {
            panic!(
                "kernel {}: no binding is named {name:?} (it declares {})",
                p.name,
                names.join(", ")
            );
        };
        assert!(
            slots[k].is_none(),
            "kernel {}: {name:?} is given twice",
            p.name
        );
        slots[k] = Some(buffer);
    }
    slots
        .into_iter()
        .zip(names)
        .map(|(b, n)| b.unwrap_or_else(|| panic!("kernel {}: no buffer given for {n:?}", p.name)))
        .collect()
}
