//! The Khronos validation layer reports through a debug messenger and never changes an exit code
//! by itself, so every message is counted here and tests assert that the error count is zero.

use ash::vk;
use std::ffi::CStr;
use std::sync::atomic::{AtomicU32, Ordering};
use std::sync::Mutex;

/// Counts of validation messages seen by one instance.
#[derive(Default, Debug)]
pub struct ValidationStats {
    errors: AtomicU32,
    warnings: AtomicU32,
    messages: Mutex<Vec<String>>,
}

impl ValidationStats {
    pub fn errors(&self) -> u32 {
        self.errors.load(Ordering::SeqCst)
    }
    pub fn warnings(&self) -> u32 {
        self.warnings.load(Ordering::SeqCst)
    }
    /// The first messages (errors and warnings), for test failure output.
    pub fn messages(&self) -> Vec<String> {
        self.messages.lock().map(|m| m.clone()).unwrap_or_default()
    }
}

/// Messages the layer emits that are not about our usage (loader chatter, performance advice
/// on lavapipe that does not apply to compute). Matched on the message id name.
const IGNORED_IDS: &[&str] = &["Loader Message"];

pub(crate) unsafe extern "system" fn debug_callback(
    severity: vk::DebugUtilsMessageSeverityFlagsEXT,
    _types: vk::DebugUtilsMessageTypeFlagsEXT,
    data: *const vk::DebugUtilsMessengerCallbackDataEXT<'_>,
    user: *mut std::ffi::c_void,
) -> vk::Bool32 {
    if data.is_null() || user.is_null() {
        return vk::FALSE;
    }
    let stats = &*(user as *const ValidationStats);
    let data = &*data;
    let id = if data.p_message_id_name.is_null() {
        String::new()
    } else {
        CStr::from_ptr(data.p_message_id_name)
            .to_string_lossy()
            .into_owned()
    };
    if IGNORED_IDS.iter().any(|i| id.contains(i)) {
        return vk::FALSE;
    }
    let text = if data.p_message.is_null() {
        String::new()
    } else {
        CStr::from_ptr(data.p_message)
            .to_string_lossy()
            .into_owned()
    };
    let is_error = severity.contains(vk::DebugUtilsMessageSeverityFlagsEXT::ERROR);
    let is_warning = severity.contains(vk::DebugUtilsMessageSeverityFlagsEXT::WARNING);
    if is_error {
        stats.errors.fetch_add(1, Ordering::SeqCst);
    } else if is_warning {
        stats.warnings.fetch_add(1, Ordering::SeqCst);
    } else {
        return vk::FALSE;
    }
    let line = format!(
        "[{}] {id}: {text}",
        if is_error { "error" } else { "warning" }
    );
    if is_error || std::env::var_os("LPMSPLAT_VALIDATION_VERBOSE").is_some() {
        eprintln!("vulkan validation {line}");
    }
    if let Ok(mut m) = stats.messages.lock() {
        if m.len() < 64 {
            m.push(line);
        }
    }
    vk::FALSE
}
