//! Re-running tests of this test binary in a child process, under driver variables that must be
//! set before the driver loads: one lavapipe thread (a fixed order for float atomics, so
//! identical runs are bitwise equal) and lavapipe subgroups of 16 (lavapipe's default is 8).
//! Other drivers ignore both variables.
#![allow(dead_code)] // each test binary uses part of this module

/// Set in every child, so a test that re-runs itself does not recurse.
const CHILD: &str = "LPMSPLAT_CHILD";

/// Whether this process is such a child.
pub fn is_child() -> bool {
    std::env::var_os(CHILD).is_some()
}

/// Runs this test binary again with `env` set, on one test thread, with `args` (test name
/// filters, `--exact`), and asserts that the child passed exactly `expected` tests.
pub fn run_child(env: &[(&str, &str)], args: &[&str], expected: usize) {
    let out = std::process::Command::new(std::env::current_exe().unwrap())
        .envs(env.iter().copied())
        .env(CHILD, "1")
        .arg("--test-threads=1")
        .args(args)
        .output()
        .unwrap();
    let text =
        String::from_utf8_lossy(&out.stdout).to_string() + &String::from_utf8_lossy(&out.stderr);
    assert!(out.status.success(), "child run failed:\n{text}");
    assert!(
        text.contains(&format!("{expected} passed")),
        "child ran the wrong tests:\n{text}"
    );
}

/// Bitwise comparisons need a deterministic backward: lavapipe's float atomics add in a
/// thread-dependent order unless it runs one thread (see the trainer's determinism docs). Unless
/// this process already runs with LP_NUM_THREADS=1, re-runs test `name` in a child that does,
/// asserts it passed, and returns true: the caller returns.
pub fn rerun_single_threaded(name: &str) -> bool {
    if std::env::var("LP_NUM_THREADS").as_deref() == Ok("1") {
        return false;
    }
    run_child(&[("LP_NUM_THREADS", "1")], &["--exact", name], 1);
    true
}

/// Runs the tests named by `filters` (one test each) in a child where lavapipe's subgroups are
/// 16 wide (LP_NATIVE_VECTOR_WIDTH=512), so subgroup code is covered at two sizes; nothing when
/// this process is itself a child.
pub fn rerun_under_subgroup_size_16(filters: &[&str]) {
    if is_child() {
        return;
    }
    run_child(&[("LP_NATIVE_VECTOR_WIDTH", "512")], filters, filters.len());
}
