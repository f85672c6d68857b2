#!/usr/bin/env bash
# Packs what the GPU machine needs (the `device` tool of this workplace; scripts/device/README.md
# says how a session uses it) into the git-ignored folders .device/ and .gl/:
#   .device/bin.tar.xz    the stripped release binary
#   .device/tests.tar.xz  the stripped test executables whose tests run GPU kernels (gpu_*),
#                         and the loss benchmark (bench_loss)
#   .device/scene-NAME.tar.xz  each scene given as an argument (../shared/data/tnt_truck ...),
#                         one per call (run.sh takes the one carried, or SCENE=NAME)
#   .gl/libvulkan1_*.deb  the Vulkan loader, which that machine lacks
#   .device/validation.deb  the Khronos validation layer, which the tests turn on
#   .device/base.tar.xz   with BASE=REV: the stripped release binary of commit REV, for the
#                         `fpspair` step's side-by-side ratios (built in a worktree under /tmp)
# A call carries some of them (the working tree travels too, 64 MiB in all): this script prints
# the size of each call of scripts/device/README.md and refuses one that would not fit.
set -euo pipefail
cd "$(dirname "$0")/../.."
scenes=("$@")
for d in /.device/ /.gl/; do
    grep -qxF "$d" .git/info/exclude 2>/dev/null || echo "$d" >>.git/info/exclude
done
rm -rf .device && mkdir -p .device/bin .device/tests
cargo build --release --quiet
cp target/release/lpmsplat .device/bin/
cargo test --release --no-run --message-format=json --quiet 2>/dev/null | python3 -c '
import json, shutil, sys
for line in sys.stdin:
    m = json.loads(line)
    exe, t = m.get("executable"), m.get("target", {})
    if exe and t.get("kind") == ["test"] and t["name"].startswith("gpu_"):
        shutil.copy(exe, ".device/tests/" + t["name"])
'
# The loss benchmark (benches/loss.rs): both loss layouts' GPU time at four image sizes.
cargo bench --no-run --bench loss --message-format=json --quiet 2>/dev/null | python3 -c '
import json, shutil, sys
for line in sys.stdin:
    m = json.loads(line)
    if m.get("executable") and m.get("target", {}).get("name") == "loss":
        shutil.copy(m["executable"], ".device/tests/bench_loss")
'
strip .device/bin/* .device/tests/*
for k in bin tests; do tar -cJf ".device/$k.tar.xz" -C .device "$k" && rm -rf ".device/$k"; done
if [ -n "${BASE:-}" ]; then
    rev=$(git rev-parse --short "$BASE")
    wt=/tmp/lpmsplat-base-$rev
    [ -d "$wt" ] || git worktree add -f --detach "$wt" "$rev" >/dev/null
    (cd "$wt" && CARGO_TARGET_DIR=/tmp/lpmsplat-base-target cargo build --release --quiet)
    mkdir -p .device/base
    cp /tmp/lpmsplat-base-target/release/lpmsplat .device/base/lpmsplat
    echo "$rev" >.device/base/REV
    strip .device/base/lpmsplat
    tar -cJf .device/base.tar.xz -C .device base && rm -rf .device/base
fi
for scene in "${scenes[@]}"; do
    [ -d "$scene" ] || { echo "no scene folder at $scene" >&2; exit 1; }
    # xz: the JPEGs stay as they are, the COLMAP model halves (Truck: 52 -> 43 MiB).
    tar -cJf ".device/scene-$(basename "$scene").tar.xz" -C "$(dirname "$scene")" "$(basename "$scene")"
done
o='-oAPT::Architecture=amd64 -oAPT::Architectures=amd64 -oDir::State::Lists=/tmp/amd64'
mkdir -p .gl /tmp/amd64/partial
# shellcheck disable=SC2086
apt-get $o update -qq
# shellcheck disable=SC2086
# The loader, and glvnd's libraries that the NVIDIA driver's Vulkan library links against.
ls .gl/libglvnd0_*.deb >/dev/null 2>&1 ||
    (cd .gl && apt-get $o download -qq libvulkan1 libegl1 libglvnd0 libopengl0 libgl1 libglx0 libgles2)
# shellcheck disable=SC2086
(cd .device && apt-get $o download -qq vulkan-validationlayers && mv vulkan-validationlayers_*.deb validation.deb)
mib() { du -cb "$@" 2>/dev/null | tail -1 | cut -f1; }
tree=$(git ls-files -z | xargs -0 du -b 2>/dev/null | awk '{s += $1} END {print s}')
fits=1
call() {
    local name=$1 bytes=$tree
    shift
    bytes=$((bytes + $(mib "$@")))
    echo "call '$name': $((bytes / 1048576)) MiB (carry: $*)"
    [ "$bytes" -lt $((63 * 1048576)) ] || { echo "  too large for one call (64 MiB)" >&2; fits=0; }
}
call check .gl .device/bin.tar.xz .device/tests.tar.xz .device/validation.deb
[ -z "${BASE:-}" ] || call fpspair .gl .device/bin.tar.xz .device/base.tar.xz
for scene in "${scenes[@]}"; do
    call "scene $(basename "$scene")" .gl .device/bin.tar.xz ".device/scene-$(basename "$scene").tar.xz"
done
[ "$fits" = 1 ]
