#!/usr/bin/env bash
# Runs the whole test suite on the default Vulkan device (lavapipe on a machine without a GPU)
# with the Khronos validation layer on (tests enable it themselves and fail on any error).
set -euo pipefail
cd "$(dirname "$0")/.."
export RUST_BACKTRACE=1
# Benchmarks must keep compiling even though the tests do not run them.
cargo bench --no-run --quiet
cargo test --release -- --test-threads=2
