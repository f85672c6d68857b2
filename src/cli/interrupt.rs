//! Ctrl-C (SIGINT) as a flag: the training loop polls it between iterations, so the current
//! iteration finishes and the run can save a checkpoint before exiting. A second Ctrl-C while
//! the first is pending falls back to the default action (the process ends at once).

use std::sync::atomic::{AtomicBool, Ordering};

static REQUESTED: AtomicBool = AtomicBool::new(false);

extern "C" fn on_sigint(_: libc::c_int) {
    // Only async-signal-safe work here: an atomic store, and restoring the default handler.
    REQUESTED.store(true, Ordering::SeqCst);
    unsafe {
        libc::signal(libc::SIGINT, libc::SIG_DFL);
    }
}

/// Installs the handler (idempotent).
pub fn install() {
    let handler: extern "C" fn(libc::c_int) = on_sigint;
    unsafe {
        libc::signal(libc::SIGINT, handler as libc::sighandler_t);
    }
}

/// Whether Ctrl-C was pressed since `install`.
pub fn requested() -> bool {
    REQUESTED.load(Ordering::SeqCst)
}
