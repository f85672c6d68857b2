//! Ctrl-C (SIGINT) and SIGTERM as a flag: the training loop polls it between iterations, so
//! the current iteration finishes and the run can save a checkpoint before exiting. SIGTERM is
//! what a scheduler sends first when it pre-empts a job or its time is up (Slurm, then SIGKILL
//! after its KillWait, 30 s by default), so a Slurm task resumes from where it was stopped. A
//! second signal while the first is pending falls back to the default action (the process
//! ends at once).

use std::sync::atomic::{AtomicBool, Ordering};

static REQUESTED: AtomicBool = AtomicBool::new(false);

extern "C" fn on_signal(signal: libc::c_int) {
    // Only async-signal-safe work here: an atomic store, and restoring the default handler.
    REQUESTED.store(true, Ordering::SeqCst);
    unsafe {
        libc::signal(signal, libc::SIG_DFL);
    }
}

/// Installs the handler for SIGINT and SIGTERM (idempotent).
pub fn install() {
    let handler: extern "C" fn(libc::c_int) = on_signal;
    unsafe {
        libc::signal(libc::SIGINT, handler as libc::sighandler_t);
        libc::signal(libc::SIGTERM, handler as libc::sighandler_t);
    }
}

/// Whether Ctrl-C was pressed since `install`.
pub fn requested() -> bool {
    REQUESTED.load(Ordering::SeqCst)
}
