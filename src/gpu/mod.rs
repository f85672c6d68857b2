//! The Vulkan layer on `ash`: instance and device selection, buffers through gpu-allocator,
//! compute pipelines from the embedded SPIR-V, command recording with explicit barriers, and GPU
//! timestamps for per-stage times.
//!
//! Conventions every kernel follows:
//! - Buffers are bound as storage buffers of set 0 (bindings 0..n) through push descriptors.
//! - Specialisation constant 0 is the workgroup size in x; constant 1 is the device's subgroup
//!   size (read from the device, never assumed). Kernels with more constants number them from 2.
//! - Large 1D dispatches spread over y when x would pass `maxComputeWorkGroupCount[0]`; kernels
//!   compute their linear index as `gl_WorkGroupID.x + gl_WorkGroupID.y * gl_NumWorkGroups.x`.

mod buffer;
mod commands;
mod context;
mod held_frees;
mod memory;
mod pipeline;
mod timestamps;
mod validation;

pub use buffer::{Bindable, BufferKind, GpuBuffer};
pub use commands::Recorder;
pub use context::{list_devices, DeviceInfo, GpuContext, GpuOptions};
pub use held_frees::HoldFrees;
pub use memory::{out_of_memory, DeviceMemory, OutOfDeviceMemory};
pub use pipeline::ComputePipeline;
pub use timestamps::{StageTimes, TimestampPool};
pub use validation::ValidationStats;
