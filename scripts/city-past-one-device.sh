#!/usr/bin/env bash
# Training past one device, shown end to end on a generated district (docs/partition.md):
#   1. generate-city: 2 M Gaussians of truth, 160 one-megapixel survey views;
#   2. the whole scene trained under --memory-limit LIMIT: it stops with a resumable checkpoint;
#   3. partition --memory LIMIT: the coarsest grid whose every block fits;
#   4. every block trained under the same --memory-limit, then merged;
#   5. eval of the merged model (and of the truth, the ceiling at this -r) on the test views.
# Run from the repository root after `cargo build --release`; OUT defaults to output/city.
# Figures: OUT/summary.txt. The settings below are the ones docs/partition.md quotes.
set -euo pipefail
cd "$(dirname "$0")/.."
BIN=${LPMSPLAT:-target/release/lpmsplat}
OUT=${1:-output/city}
LIMIT=${LIMIT:-384}           # MiB: the rehearsed device
BUDGET=${BUDGET:-400k}        # the whole model's Gaussians at the end of densification
R=${R:-4}                     # training resolution factor (1152x864 / 4 on lavapipe)
ITER=${ITER:-2000}
TRAIN=(-r "$R" --iterations "$ITER" --strategy mcmc --budget-growth taming
  --densify-from 200 --densify-until 1400 --densify-interval 50 --eval-every 0)
mkdir -p "$OUT"
[ -d "$OUT/city" ] || "$BIN" generate-city "$OUT/city" --lots 6x6 --gaussians 2M --views 160 \
  --points 200k
# The whole scene, under the limit: expected to stop with a checkpoint (exit status ≠ 0).
if [ ! -e "$OUT/whole.log" ]; then
  set +e
  /usr/bin/time -v "$BIN" --memory-limit "$LIMIT" train "$OUT/city" "${TRAIN[@]}" \
    --budget "$BUDGET" -o "$OUT/whole" >"$OUT/whole.log" 2>&1
  echo "whole run exit status $?" >>"$OUT/whole.log"
  set -e
fi
[ -e "$OUT/plan/plan.json" ] || "$BIN" partition "$OUT/city" -r "$R" --budget "$BUDGET" \
  --memory "$LIMIT" -o "$OUT/plan" -- "${TRAIN[@]:2}"
for b in $(python3 -c "import json,sys; print(' '.join(b['name'] for b in json.load(open(sys.argv[1]))['blocks']))" "$OUT/plan/plan.json"); do
  [ -e "$OUT/plan/runs/$b/metrics.json" ] && continue
  budget=$(python3 -c "import json,sys; print([b['expected_gaussians'] for b in json.load(open(sys.argv[1]))['blocks'] if b['name']==sys.argv[2]][0])" "$OUT/plan/plan.json" "$b")
  /usr/bin/time -v "$BIN" --memory-limit "$LIMIT" train "$OUT/plan/blocks/$b" "${TRAIN[@]}" \
    --budget "$budget" -o "$OUT/plan/runs/$b" >"$OUT/plan/runs-$b.log" 2>&1
done
"$BIN" merge "$OUT/plan/plan.json" -o "$OUT/merged" | tee "$OUT/merge.txt"
"$BIN" eval "$OUT/city" -r "$R" --ply "$OUT/merged/point_cloud.ply" --json "$OUT/merged_eval.json" \
  >"$OUT/merged_eval.txt"
"$BIN" eval "$OUT/city" -r "$R" --ply "$OUT/city/truth.ply" --json "$OUT/truth_eval.json" \
  >"$OUT/truth_eval.txt"
{
  echo "limit ${LIMIT} MiB, budget ${BUDGET}, -r ${R}, ${ITER} iterations"
  grep -E "after iteration|exit status" "$OUT/whole.log" | head -3
  cat "$OUT/merge.txt"
  echo "merged: $(grep "^mean" "$OUT/merged_eval.txt")"
  echo "truth:  $(grep "^mean" "$OUT/truth_eval.txt")"
} | tee "$OUT/summary.txt"
