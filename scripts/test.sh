#!/usr/bin/env bash
# Runs the whole test suite on the default Vulkan device (lavapipe on a machine without a GPU)
# with the Khronos validation layer on (tests enable it themselves and fail on any error).
set -euo pipefail
cd "$(dirname "$0")/.."
export RUST_BACKTRACE=1
# Benchmarks must keep compiling even though the tests do not run them.
cargo bench --no-run --quiet
# cargo-nextest, where installed, runs two tests at a time across all test executables;
# `cargo test` runs the executables one after another, so a file whose last test is long
# leaves a core idle (on 2 cores the same suite took 362 s with nextest, 572 s without,
# 2026-11-29). The crate has no doctests, which nextest would not run.
# LPMSPLAT_TEST_RUNNER=cargo forces `cargo test`.
if [ "${LPMSPLAT_TEST_RUNNER:-}" != cargo ] && cargo nextest --version >/dev/null 2>&1; then
    cargo nextest run --release --test-threads 2 --no-fail-fast --failure-output immediate-final
else
    cargo test --release -- --test-threads=2
fi
