//! Errors for bad input: every message names the file, the field and what to do about it.

use std::fmt;
use std::path::{Path, PathBuf};

/// A problem with something the user gave us (a file, a flag, a scene).
#[derive(Debug, Clone)]
pub struct InputError {
    /// The file (or folder) at fault.
    pub file: PathBuf,
    /// Where in the file: a field, a line, a property, an element index.
    pub field: String,
    /// What is wrong.
    pub problem: String,
    /// What the user can do about it.
    pub fix: String,
}

impl InputError {
    pub fn new(
        file: impl AsRef<Path>,
        field: impl Into<String>,
        problem: impl Into<String>,
        fix: impl Into<String>,
    ) -> Self {
        Self {
            file: file.as_ref().to_path_buf(),
            field: field.into(),
            problem: problem.into(),
            fix: fix.into(),
        }
    }
}

impl fmt::Display for InputError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(
            f,
            "{}: {}: {}. Fix: {}",
            self.file.display(),
            self.field,
            self.problem,
            self.fix
        )
    }
}

impl std::error::Error for InputError {}

/// Shorthand for returning an [`InputError`] wrapped in `anyhow`.
pub fn bad_input<T>(
    file: impl AsRef<Path>,
    field: impl Into<String>,
    problem: impl Into<String>,
    fix: impl Into<String>,
) -> anyhow::Result<T> {
    Err(InputError::new(file, field, problem, fix).into())
}

/// The text of `path`, or an input error naming the file that says it cannot be read as text,
/// with `fix`.
pub fn read_text(path: &Path, fix: &str) -> anyhow::Result<String> {
    match std::fs::read_to_string(path) {
        Ok(t) => Ok(t),
        Err(e) => bad_input(path, "file", format!("cannot be read as text: {e}"), fix),
    }
}

/// Writes a file atomically: to a temporary sibling first, then renamed over the target, so a
/// failed run never leaves a half-written file or destroys an existing one.
pub fn write_atomic(
    path: &Path,
    write: impl FnOnce(&mut std::fs::File) -> anyhow::Result<()>,
) -> anyhow::Result<()> {
    use anyhow::Context;
    let dir = path
        .parent()
        .filter(|p| !p.as_os_str().is_empty())
        .unwrap_or(Path::new("."));
    let name = path
        .file_name()
        .map(|n| n.to_string_lossy().to_string())
        .unwrap_or_default();
    let tmp = dir.join(format!(".{name}.tmp{}", std::process::id()));
    let result = (|| {
        let mut f = std::fs::File::create(&tmp).with_context(|| {
            format!("{}: cannot create (is the folder writable?)", tmp.display())
        })?;
        write(&mut f)?;
        f.sync_all().ok();
        Ok(())
    })();
    match result {
        Ok(()) => std::fs::rename(&tmp, path).with_context(|| {
            format!(
                "{}: cannot rename {} over it",
                path.display(),
                tmp.display()
            )
        }),
        Err(e) => {
            let _ = std::fs::remove_file(&tmp);
            Err(e)
        }
    }
}

/// Creates `out` and proves it writable before any work is done, so that a long run (`train`,
/// `bench trade`, `bench merge`) never fails at its end for want of a place to write.
pub fn prepare_output(out: &Path) -> anyhow::Result<()> {
    use anyhow::Context;
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
