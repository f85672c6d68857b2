//! Instance, device selection and the single compute queue.

use super::memory::DeviceMemory;
use super::validation::{debug_callback, ValidationStats};
use anyhow::{anyhow, bail};
use ash::vk;
use gpu_allocator::vulkan::{Allocator, AllocatorCreateDesc};
use std::ffi::{CStr, CString};
use std::mem::ManuallyDrop;
use std::sync::{Arc, Mutex};

const VALIDATION_LAYER: &CStr = c"VK_LAYER_KHRONOS_validation";

/// How to open the GPU.
#[derive(Debug, Clone, Default)]
pub struct GpuOptions {
    /// Enable the Khronos validation layer (also enabled by `LPMSPLAT_VALIDATION=1`).
    pub validation: bool,
    /// Choose a device by index (as listed by `info`) or by a case-insensitive name substring.
    pub device: Option<String>,
    /// Refuse device-local allocations past this many bytes in all ([`DeviceMemory`]).
    pub memory_limit: Option<u64>,
    /// The radix sorts' digit width: 4 (4- and 5-bit passes) or 8 (ballot-ranked byte
    /// passes); `None`: the engine's choice for the device (`render::sort::Digits`).
    pub sort_digit_bits: Option<u32>,
}

impl GpuOptions {
    /// Options for tests: validation always on; `LPMSPLAT_DEVICE` picks the device.
    pub fn for_tests() -> Self {
        Self {
            validation: true,
            device: std::env::var("LPMSPLAT_DEVICE").ok(),
            memory_limit: None,
            sort_digit_bits: None,
        }
    }

    /// Options for benchmarks: validation off (it would be timed too); `LPMSPLAT_DEVICE` picks
    /// the device.
    pub fn for_benches() -> Self {
        Self {
            validation: false,
            ..Self::for_tests()
        }
    }
}

/// What the engine needs to know about the chosen device.
#[derive(Debug, Clone)]
pub struct DeviceInfo {
    pub index: usize,
    pub name: String,
    pub device_type: String,
    pub api_version: String,
    pub driver: String,
    pub subgroup_size: u32,
    pub min_subgroup_size: u32,
    pub max_subgroup_size: u32,
    pub max_storage_buffer_range: u64,
    pub max_memory_allocation_size: u64,
    pub max_shared_memory: u32,
    pub max_workgroup_invocations: u32,
    pub max_workgroup_count: [u32; 3],
    pub max_push_constants: u32,
    /// Storage buffers one kernel may bind (the smaller of the per-stage and per-set limits).
    pub max_storage_buffers: u32,
    pub timestamp_period_ns: f64,
    pub timestamps_supported: bool,
    pub float_atomic_add: bool,
    pub full_subgroups: bool,
    pub device_local_bytes: u64,
    /// The subgroup shuffle operations (`subgroupShuffle`, `subgroupShuffleXor`) in compute.
    pub subgroup_shuffle: bool,
}

impl DeviceInfo {
    /// A readable multi-line summary.
    pub fn summary(&self) -> String {
        format!(
            "device [{}] {} ({}), Vulkan {}, driver {}\n  subgroup size {} (range {}..{}), full-subgroup control: {}\n  max storage buffer range {} MiB, max allocation {} MiB, device-local memory {} MiB\n  shared memory {} KiB, workgroup invocations {}, workgroup count {:?}, push constants {} B, storage buffers a kernel {}\n  float32 atomic add: {}, subgroup shuffle: {}, timestamps: {} (period {} ns)",
            self.index,
            self.name,
            self.device_type,
            self.api_version,
            self.driver,
            self.subgroup_size,
            self.min_subgroup_size,
            self.max_subgroup_size,
            self.full_subgroups,
            self.max_storage_buffer_range >> 20,
            self.max_memory_allocation_size >> 20,
            self.device_local_bytes >> 20,
            self.max_shared_memory / 1024,
            self.max_workgroup_invocations,
            self.max_workgroup_count,
            self.max_push_constants,
            self.max_storage_buffers,
            self.float_atomic_add,
            self.subgroup_shuffle,
            self.timestamps_supported,
            self.timestamp_period_ns
        )
    }
}

/// The validation layer's messenger and the loader that destroys it.
type DebugMessenger = (ash::ext::debug_utils::Instance, vk::DebugUtilsMessengerEXT);

/// The Vulkan instance, the chosen device, its compute queue and the memory allocator.
pub struct GpuContext {
    pub(crate) entry: ash::Entry,
    pub(crate) instance: ash::Instance,
    debug: Option<DebugMessenger>,
    validation: Option<Arc<ValidationStats>>,
    pub physical: vk::PhysicalDevice,
    pub(crate) device: ash::Device,
    pub(crate) push_descriptor: ash::khr::push_descriptor::Device,
    pub(crate) queue: vk::Queue,
    pub(crate) queue_family: u32,
    pub(crate) command_pool: Mutex<vk::CommandPool>,
    pub(crate) queue_lock: Mutex<()>,
    pub(crate) allocator: ManuallyDrop<Mutex<Allocator>>,
    /// Device-local bytes in use and their limit.
    pub memory: DeviceMemory,
    pub info: DeviceInfo,
    /// Buffers dropped while a [`HoldFrees`](super::HoldFrees) guard lives.
    pub(crate) held_frees: Mutex<super::held_frees::HeldFrees>,
    /// [`GpuOptions::sort_digit_bits`].
    pub sort_digit_bits: Option<u32>,
}

fn device_type_name(t: vk::PhysicalDeviceType) -> &'static str {
    match t {
        vk::PhysicalDeviceType::DISCRETE_GPU => "discrete GPU",
        vk::PhysicalDeviceType::INTEGRATED_GPU => "integrated GPU",
        vk::PhysicalDeviceType::VIRTUAL_GPU => "virtual GPU",
        vk::PhysicalDeviceType::CPU => "CPU (software)",
        _ => "other",
    }
}

fn type_rank(t: vk::PhysicalDeviceType) -> u32 {
    match t {
        vk::PhysicalDeviceType::DISCRETE_GPU => 0,
        vk::PhysicalDeviceType::INTEGRATED_GPU => 1,
        vk::PhysicalDeviceType::VIRTUAL_GPU => 2,
        vk::PhysicalDeviceType::CPU => 3,
        _ => 4,
    }
}

fn version_string(v: u32) -> String {
    format!(
        "{}.{}.{}",
        vk::api_version_major(v),
        vk::api_version_minor(v),
        vk::api_version_patch(v)
    )
}

/// Serialises creating and destroying Vulkan instances and devices within the process. The
/// Vulkan spec allows them concurrently, but one run of the test suite (two test threads, each
/// opening and closing contexts) crashed once with SIGSEGV in a binary that does nothing else,
/// and lavapipe (Mesa 22.3) sets up process-wide LLVM state when an instance or device is
/// created. Contexts are opened once per run, so holding a lock costs nothing.
fn lifecycle_lock() -> std::sync::MutexGuard<'static, ()> {
    static LOCK: std::sync::Mutex<()> = std::sync::Mutex::new(());
    LOCK.lock().unwrap_or_else(|poisoned| poisoned.into_inner())
}

/// One line per Vulkan device: (index, name, type, api version).
pub fn list_devices() -> anyhow::Result<Vec<(usize, String, String, String)>> {
    let entry = load_entry()?;
    let _serial = lifecycle_lock();
    let app = vk::ApplicationInfo::default().api_version(vk::API_VERSION_1_3);
    let instance = unsafe {
        entry.create_instance(
            &vk::InstanceCreateInfo::default().application_info(&app),
            None,
        )
    }
    .map_err(|e| no_vulkan(format!("vkCreateInstance failed: {e}")))?;
    let out = unsafe {
        let devices = instance.enumerate_physical_devices().unwrap_or_default();
        let out = devices
            .iter()
            .enumerate()
            .map(|(i, &d)| {
                let p = instance.get_physical_device_properties(d);
                let name = CStr::from_ptr(p.device_name.as_ptr())
                    .to_string_lossy()
                    .into_owned();
                (
                    i,
                    name,
                    device_type_name(p.device_type).to_string(),
                    version_string(p.api_version),
                )
            })
            .collect();
        instance.destroy_instance(None);
        out
    };
    Ok(out)
}

fn no_vulkan(detail: String) -> anyhow::Error {
    anyhow!(
        "no usable Vulkan: {detail}. Fix: install a Vulkan driver and loader (on Debian/Ubuntu without a GPU: `apt-get install libvulkan1 mesa-vulkan-drivers` for lavapipe), or pick another device with --device"
    )
}

fn load_entry() -> anyhow::Result<ash::Entry> {
    unsafe { ash::Entry::load() }.map_err(|e| {
        no_vulkan(format!(
            "cannot load the Vulkan loader (libvulkan.so.1): {e}"
        ))
    })
}

impl GpuContext {
    /// Opens the device chosen by `opts` (see [`GpuOptions`]).
    pub fn new(opts: &GpuOptions) -> anyhow::Result<Arc<GpuContext>> {
        let validation = opts.validation
            || std::env::var("LPMSPLAT_VALIDATION")
                .map(|v| v != "0" && !v.is_empty())
                .unwrap_or(false);
        let entry = load_entry()?;
        let _serial = lifecycle_lock();
        if let Some(bits) = opts.sort_digit_bits {
            anyhow::ensure!(
                bits == 4 || bits == 8,
                "sort digits {bits}: the radix sorts take 4- or 8-bit digits. Fix: pass 4 or 8"
            );
        }
        unsafe { Self::create(entry, validation, opts) }
    }

    unsafe fn create(
        entry: ash::Entry,
        validation: bool,
        opts: &GpuOptions,
    ) -> anyhow::Result<Arc<GpuContext>> {
        let (choose, memory_limit) = (opts.device.as_deref(), opts.memory_limit);
        let (instance, debug, stats) = Self::create_instance(&entry, validation)?;

        // On an error before the device exists: the messenger, then the instance.
        let teardown = || {
            if let Some((loader, m)) = &debug {
                loader.destroy_debug_utils_messenger(*m, None);
            }
            instance.destroy_instance(None);
        };
        let result = Self::open_device(&entry, &instance, choose);
        let (physical, index, queue_family) = match result {
            Ok(v) => v,
            Err(e) => {
                teardown();
                return Err(e);
            }
        };

        // Device features: subgroup size control and float atomics where present.
        let mut f11 = vk::PhysicalDeviceVulkan11Features::default();
        let mut f12 = vk::PhysicalDeviceVulkan12Features::default();
        let mut f13 = vk::PhysicalDeviceVulkan13Features::default();
        let mut fatomic = vk::PhysicalDeviceShaderAtomicFloatFeaturesEXT::default();
        let dev_exts = instance
            .enumerate_device_extension_properties(physical)
            .unwrap_or_default();
        let has_ext = |n: &CStr| {
            dev_exts
                .iter()
                .any(|e| CStr::from_ptr(e.extension_name.as_ptr()) == n)
        };
        if !has_ext(ash::khr::push_descriptor::NAME) {
            teardown();
            bail!("the Vulkan device lacks VK_KHR_push_descriptor, which this engine needs. Fix: choose another device with --device");
        }
        let has_atomic_float = has_ext(ash::ext::shader_atomic_float::NAME);
        {
            let mut q = vk::PhysicalDeviceFeatures2::default()
                .push_next(&mut f11)
                .push_next(&mut f12)
                .push_next(&mut f13);
            if has_atomic_float {
                q = q.push_next(&mut fatomic);
            }
            instance.get_physical_device_features2(physical, &mut q);
        }
        let base_features = instance.get_physical_device_features(physical);
        let float_atomic_add =
            has_atomic_float && fatomic.shader_buffer_float32_atomic_add == vk::TRUE;
        let full_subgroups =
            f13.subgroup_size_control == vk::TRUE && f13.compute_full_subgroups == vk::TRUE;

        let mut en12 = vk::PhysicalDeviceVulkan12Features::default()
            .shader_int8(f12.shader_int8 == vk::TRUE)
            .storage_buffer8_bit_access(f12.storage_buffer8_bit_access == vk::TRUE)
            .shader_float16(f12.shader_float16 == vk::TRUE)
            .host_query_reset(f12.host_query_reset == vk::TRUE)
            .timeline_semaphore(f12.timeline_semaphore == vk::TRUE);
        let mut en11 = vk::PhysicalDeviceVulkan11Features::default()
            .storage_buffer16_bit_access(f11.storage_buffer16_bit_access == vk::TRUE);
        let mut en13 = vk::PhysicalDeviceVulkan13Features::default()
            .subgroup_size_control(f13.subgroup_size_control == vk::TRUE)
            .compute_full_subgroups(f13.compute_full_subgroups == vk::TRUE)
            .synchronization2(f13.synchronization2 == vk::TRUE);
        let mut enatomic = vk::PhysicalDeviceShaderAtomicFloatFeaturesEXT::default()
            .shader_buffer_float32_atomics(fatomic.shader_buffer_float32_atomics == vk::TRUE)
            .shader_buffer_float32_atomic_add(float_atomic_add)
            .shader_shared_float32_atomics(fatomic.shader_shared_float32_atomics == vk::TRUE)
            .shader_shared_float32_atomic_add(fatomic.shader_shared_float32_atomic_add == vk::TRUE);
        let en_base = vk::PhysicalDeviceFeatures::default()
            .shader_int64(base_features.shader_int64 == vk::TRUE);
        let mut ext_names = vec![ash::khr::push_descriptor::NAME.as_ptr()];
        if has_atomic_float {
            ext_names.push(ash::ext::shader_atomic_float::NAME.as_ptr());
        }
        let priorities = [1.0f32];
        let queue_infos = [vk::DeviceQueueCreateInfo::default()
            .queue_family_index(queue_family)
            .queue_priorities(&priorities)];
        let mut dci = vk::DeviceCreateInfo::default()
            .queue_create_infos(&queue_infos)
            .enabled_extension_names(&ext_names)
            .enabled_features(&en_base)
            .push_next(&mut en11)
            .push_next(&mut en12)
            .push_next(&mut en13);
        if has_atomic_float {
            dci = dci.push_next(&mut enatomic);
        }
        let device = match instance.create_device(physical, &dci, None) {
            Ok(d) => d,
            Err(e) => {
                teardown();
                bail!("vkCreateDevice failed: {e}. Fix: update the Vulkan driver or choose another device with --device");
            }
        };
        let queue = device.get_device_queue(queue_family, 0);
        let push_descriptor = ash::khr::push_descriptor::Device::new(&instance, &device);
        // On an error once the device exists: the device, then the messenger and the instance
        // (the order `Drop` keeps), so that a caller who goes on holds nothing of this one.
        let pool = match device.create_command_pool(
            &vk::CommandPoolCreateInfo::default()
                .queue_family_index(queue_family)
                .flags(vk::CommandPoolCreateFlags::RESET_COMMAND_BUFFER),
            None,
        ) {
            Ok(p) => p,
            Err(e) => {
                device.destroy_device(None);
                teardown();
                return Err(anyhow::Error::new(e).context("creating command pool"));
            }
        };
        let allocator = match Allocator::new(&AllocatorCreateDesc {
            instance: instance.clone(),
            device: device.clone(),
            physical_device: physical,
            debug_settings: Default::default(),
            buffer_device_address: false,
            allocation_sizes: Default::default(),
        }) {
            Ok(a) => a,
            Err(e) => {
                device.destroy_command_pool(pool, None);
                device.destroy_device(None);
                teardown();
                return Err(anyhow::Error::new(e).context("creating the GPU memory allocator"));
            }
        };

        let info = Self::query_info(
            &instance,
            physical,
            index,
            queue_family,
            float_atomic_add,
            full_subgroups,
        );
        Ok(Arc::new(GpuContext {
            entry,
            instance,
            debug,
            validation: stats,
            physical,
            device,
            push_descriptor,
            queue,
            queue_family,
            command_pool: Mutex::new(pool),
            queue_lock: Mutex::new(()),
            allocator: ManuallyDrop::new(Mutex::new(allocator)),
            memory: DeviceMemory::new(memory_limit),
            info,
            held_frees: Mutex::new(Default::default()),
            sort_digit_bits: opts.sort_digit_bits,
        }))
    }

    /// The Vulkan instance, with the Khronos validation layer (synchronisation validation on)
    /// and a messenger counting its messages when `validation` is set.
    unsafe fn create_instance(
        entry: &ash::Entry,
        validation: bool,
    ) -> anyhow::Result<(
        ash::Instance,
        Option<DebugMessenger>,
        Option<Arc<ValidationStats>>,
    )> {
        let app_name = CString::new("lpmsplat").unwrap();
        let app = vk::ApplicationInfo::default()
            .application_name(&app_name)
            .engine_name(&app_name)
            .api_version(vk::API_VERSION_1_3);
        let mut layers: Vec<*const i8> = Vec::new();
        let mut extensions: Vec<*const i8> = Vec::new();
        let stats = if validation {
            let available = entry
                .enumerate_instance_layer_properties()
                .unwrap_or_default();
            let found = available
                .iter()
                .any(|l| CStr::from_ptr(l.layer_name.as_ptr()) == VALIDATION_LAYER);
            if !found {
                bail!(
                    "validation was requested but the Khronos validation layer (VK_LAYER_KHRONOS_validation) is not installed. Fix: `apt-get install vulkan-validationlayers`, or run without --validation / LPMSPLAT_VALIDATION"
                );
            }
            layers.push(VALIDATION_LAYER.as_ptr());
            extensions.push(ash::ext::debug_utils::NAME.as_ptr());
            Some(Arc::new(ValidationStats::default()))
        } else {
            None
        };
        // Synchronisation validation catches missing barriers: the bugs a compute engine makes.
        let enables = [vk::ValidationFeatureEnableEXT::SYNCHRONIZATION_VALIDATION];
        let mut features =
            vk::ValidationFeaturesEXT::default().enabled_validation_features(&enables);
        let mut create = vk::InstanceCreateInfo::default()
            .application_info(&app)
            .enabled_layer_names(&layers)
            .enabled_extension_names(&extensions);
        if validation {
            create = create.push_next(&mut features);
        }
        let instance = entry
            .create_instance(&create, None)
            .map_err(|e| no_vulkan(format!("vkCreateInstance failed: {e}")))?;

        let debug = if let Some(stats) = &stats {
            let loader = ash::ext::debug_utils::Instance::new(entry, &instance);
            let info = vk::DebugUtilsMessengerCreateInfoEXT::default()
                .message_severity(
                    vk::DebugUtilsMessageSeverityFlagsEXT::ERROR
                        | vk::DebugUtilsMessageSeverityFlagsEXT::WARNING,
                )
                .message_type(
                    vk::DebugUtilsMessageTypeFlagsEXT::GENERAL
                        | vk::DebugUtilsMessageTypeFlagsEXT::VALIDATION
                        | vk::DebugUtilsMessageTypeFlagsEXT::PERFORMANCE,
                )
                .pfn_user_callback(Some(debug_callback))
                .user_data(Arc::as_ptr(stats) as *mut std::ffi::c_void);
            let messenger = match loader.create_debug_utils_messenger(&info, None) {
                Ok(m) => m,
                Err(e) => {
                    instance.destroy_instance(None);
                    bail!("creating the validation layer's debug messenger: {e}");
                }
            };
            Some((loader, messenger))
        } else {
            None
        };
        Ok((instance, debug, stats))
    }

    unsafe fn open_device(
        _entry: &ash::Entry,
        instance: &ash::Instance,
        choose: Option<&str>,
    ) -> anyhow::Result<(vk::PhysicalDevice, usize, u32)> {
        let devices = instance
            .enumerate_physical_devices()
            .map_err(|e| no_vulkan(format!("vkEnumeratePhysicalDevices failed: {e}")))?;
        if devices.is_empty() {
            return Err(no_vulkan("the loader found no Vulkan device".into()));
        }
        let props: Vec<_> = devices
            .iter()
            .map(|&d| instance.get_physical_device_properties(d))
            .collect();
        let names: Vec<String> = props
            .iter()
            .map(|p| {
                CStr::from_ptr(p.device_name.as_ptr())
                    .to_string_lossy()
                    .into_owned()
            })
            .collect();
        let listing = names
            .iter()
            .enumerate()
            .map(|(i, n)| format!("[{i}] {n}"))
            .collect::<Vec<_>>()
            .join(", ");
        let compute_family = |d: vk::PhysicalDevice| -> Option<u32> {
            instance
                .get_physical_device_queue_family_properties(d)
                .iter()
                .position(|q| q.queue_flags.contains(vk::QueueFlags::COMPUTE))
                .map(|i| i as u32)
        };
        let index = match choose {
            Some(sel) if !sel.is_empty() => {
                if let Ok(i) = sel.parse::<usize>() {
                    if i >= devices.len() {
                        bail!("--device {i}: no such device (devices: {listing}). Fix: pass an index or a name from this list");
                    }
                    i
                } else {
                    let lower = sel.to_lowercase();
                    names.iter().position(|n| n.to_lowercase().contains(&lower)).ok_or_else(|| {
                        anyhow!("--device {sel:?}: no device name contains it (devices: {listing}). Fix: pass an index or a name from this list")
                    })?
                }
            }
            _ => {
                let mut order: Vec<usize> = (0..devices.len()).collect();
                order.sort_by_key(|&i| {
                    (
                        props[i].api_version < vk::API_VERSION_1_3,
                        type_rank(props[i].device_type),
                        i,
                    )
                });
                order
                    .into_iter()
                    .find(|&i| compute_family(devices[i]).is_some())
                    .ok_or_else(|| {
                        no_vulkan(format!(
                            "no device has a compute queue (devices: {listing})"
                        ))
                    })?
            }
        };
        if props[index].api_version < vk::API_VERSION_1_3 {
            bail!(
                "device [{index}] {} supports Vulkan {} but this engine needs 1.3. Fix: update the driver or choose another device with --device",
                names[index],
                version_string(props[index].api_version)
            );
        }
        let family = compute_family(devices[index]).ok_or_else(|| {
            anyhow!(
                "device [{index}] {} has no compute queue. Fix: choose another with --device",
                names[index]
            )
        })?;
        Ok((devices[index], index, family))
    }

    unsafe fn query_info(
        instance: &ash::Instance,
        physical: vk::PhysicalDevice,
        index: usize,
        queue_family: u32,
        float_atomic_add: bool,
        full_subgroups: bool,
    ) -> DeviceInfo {
        let mut subgroup = vk::PhysicalDeviceSubgroupProperties::default();
        let mut size_control = vk::PhysicalDeviceSubgroupSizeControlProperties::default();
        let mut driver = vk::PhysicalDeviceDriverProperties::default();
        let mut maint3 = vk::PhysicalDeviceMaintenance3Properties::default();
        let mut props2 = vk::PhysicalDeviceProperties2::default()
            .push_next(&mut subgroup)
            .push_next(&mut size_control)
            .push_next(&mut driver)
            .push_next(&mut maint3);
        instance.get_physical_device_properties2(physical, &mut props2);
        let p = props2.properties;
        let limits = p.limits;
        let families = instance.get_physical_device_queue_family_properties(physical);
        let ts_bits = families
            .get(queue_family as usize)
            .map(|f| f.timestamp_valid_bits)
            .unwrap_or(0);
        let mem = instance.get_physical_device_memory_properties(physical);
        let device_local_bytes = mem.memory_heaps[..mem.memory_heap_count as usize]
            .iter()
            .filter(|h| h.flags.contains(vk::MemoryHeapFlags::DEVICE_LOCAL))
            .map(|h| h.size)
            .max()
            .unwrap_or(0);
        DeviceInfo {
            index,
            name: CStr::from_ptr(p.device_name.as_ptr())
                .to_string_lossy()
                .into_owned(),
            device_type: device_type_name(p.device_type).to_string(),
            api_version: version_string(p.api_version),
            driver: format!(
                "{} {}",
                CStr::from_ptr(driver.driver_name.as_ptr()).to_string_lossy(),
                CStr::from_ptr(driver.driver_info.as_ptr()).to_string_lossy()
            ),
            subgroup_size: subgroup.subgroup_size,
            min_subgroup_size: size_control.min_subgroup_size.max(1),
            max_subgroup_size: size_control.max_subgroup_size.max(subgroup.subgroup_size),
            max_storage_buffer_range: limits.max_storage_buffer_range as u64,
            max_memory_allocation_size: maint3.max_memory_allocation_size,
            max_shared_memory: limits.max_compute_shared_memory_size,
            max_workgroup_invocations: limits.max_compute_work_group_invocations,
            max_workgroup_count: limits.max_compute_work_group_count,
            max_push_constants: limits.max_push_constants_size,
            max_storage_buffers: limits
                .max_per_stage_descriptor_storage_buffers
                .min(limits.max_descriptor_set_storage_buffers),
            timestamp_period_ns: limits.timestamp_period as f64,
            // The compute queue's timestampValidBits is what matters for a compute-only engine.
            timestamps_supported: ts_bits > 0,
            float_atomic_add,
            full_subgroups,
            device_local_bytes,
            subgroup_shuffle: subgroup
                .supported_operations
                .contains(vk::SubgroupFeatureFlags::SHUFFLE)
                && subgroup
                    .supported_stages
                    .contains(vk::ShaderStageFlags::COMPUTE),
        }
    }

    /// Validation messages counted so far (None when validation is off).
    pub fn validation(&self) -> Option<&ValidationStats> {
        self.validation.as_deref()
    }

    /// Number of validation errors so far (0 when validation is off).
    pub fn validation_errors(&self) -> u32 {
        self.validation.as_ref().map(|v| v.errors()).unwrap_or(0)
    }

    /// Fails with the messages when the validation layer reported any error.
    pub fn check_validation(&self) -> anyhow::Result<()> {
        if let Some(v) = &self.validation {
            if v.errors() > 0 {
                bail!(
                    "{} Vulkan validation error(s):\n{}",
                    v.errors(),
                    v.messages().join("\n")
                );
            }
        }
        Ok(())
    }

    /// Groups for a 1D dispatch of `n` invocations with workgroups of `wg`, spilling into y
    /// when x would pass the device limit.
    pub fn groups_1d(&self, n: u64, wg: u32) -> [u32; 3] {
        let groups = n.div_ceil(wg as u64).max(1);
        let max_x = self.info.max_workgroup_count[0] as u64;
        if groups <= max_x {
            [groups as u32, 1, 1]
        } else {
            let y = groups.div_ceil(max_x);
            [groups.div_ceil(y) as u32, y as u32, 1]
        }
    }

    /// Waits until the device is idle (used at teardown and at explicit sync points only).
    /// GPU memory held by the allocator: (bytes in live allocations, bytes of device memory
    /// blocks). The second is what the device is actually charged.
    pub fn memory_in_use(&self) -> (u64, u64) {
        let r = self.allocator.lock().unwrap().generate_report();
        (r.total_allocated_bytes, r.total_capacity_bytes)
    }

    pub fn wait_idle(&self) {
        unsafe {
            let _ = self.device.device_wait_idle();
        }
    }

    pub fn device(&self) -> &ash::Device {
        &self.device
    }
}

impl Drop for GpuContext {
    fn drop(&mut self) {
        let _serial = lifecycle_lock();
        unsafe {
            let _ = self.device.device_wait_idle();
            let held = self
                .held_frees
                .get_mut()
                .map(|h| std::mem::take(&mut h.retired))
                .unwrap_or_default();
            for r in held {
                super::held_frees::destroy(self, r);
            }
            ManuallyDrop::drop(&mut self.allocator);
            if let Ok(pool) = self.command_pool.lock() {
                self.device.destroy_command_pool(*pool, None);
            }
            self.device.destroy_device(None);
            if let Some((loader, m)) = &self.debug {
                loader.destroy_debug_utils_messenger(*m, None);
            }
            self.instance.destroy_instance(None);
        }
        let _ = &self.entry;
    }
}
