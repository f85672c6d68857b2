//! With no Vulkan driver visible, opening the GPU is a clear error, not a panic. (Its own test
//! binary: the loader reads these variables when the instance is created.)

use lpmsplat::gpu::{GpuContext, GpuOptions};

#[test]
fn no_vulkan_device_is_a_clear_error() {
    std::env::set_var("VK_ICD_FILENAMES", "/nonexistent/lpmsplat_no_icd.json");
    std::env::set_var("VK_DRIVER_FILES", "/nonexistent/lpmsplat_no_icd.json");
    let err = GpuContext::new(&GpuOptions {
        validation: false,
        device: None,
        memory_limit: None,
        sort_digit_bits: None,
    })
    .err()
    .expect("no device must be an error");
    let msg = format!("{err:#}");
    assert!(
        msg.contains("no usable Vulkan") && msg.contains("Fix:"),
        "{msg}"
    );
    assert!(
        msg.contains("mesa-vulkan-drivers"),
        "the fix names the package: {msg}"
    );
}
