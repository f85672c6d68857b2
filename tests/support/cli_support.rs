//! Running the `lpmsplat` binary from a test: the validation layer on, and its output kept for
//! the assertion messages.
#![allow(dead_code)] // each test binary uses part of this module

use std::process::Command;

/// The binary under test, with the validation layer on (any validation error fails the run).
pub fn lpmsplat() -> Command {
    let mut c = Command::new(env!("CARGO_BIN_EXE_lpmsplat"));
    c.env("LPMSPLAT_VALIDATION", "1");
    c
}

/// Runs `c`: whether it succeeded, and its standard output and error together.
pub fn run(c: &mut Command) -> (bool, String) {
    let out = c.output().unwrap();
    let text = format!(
        "{}{}",
        String::from_utf8_lossy(&out.stdout),
        String::from_utf8_lossy(&out.stderr)
    );
    (out.status.success(), text)
}

/// Runs `c`, which must succeed; its output.
pub fn run_ok(c: &mut Command) -> String {
    let (ok, text) = run(c);
    assert!(ok, "{c:?} failed:\n{text}");
    text
}
