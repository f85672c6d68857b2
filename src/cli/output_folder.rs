//! The output folder every command that writes one (`train`, `bench trade`, `bench merge`)
//! prepares before any work is done.

use anyhow::Context;
use std::path::Path;

/// Creates `out` and proves it writable before any work is done.
pub fn prepare_output(out: &Path) -> anyhow::Result<()> {
    std::fs::create_dir_all(out).with_context(|| {
        format!(
            "{}: cannot create the output folder. Fix: choose a writable --out",
            out.display()
        )
    })?;
    let probe = out.join(".lpmsplat-write-test");
    std::fs::write(&probe, b"ok").with_context(|| {
        format!(
            "{}: the output folder is not writable. Fix: choose a writable --out",
            out.display()
        )
    })?;
    let _ = std::fs::remove_file(probe);
    Ok(())
}
