//! Re-running a test on one lavapipe thread, where identical training runs are bitwise equal.

/// Bitwise comparisons need a deterministic backward: lavapipe's float atomics add in a
/// thread-dependent order unless it runs one thread (see the trainer's determinism docs). Unless
/// this process already runs with LP_NUM_THREADS=1, re-runs test `name` in a child that does
/// (other drivers ignore the variable), asserts it passed, and returns true: the caller returns.
pub fn rerun_single_threaded(name: &str) -> bool {
    if std::env::var("LP_NUM_THREADS").as_deref() == Ok("1") {
        return false;
    }
    let out = std::process::Command::new(std::env::current_exe().unwrap())
        .env("LP_NUM_THREADS", "1")
        .args(["--exact", name, "--test-threads=1"])
        .output()
        .unwrap();
    let text =
        String::from_utf8_lossy(&out.stdout).to_string() + &String::from_utf8_lossy(&out.stderr);
    assert!(out.status.success(), "child run failed:\n{text}");
    assert!(
        text.contains("1 passed"),
        "child ran the wrong tests:\n{text}"
    );
    true
}
