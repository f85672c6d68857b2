//! Compute pipelines from embedded SPIR-V: storage buffers through push descriptors, push
//! constants, and specialisation constants (0 = workgroup size x, 1 = subgroup size).

use super::GpuContext;
use anyhow::{bail, Context as _};
use ash::vk;
use std::sync::Arc;

/// One compute kernel ready to dispatch.
pub struct ComputePipeline {
    ctx: Arc<GpuContext>,
    pub(crate) pipeline: vk::Pipeline,
    pub(crate) layout: vk::PipelineLayout,
    set_layout: vk::DescriptorSetLayout,
    pub(crate) num_buffers: u32,
    pub(crate) push_size: u32,
    /// Workgroup size in x (specialisation constant 0).
    pub workgroup_size: u32,
    pub name: String,
    /// The kernel's storage buffers by binding, as its GLSL names them (from `build.rs`'s
    /// table; empty for SPIR-V that is not one of ours): what [`Recorder::dispatch_named`]
    /// places the named buffers by.
    ///
    /// [`Recorder::dispatch_named`]: super::Recorder::dispatch_named
    pub(crate) binding_names: &'static [&'static str],
}

/// The binding names `build.rs` found in the GLSL of the kernel whose SPIR-V is `spirv`.
fn declared_bindings(spirv: &[u8]) -> Option<&'static [&'static str]> {
    crate::shaders::BINDINGS
        .iter()
        .find(|(code, _)| code.len() == spirv.len() && *code == spirv)
        .map(|(_, names)| *names)
}

impl ComputePipeline {
    /// Builds a pipeline from SPIR-V bytes. `extra_constants` are specialisation constants with
    /// ids 2, 3, ... in order.
    pub fn new(
        ctx: &Arc<GpuContext>,
        name: &str,
        spirv: &[u8],
        num_buffers: u32,
        push_size: u32,
        workgroup_size: u32,
        extra_constants: &[u32],
    ) -> anyhow::Result<Self> {
        if push_size > ctx.info.max_push_constants {
            bail!(
                "kernel {name}: {push_size} bytes of push constants exceed the device limit {}",
                ctx.info.max_push_constants
            );
        }
        if num_buffers > ctx.info.max_storage_buffers {
            bail!(
                "kernel {name}: binds {num_buffers} storage buffers but this device allows {} a \
                 kernel (maxPerStageDescriptorStorageBuffers). Fix: use a device with a higher \
                 limit (desktop GPUs and lavapipe allow thousands or more)",
                ctx.info.max_storage_buffers
            );
        }
        if workgroup_size == 0 || workgroup_size > ctx.info.max_workgroup_invocations {
            bail!(
                "kernel {name}: workgroup size {workgroup_size} is outside 1..={}",
                ctx.info.max_workgroup_invocations
            );
        }
        let binding_names = declared_bindings(spirv).unwrap_or(&[]);
        if let Some(names) = declared_bindings(spirv) {
            if names.len() as u32 != num_buffers {
                bail!(
                    "kernel {name}: the Rust side binds {num_buffers} storage buffers, its GLSL \
                     declares {} ({}). Fix: make the two agree",
                    names.len(),
                    names.join(", ")
                );
            }
        }
        let device = &ctx.device;
        let code = ash::util::read_spv(&mut std::io::Cursor::new(spirv))
            .with_context(|| format!("kernel {name}: bad SPIR-V"))?;
        let module = unsafe {
            device.create_shader_module(&vk::ShaderModuleCreateInfo::default().code(&code), None)
        }
        .with_context(|| format!("kernel {name}: creating shader module"))?;

        let bindings: Vec<_> = (0..num_buffers)
            .map(|b| {
                vk::DescriptorSetLayoutBinding::default()
                    .binding(b)
                    .descriptor_type(vk::DescriptorType::STORAGE_BUFFER)
                    .descriptor_count(1)
                    .stage_flags(vk::ShaderStageFlags::COMPUTE)
            })
            .collect();
        let set_layout = unsafe {
            device.create_descriptor_set_layout(
                &vk::DescriptorSetLayoutCreateInfo::default()
                    .flags(vk::DescriptorSetLayoutCreateFlags::PUSH_DESCRIPTOR_KHR)
                    .bindings(&bindings),
                None,
            )
        }?;
        let ranges = [vk::PushConstantRange::default()
            .stage_flags(vk::ShaderStageFlags::COMPUTE)
            .offset(0)
            .size(push_size)];
        let set_layouts = [set_layout];
        let mut layout_info = vk::PipelineLayoutCreateInfo::default().set_layouts(&set_layouts);
        if push_size > 0 {
            layout_info = layout_info.push_constant_ranges(&ranges);
        }
        let layout = unsafe { device.create_pipeline_layout(&layout_info, None) }?;

        let mut values = vec![workgroup_size, ctx.info.subgroup_size];
        values.extend_from_slice(extra_constants);
        let entries: Vec<_> = (0..values.len() as u32)
            .map(|i| vk::SpecializationMapEntry {
                constant_id: i,
                offset: i * 4,
                size: 4,
            })
            .collect();
        let data: &[u8] = bytemuck::cast_slice(&values);
        let spec = vk::SpecializationInfo::default()
            .map_entries(&entries)
            .data(data);
        let entry = c"main";
        let stage = vk::PipelineShaderStageCreateInfo::default()
            .stage(vk::ShaderStageFlags::COMPUTE)
            .module(module)
            .name(entry)
            .specialization_info(&spec);
        let info = vk::ComputePipelineCreateInfo::default()
            .stage(stage)
            .layout(layout);
        let result =
            unsafe { device.create_compute_pipelines(vk::PipelineCache::null(), &[info], None) };
        unsafe { device.destroy_shader_module(module, None) };
        let pipeline = match result {
            Ok(p) => p[0],
            Err((_, e)) => {
                unsafe {
                    device.destroy_pipeline_layout(layout, None);
                    device.destroy_descriptor_set_layout(set_layout, None);
                }
                bail!("kernel {name}: creating compute pipeline failed: {e}");
            }
        };
        Ok(Self {
            ctx: ctx.clone(),
            pipeline,
            layout,
            set_layout,
            num_buffers,
            push_size,
            workgroup_size,
            name: name.to_string(),
            binding_names,
        })
    }
}

impl Drop for ComputePipeline {
    fn drop(&mut self) {
        // Destroyed now, or when the last `HoldFrees` guard goes (a recorded command buffer
        // may still be on the queue with it bound).
        super::held_frees::retire(
            &self.ctx,
            super::held_frees::Retired::Pipeline {
                pipeline: self.pipeline,
                layout: self.layout,
                set_layout: self.set_layout,
            },
        );
    }
}
