//! Typed storage buffers through gpu-allocator.

use super::{GpuContext, OutOfDeviceMemory};
use anyhow::{bail, Context as _};
use ash::vk;
use bytemuck::Pod;
use gpu_allocator::vulkan::{Allocation, AllocationCreateDesc, AllocationScheme};
use gpu_allocator::MemoryLocation;
use std::marker::PhantomData;
use std::sync::Arc;

/// Where a buffer lives.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum BufferKind {
    /// Device-local: what kernels read and write.
    DeviceLocal,
    /// Host-visible, written by the CPU, read by the GPU.
    Upload,
    /// Host-visible, written by the GPU, read by the CPU.
    Readback,
}

/// `LPMSPLAT_BUFFER_LOG=FILE`: every device-local buffer allocated is appended to FILE as
/// `name<TAB>bytes` (which buffers hold the memory, and how they scale with the model:
/// `tests/cli/buffer_widths.rs` checks that none is wider than a binding allows).
fn log_allocation(name: &str, bytes: u64) {
    use std::io::Write as _;
    use std::sync::{Mutex, OnceLock};
    static LOG: OnceLock<Option<Mutex<std::fs::File>>> = OnceLock::new();
    let log = LOG.get_or_init(|| {
        let path = std::env::var_os("LPMSPLAT_BUFFER_LOG")?;
        match std::fs::OpenOptions::new()
            .create(true)
            .append(true)
            .open(&path)
        {
            Ok(file) => Some(Mutex::new(file)),
            Err(e) => {
                // A diagnostic that cannot be written must not stop the run.
                eprintln!(
                    "warning: LPMSPLAT_BUFFER_LOG={}: {e}; no buffer log is written. Fix: \
                     point it at a writable file",
                    path.to_string_lossy()
                );
                None
            }
        }
    });
    if let Some(file) = log {
        let _ = writeln!(file.lock().unwrap(), "{name}\t{bytes}");
    }
}

/// A buffer of `len` elements of `T`, usable as a storage buffer and as a transfer source and
/// destination. Zero-length buffers are allowed (one element is allocated, `len` stays 0).
pub struct GpuBuffer<T: Pod> {
    ctx: Arc<GpuContext>,
    pub(crate) buffer: vk::Buffer,
    allocation: Option<Allocation>,
    len: usize,
    kind: BufferKind,
    name: String,
    /// Device-local bytes booked in the context's [`DeviceMemory`](super::DeviceMemory).
    booked: u64,
    _t: PhantomData<T>,
}

impl<T: Pod> GpuBuffer<T> {
    /// Allocates a buffer of `len` elements. Storage buffers larger than the device's
    /// `maxStorageBufferRange` cannot be bound whole, so they are refused here with the limit.
    pub fn new(
        ctx: &Arc<GpuContext>,
        name: &str,
        len: usize,
        kind: BufferKind,
    ) -> anyhow::Result<Self> {
        let elem = std::mem::size_of::<T>() as u64;
        let bytes = (len.max(1) as u64)
            .checked_mul(elem)
            .context("buffer size overflows u64")?;
        if bytes > ctx.info.max_storage_buffer_range {
            bail!(
                "buffer '{name}' needs {} MiB but this device binds at most {} MiB per storage buffer (maxStorageBufferRange). Fix: lower the Gaussian count or image size, or use a device with a larger limit",
                bytes >> 20,
                ctx.info.max_storage_buffer_range >> 20
            );
        }
        let usage = vk::BufferUsageFlags::STORAGE_BUFFER
            | vk::BufferUsageFlags::TRANSFER_SRC
            | vk::BufferUsageFlags::TRANSFER_DST
            | vk::BufferUsageFlags::INDIRECT_BUFFER;
        let device = &ctx.device;
        let buffer = unsafe {
            device.create_buffer(
                &vk::BufferCreateInfo::default()
                    .size(bytes)
                    .usage(usage)
                    .sharing_mode(vk::SharingMode::EXCLUSIVE),
                None,
            )
        }
        .with_context(|| format!("creating buffer '{name}' ({bytes} bytes)"))?;
        let requirements = unsafe { device.get_buffer_memory_requirements(buffer) };
        // Device-local memory is booked first, so a run under --memory-limit fails here, with
        // the same typed error as a driver that is out of memory.
        let booked = if kind == BufferKind::DeviceLocal {
            log_allocation(name, bytes);
            if let Err(e) = ctx.memory.reserve(name, requirements.size) {
                unsafe { device.destroy_buffer(buffer, None) };
                return Err(e.into());
            }
            requirements.size
        } else {
            0
        };
        let location = match kind {
            BufferKind::DeviceLocal => MemoryLocation::GpuOnly,
            BufferKind::Upload => MemoryLocation::CpuToGpu,
            BufferKind::Readback => MemoryLocation::GpuToCpu,
        };
        let allocation = ctx
            .allocator
            .lock()
            .unwrap()
            .allocate(&AllocationCreateDesc {
                name,
                requirements,
                location,
                linear: true,
                allocation_scheme: AllocationScheme::GpuAllocatorManaged,
            });
        let allocation = match allocation {
            Ok(a) => a,
            Err(e) => {
                unsafe { device.destroy_buffer(buffer, None) };
                ctx.memory.release(booked);
                return Err(OutOfDeviceMemory {
                    buffer: name.to_string(),
                    bytes: requirements.size,
                    in_use: ctx.memory.in_use(),
                    limit: ctx.memory.limit(),
                    driver: Some(e.to_string()),
                }
                .into());
            }
        };
        if let Err(e) =
            unsafe { device.bind_buffer_memory(buffer, allocation.memory(), allocation.offset()) }
        {
            // Nothing of the failed buffer stays allocated or booked.
            unsafe { device.destroy_buffer(buffer, None) };
            let _ = ctx.allocator.lock().map(|mut al| al.free(allocation));
            ctx.memory.release(booked);
            return Err(e).with_context(|| format!("binding memory of '{name}'"));
        }
        Ok(Self {
            ctx: ctx.clone(),
            buffer,
            allocation: Some(allocation),
            len,
            kind,
            name: name.to_string(),
            booked,
            _t: PhantomData,
        })
    }

    /// A device-local buffer holding `data` (uploaded through a staging buffer).
    pub fn from_slice(ctx: &Arc<GpuContext>, name: &str, data: &[T]) -> anyhow::Result<Self> {
        let buf = Self::new(ctx, name, data.len(), BufferKind::DeviceLocal)?;
        buf.upload(data)?;
        Ok(buf)
    }

    pub fn len(&self) -> usize {
        self.len
    }
    pub fn is_empty(&self) -> bool {
        self.len == 0
    }
    pub fn kind(&self) -> BufferKind {
        self.kind
    }
    pub fn name(&self) -> &str {
        &self.name
    }
    /// Bytes of the elements (0 for an empty buffer).
    pub fn byte_len(&self) -> u64 {
        (self.len * std::mem::size_of::<T>()) as u64
    }
    /// Bytes allocated for binding (at least one element).
    pub(crate) fn bind_bytes(&self) -> u64 {
        (self.len.max(1) * std::mem::size_of::<T>()) as u64
    }
    pub fn handle(&self) -> vk::Buffer {
        self.buffer
    }

    /// Writes `data` at the start of the buffer. Host-visible buffers are written through the
    /// mapping; device-local ones through a staging buffer and a one-off submission (not for the
    /// per-iteration path).
    pub fn upload(&self, data: &[T]) -> anyhow::Result<()> {
        self.upload_at(0, data)
    }

    /// Writes `data` starting at element `first` (as [`GpuBuffer::upload`]). On a host-visible
    /// buffer the caller makes sure no submitted work still reads that range.
    pub fn upload_at(&self, first: usize, data: &[T]) -> anyhow::Result<()> {
        if first
            .checked_add(data.len())
            .is_none_or(|end| end > self.len)
        {
            bail!(
                "upload of {} elements at {first} into '{}' of {} elements",
                data.len(),
                self.name,
                self.len
            );
        }
        if data.is_empty() {
            return Ok(());
        }
        if let Some(mapped) = self.allocation.as_ref().and_then(|a| a.mapped_ptr()) {
            let bytes: &[u8] = bytemuck::cast_slice(data);
            unsafe {
                std::ptr::copy_nonoverlapping(
                    bytes.as_ptr(),
                    (mapped.as_ptr() as *mut u8).add(first * std::mem::size_of::<T>()),
                    bytes.len(),
                )
            };
            return Ok(());
        }
        let staging =
            GpuBuffer::<T>::new(&self.ctx, "staging upload", data.len(), BufferKind::Upload)?;
        staging.upload(data)?;
        let mut rec = super::Recorder::new(&self.ctx)?;
        rec.copy_region(&staging, 0, self, first, data.len());
        rec.submit_and_wait()?;
        Ok(())
    }

    /// Reads the whole buffer back (waits for nothing: call after the work that wrote it has
    /// completed).
    pub fn read(&self) -> anyhow::Result<Vec<T>> {
        self.read_range(0, self.len)
    }

    /// Reads `count` elements starting at `first`.
    pub fn read_range(&self, first: usize, count: usize) -> anyhow::Result<Vec<T>> {
        if first + count > self.len {
            bail!(
                "read of {}..{} from '{}' of {} elements",
                first,
                first + count,
                self.name,
                self.len
            );
        }
        let mut out = vec![T::zeroed(); count];
        if count == 0 {
            return Ok(out);
        }
        if let Some(mapped) = self.allocation.as_ref().and_then(|a| a.mapped_ptr()) {
            let bytes: &mut [u8] = bytemuck::cast_slice_mut(&mut out);
            let src =
                unsafe { (mapped.as_ptr() as *const u8).add(first * std::mem::size_of::<T>()) };
            unsafe { std::ptr::copy_nonoverlapping(src, bytes.as_mut_ptr(), bytes.len()) };
            return Ok(out);
        }
        let staging =
            GpuBuffer::<T>::new(&self.ctx, "staging readback", count, BufferKind::Readback)?;
        let mut rec = super::Recorder::new(&self.ctx)?;
        rec.copy_region(self, first, &staging, 0, count);
        rec.submit_and_wait()?;
        staging.read()
    }
}

impl<T: Pod> Drop for GpuBuffer<T> {
    fn drop(&mut self) {
        // Destroyed now, or when the last `HoldFrees` guard goes (work recorded against the
        // buffer may still be on the queue).
        super::held_frees::retire(
            &self.ctx,
            super::held_frees::Retired::Buffer {
                buffer: self.buffer,
                allocation: self.allocation.take(),
                booked: self.booked,
            },
        );
    }
}

/// Anything that can be bound as a storage buffer.
pub trait Bindable {
    fn vk_buffer(&self) -> vk::Buffer;
    fn range(&self) -> u64;
}

impl<T: Pod> Bindable for GpuBuffer<T> {
    fn vk_buffer(&self) -> vk::Buffer {
        self.buffer
    }
    fn range(&self) -> u64 {
        self.bind_bytes()
    }
}
