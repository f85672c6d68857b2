#!/usr/bin/env bash
# The README's main job: installs what is missing (scripts/install-deps.sh), builds, and trains
# the small real scene shipped in tests/data (Lund door, 10 training and 2 test views at
# 162×242) end to end into output/lund_door_small/: the PLY (and a .splat), test renders,
# metrics.json, and training.png (test PSNR, Gaussians and loss against iterations and time).
# Extra arguments go to `lpmsplat train` (e.g. `--iterations 500`, `--lpm`).
set -euo pipefail
cd "$(dirname "$0")/.."
bash scripts/install-deps.sh
exec cargo run --release -- train tests/data/lund_door_small -r 2 --iterations 2000 --eval-every 250 \
  -o output/lund_door_small "$@"
