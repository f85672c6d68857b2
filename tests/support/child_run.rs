//! Re-running tests of this test binary in a child process, under driver variables that must be
//! set before the driver loads: one lavapipe thread (a fixed order for float atomics, so
//! identical runs are bitwise equal) and lavapipe subgroups of 16 (lavapipe's default is 8).
//! Other drivers ignore both variables.
#![allow(dead_code)] // each test crate uses part of this module

/// Set in every child, so a test that re-runs itself does not recurse.
const CHILD: &str = "LPMSPLAT_CHILD";

/// Whether this process is such a child.
pub fn is_child() -> bool {
    std::env::var_os(CHILD).is_some()
}

/// A test's name as the harness of a grouped test crate knows it: `module` is the caller's
/// `module_path!()` (`crate::file_module`), whose crate segment the harness leaves out.
pub fn test_path(module: &str, name: &str) -> String {
    match module.split_once("::") {
        Some((_, inner)) => format!("{inner}::{name}"),
        None => name.to_string(),
    }
}

/// Runs this test binary again with `env` set, on one test thread, with `args` (test name
/// filters, taken inside `module`, the caller's `module_path!()`; and `--exact`), and asserts
/// that the child passed exactly `expected` tests.
pub fn run_child(module: &str, env: &[(&str, &str)], args: &[&str], expected: usize) {
    let args: Vec<String> = args
        .iter()
        .map(|a| {
            if a.starts_with("--") {
                a.to_string()
            } else {
                test_path(module, a)
            }
        })
        .collect();
    let out = std::process::Command::new(std::env::current_exe().unwrap())
        .envs(env.iter().copied())
        .env(CHILD, "1")
        .arg("--test-threads=1")
        .args(&args)
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
/// this process already runs with LP_NUM_THREADS=1, re-runs test `name` of `module` (the
/// caller's `module_path!()`) in a child that does, asserts it passed, and returns true: the
/// caller returns.
pub fn rerun_single_threaded(module: &str, name: &str) -> bool {
    if std::env::var("LP_NUM_THREADS").as_deref() == Ok("1") {
        return false;
    }
    run_child(module, &[("LP_NUM_THREADS", "1")], &["--exact", name], 1);
    true
}

/// Runs the tests named by `filters` (one test each) in a child where lavapipe's subgroups are
/// 16 wide (LP_NATIVE_VECTOR_WIDTH=512), so subgroup code is covered at two sizes; nothing when
/// this process is itself a child.
pub fn rerun_under_subgroup_size_16(module: &str, filters: &[&str]) {
    if is_child() {
        return;
    }
    run_child(
        module,
        &[("LP_NATIVE_VECTOR_WIDTH", "512")],
        filters,
        filters.len(),
    );
}
