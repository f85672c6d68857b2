#!/usr/bin/env bash
# Runs on the GPU machine, from the repository root, after scripts/device/pack.sh packed what it
# needs here (scripts/device/README.md): `bash scripts/device/run.sh STEP...`, each step inside
# what is left of BUDGET seconds (default 540, under one call's 600), so a slow step cannot
# take the others' results with it. Everything lands in $OUT/results.tar.gz (logs, JSON, the
# per-stage tables) and a summary is printed last.
#   info     the device as the engine sees it
#   tests    the gpu_* test executables (kernels against the f64 references), validation on
#   demo     the README's main job, 3DGS then 2DGS (lund_door_small -r 2, 2000 iterations)
#   ahead    train --record-ahead on against off, alternated twice: the main job, then (with a
#            packed scene) ITERATIONS (3000) at full size
#   fps      bench fps at 1352x1014: 100k, 1M and 3M generated Gaussians
#   sortdigits bench fps with --sort-digits 4 against 8 (ballot-ranked byte passes), alternated
#            twice, the main job likewise (where the sorts' fixed cost a pass shows), then (with
#            a packed scene) training at full size, ITERATIONS (3000), the same two alternated:
#            whether 8-bit digits should become the GPUs' default
#   fpspair  the same with the packed baseline (pack.sh with BASE=REV) and this build, alternated
#            twice: the FPS ratio measured side by side on one GPU
#   trade7k  bench trade on the packed scene at full size: ADC vs ADC+LPM, 7k of the 30k
#            calendar, then bench fps of the LPM model at 1352x1014
#   trade30k bench trade on the packed scene at full size: ADC vs ADC+LPM, the whole 30k
#            schedule, evaluated at 3k, 7k and 15k on the way: the rows reached come back
#            even when the budget ends the run first
#   ablate7k 7k of the 30k calendar on the packed scene: ADC, ADC+LPM, LPM without its reset and
#            with the reset's cone to the zone's bounding sphere, seed SEED (default 1; 4 runs)
#   pair30k  train the packed scene at full size, ADC and ADC+LPM as two processes side by side
#            (quality only: they share the GPU), 30k iterations (ITERATIONS=N for fewer),
#            LPM_FLAGS=... added to the LPM run, each process's GPU memory logged
#   serial30k train the packed scene at full size to 30k (ITERATIONS) with LPM, then without, alone
#            with --timestamps and its GPU memory logged, seed SEED (0) (Truck on an H100 with
#            the butterflies: 232 s + 237 s, both in one call; RUNS=adc or RUNS=lpm runs one)
#   layouts  train the packed scene at full size with each --raster-pixels layout (LAYOUTS,
#            default "1 2 4 8"), ITERATIONS (default 5000) each, --timestamps, alternated twice;
#            TRAIN_FLAGS=... added to every run (e.g. "--model 2dgs")
#   lossbench the loss kernels alone (benches/loss.rs): each layout's GPU time at four image
#            sizes, twice (needs tests.tar.xz, like `tests`)
#   losslayouts train the packed scene at full size with each loss layout (--loss-layout
#            segments, tiles), ITERATIONS (default 3000) each, --timestamps, alternated twice
#   stgs     SpacetimeGaussians full on the packed video scene (panoptic_basketball) at full
#            size, ADC vs ADC+LPM, ITERATIONS (12000), then each model's FPS at 1352x1014
#   local7k  bench trade on the packed scene at full size, 7k of the 30k calendar: ADC, ADC+LPM,
#            ADC+LPM without zones wider than the scene (lpm-local-zones) and with slab zones
#            (lpm-slab), seed SEED (0); TRADE_RUNS replaces the list
#   budget7k bench trade on the packed scene at full size, 7k of the 30k calendar: ADC and ADC+LPM
#            under one Gaussian budget (--max-gaussians CAP, default 1000000), so they compare
#            at one count; seed SEED (0); TRADE_RUNS replaces the list (e.g. adc,lpm,lpm-no-reset);
#            BLOCK_FRACTION sets the LPM runs' --lpm-block-fraction (0.7 led at -r 4);
#            MATCH=1 holds the other runs to ADC's count at every iteration instead;
#            THRESHOLD_RATIO=1 runs LPM without its lowered threshold (its resets only)
#   blend7k  bench trade on the packed scene at full size, 7k of the 30k calendar: the exact
#            budget ranked by the gradient statistic and by Taming-3DGS's blended score
#            (adc-exact, adc-exact-blend) at one count, --budget COUNT (default 1M), seed SEED (0);
#            TRADE_RUNS replaces the list (e.g. adc-exact,adc-exact-blend,mcmc)
#   MODEL=NAME (2dgs, pixel-gs, mip-splatting) sets the base model of trade7k, trade30k,
#            local7k and budget7k (default 3dgs)
#   train30k train the packed scene at full size with LPM, 30k iterations, --timestamps
set -uo pipefail
cd "$(dirname "$0")/../.."
OUT=${OUT:-/tmp/device-out}
budget=${BUDGET:-540}
deadline=$((SECONDS + budget))
work=/tmp/lpmsplat-device
res=$work/results
mkdir -p "$res" "$OUT"
for f in .gl/*.deb .device/validation.deb; do [ -f "$f" ] && dpkg -x "$f" /; done
ldconfig
# The NVIDIA driver's Vulkan manifest is not always where the loader looks: name it when not.
if [ -z "${VK_DRIVER_FILES:-}" ] && ! ls /usr/share/vulkan/icd.d/nvidia_icd*.json \
    /etc/vulkan/icd.d/nvidia_icd*.json >/dev/null 2>&1; then
    icd=$(find /usr/local/nvidia /usr/share /etc /usr/lib /opt -name 'nvidia_icd*.json' 2>/dev/null | head -1)
    [ -n "$icd" ] && export VK_DRIVER_FILES=$icd
fi
for k in bin tests base; do [ -f ".device/$k.tar.xz" ] && tar -xJf ".device/$k.tar.xz" -C "$work"; done
# The scene: .device/scene-$SCENE.tar.xz, or the only packed one (a warm machine keeps the
# previous call's, so name it with SCENE=NAME when calls carried different scenes).
scene=
archive=
if [ -n "${SCENE:-}" ]; then
    archive=.device/scene-$SCENE.tar.xz
    [ -f "$archive" ] || { echo "SCENE=$SCENE: no $archive carried" >&2; exit 1; }
else
    packed=(.device/scene-*.tar.xz)
    if [ "${#packed[@]}" -gt 1 ]; then
        echo "several scenes here (${packed[*]}): name one with SCENE=NAME" >&2
        exit 1
    fi
    [ -f "${packed[0]}" ] && archive=${packed[0]}
fi
if [ -n "$archive" ]; then
    scene=$(tar -tJf "$archive" | head -1 | cut -d/ -f1)
    [ -d "$work/$scene" ] || tar -xJf "$archive" -C "$work"
    scene=$work/$scene
fi
bin=$work/bin/lpmsplat
summary=$res/summary.txt
: >"$summary"
{
    echo "VK_DRIVER_FILES=${VK_DRIVER_FILES:-}"
    find /usr /etc /opt \( -name 'nvidia_icd*.json' -o -name 'libGLX_nvidia.so*' \) 2>/dev/null | head
    cat "${VK_DRIVER_FILES:-/dev/null}" 2>/dev/null
    ldconfig -p | grep -E 'libvulkan|libGLX|libEGL_nvidia|libnvidia-glvkspirv' | head
} >"$res/vulkan-setup.txt" 2>&1

# collect: the small results so far (logs, the summary, every JSON / Markdown table) as one
# file, $OUT/live.tar.gz (the tool brings back only a few files a call). Run every 20 s in the
# background as well, so a call that the lease ends early still brings back the rows a long
# step had written.
collect() {
    local live=$work/live
    rm -rf "$live" && mkdir -p "$live"
    cp "$res"/*.log "$res"/*.txt "$live/" 2>/dev/null
    (cd "$work" && find . \( -name '*.json' -o -name '*.md' \) -size -4M ! -path './results/*' \
        ! -path './live/*' ! -path './bin/*' ! -path './tests/*' ! -path "./${scene##*/}/*" \
        -exec cp --parents {} "$live" \; 2>/dev/null)
    tar -czf "$OUT/live.tar.gz.part" -C "$work" live && mv "$OUT/live.tar.gz.part" "$OUT/live.tar.gz"
    return 0
}
(while sleep 20; do collect; done) &
collector=$!

# step NAME LIMIT CMD...: runs CMD with its output in NAME.log, for at most LIMIT seconds or
# what is left of the budget, and notes its exit status and wall time in the summary.
step() {
    local name=$1 limit=$2 left t0 rc
    shift 2
    left=$((deadline - SECONDS - 15))
    [ "$left" -lt "$limit" ] && limit=$left
    if [ "$limit" -le 5 ]; then
        echo "$name: skipped (budget spent)" >>"$summary"
        return
    fi
    t0=$SECONDS
    timeout "$limit" "$@" >"$res/$name.log" 2>&1
    rc=$?
    echo "$name: rc $rc, $((SECONDS - t0)) s (limit $limit s)" >>"$summary"
}

# alternate PREFIX FLAG ITERATIONS VALUE...: trains the packed scene at full size once per value
# of FLAG (PREFIX-VALUE-ROUND.log), ITERATIONS each with --timestamps and TRAIN_FLAGS, the values
# alternated over two rounds; with a packed baseline (pack.sh with BASE=REV) its default run
# first in each round (PREFIX-base-ROUND.log): side-by-side ratios on one GPU.
alternate() {
    local prefix=$1 flag=$2 its=$3 r v
    shift 3
    for r in 1 2; do
        # shellcheck disable=SC2086
        [ -x "$work/base/lpmsplat" ] &&
            step "$prefix-base-$r" 200 "$work/base/lpmsplat" train "$scene" -r 1 \
                --iterations "$its" --timestamps ${TRAIN_FLAGS:-} -o "$work/$prefix-base-$r"
        for v in "$@"; do
            # shellcheck disable=SC2086
            step "$prefix-$v-$r" 200 "$bin" train "$scene" -r 1 --iterations "$its" \
                --timestamps "$flag" "$v" ${TRAIN_FLAGS:-} -o "$work/$prefix-$v-$r"
        done
    done
}

# MODEL=NAME: the base model of the bench trade steps (trade7k, trade30k, local7k, budget7k)
# and of trade7k's FPS of the trained model (default 3dgs).
model_args=(${MODEL:+--model "$MODEL"})

need_scene() {
    [ -n "$scene" ] && return 0
    echo "$1: skipped (no .device/scene-NAME.tar.xz carried)" >>"$summary"
    return 1
}

for s in "$@"; do
    case $s in
    info)
        step info 30 "$bin" info
        nvidia-smi >"$res/nvidia-smi.txt" 2>&1
        ;;
    tests)
        for t in "$work"/tests/gpu_*; do
            step "test-$(basename "$t")" 240 "$t" --test-threads=4
        done
        ;;
    demo)
        step demo-3dgs 120 "$bin" train tests/data/lund_door_small -r 2 --iterations 2000 \
            --timestamps -o "$work/demo-3dgs"
        step demo-2dgs 180 "$bin" train tests/data/lund_door_small -r 2 --iterations 2000 \
            --model 2dgs --timestamps -o "$work/demo-2dgs"
        ;;
    ahead)
        # Recording each iteration while the previous one runs (train --record-ahead on, the
        # default) against recording between iterations (off), alternated twice: the README's
        # main job (lund_door_small -r 2, 2000 iterations, where the host's recording was most
        # of the H100's 0.29 ms gap an iteration), then, with a packed scene, ITERATIONS
        # (default 3000) at full size.
        for r in 1 2; do
            for v in on off; do
                step "ahead-demo-$v-$r" 60 "$bin" train tests/data/lund_door_small -r 2 \
                    --iterations 2000 --timestamps --record-ahead "$v" -o "$work/ahead-demo-$v-$r"
            done
        done
        [ -n "$scene" ] && alternate ahead --record-ahead "${ITERATIONS:-3000}" on off
        ;;
    fps)
        step fps 120 "$bin" bench fps --gaussians 100000,1000000,3000000 --json "$res/fps.json"
        # 4K frames of multi-million models (issue 19's "4K renders"; on lavapipe 3 M
        # Gaussians at 4096×2700 need two bands of tile rows, on a GPU one binding holds them).
        step fps-4k 120 "$bin" bench fps --gaussians 1000000,3000000 --width 3840 --height 2160 \
            --frames 20 --json "$res/fps-4k.json"
        ;;
    sortdigits)
        for r in 1 2; do
            for v in 4 8; do
                step "fps-digits$v-$r" 100 "$bin" bench fps --sort-digits "$v" \
                    --gaussians 100000,1000000,3000000 --json "$res/fps-digits$v-$r.json"
            done
        done
        for r in 1 2; do
            for v in 4 8; do
                step "digits-demo$v-$r" 60 "$bin" --sort-digits "$v" train \
                    tests/data/lund_door_small -r 2 --iterations 2000 --timestamps \
                    -o "$work/digits-demo$v-$r"
            done
        done
        [ -n "$scene" ] && alternate sortdigits --sort-digits "${ITERATIONS:-3000}" 4 8
        ;;
    fpspair)
        if [ -x "$work/base/lpmsplat" ]; then
            for r in 1 2; do
                step "fps-base-$r" 100 "$work/base/lpmsplat" bench fps \
                    --gaussians 100000,1000000,3000000 --json "$res/fps-base-$r.json"
                step "fps-new-$r" 100 "$bin" bench fps --gaussians 100000,1000000,3000000 \
                    --json "$res/fps-new-$r.json"
            done
            echo "fpspair: baseline $(cat "$work/base/REV")" >>"$summary"
        else
            echo "fpspair: skipped (no .device/base.tar.xz: pack.sh with BASE=REV)" >>"$summary"
        fi
        ;;
    trade7k)
        need_scene trade7k &&
            step trade7k 900 "$bin" bench trade "$scene" -r 1 --iterations 7000 --calendar 30000 \
                --runs adc,lpm --eval-at 3500 --fps-frames 20 "${model_args[@]}" -o "$work/trade7k" &&
            step fps-trained 90 "$bin" bench fps --ply "$work/trade7k/adc+lpm.ply" \
                "${model_args[@]}" --json "$res/fps-trained.json"
        ;;
    trade30k)
        need_scene trade30k &&
            step trade30k 900 "$bin" bench trade "$scene" -r 1 --iterations 30000 \
                --runs adc,lpm --eval-at 3000,7000,15000 --fps-frames 20 "${model_args[@]}" \
                -o "$work/trade30k"
        ;;
    ablate7k)
        need_scene ablate7k &&
            step ablate7k 900 "$bin" bench trade "$scene" -r 1 --iterations 7000 --calendar 30000 \
                --runs adc,lpm,lpm-no-reset,lpm-bounding-cone --seed "${SEED:-1}" --fps-frames 5 \
                -o "$work/ablate7k"
        ;;
    pair30k)
        # ADC and ADC+LPM trained side by side as two processes sharing the GPU, for their
        # quality at 30k in one call (their it/s are shared-GPU rates, not the engine's speed).
        # LPM_FLAGS adds options to the LPM run (e.g. "--lpm-cone bounding"). Each process's GPU
        # memory is sampled every 5 s into gpu-mem.log (memory, unlike speed, is not shared).
        need_scene pair30k && {
            n=${ITERATIONS:-30000}
            nvidia-smi --query-compute-apps=pid,used_memory --format=csv,noheader -l 5 \
                >"$res/gpu-mem.log" 2>&1 &
            smi=$!
            (sleep 30 && ps -eo pid,args | grep '[l]pmsplat train' >"$res/gpu-mem-pids.txt") &
            step pair30k-adc 900 "$bin" train "$scene" -r 1 --iterations "$n" --eval-every 7000 \
                -o "$work/pair30k-adc" &
            adc=$!
            # shellcheck disable=SC2086
            step pair30k-lpm 900 "$bin" train "$scene" -r 1 --iterations "$n" --eval-every 7000 \
                --lpm ${LPM_FLAGS:-} -o "$work/pair30k-lpm"
            wait "$adc" # not a bare wait: the collector runs in the background too
            kill "$smi" 2>/dev/null
        }
        ;;
    serial30k)
        # ADC+LPM then ADC, each alone on the GPU with --timestamps (the speed and the 30k
        # quality in one lease: about 12 minutes on an H100, so it runs detached over two calls,
        # scripts/device/README.md). GPU memory is sampled every 5 s into gpu-mem.log.
        need_scene serial30k && {
            nvidia-smi --query-compute-apps=pid,used_memory --format=csv,noheader -l 5 \
                >"$res/gpu-mem.log" 2>&1 &
            smi=$!
            for run in ${RUNS:-lpm adc}; do
                flags=
                [ "$run" = lpm ] && flags=--lpm
                # shellcheck disable=SC2086
                step "serial30k-$run" 900 "$bin" train "$scene" -r 1 --iterations "${ITERATIONS:-30000}" \
                    --eval-every 7000 --timestamps --seed "${SEED:-0}" $flags -o "$work/serial30k-$run"
                echo "serial30k-$run ended at $SECONDS s" >>"$res/gpu-mem.log"
                # The trained model's FPS at 1352x1014 (issue 19 asks for Truck's).
                [ -f "$work/serial30k-$run/point_cloud.ply" ] &&
                    step "fps-serial30k-$run" 60 "$bin" bench fps --scene "$scene" \
                        --ply "$work/serial30k-$run/point_cloud.ply" --json "$res/fps-serial30k-$run.json"
            done
            kill "$smi" 2>/dev/null
        }
        ;;
    layouts)
        # The rasterizers' pixels per invocation (train --raster-pixels) on the packed scene at
        # full size, each layout alone with --timestamps, ITERATIONS (default 5000) each, the
        # layouts alternated twice: which of the backward's two ways to sum (shared memory at 1
        # pixel, subgroup butterflies and atomics at 2 to 8) is faster on this GPU.
        # With a packed baseline (pack.sh with BASE=REV), its default layout runs first in each
        # round: the side-by-side ratio of a rasterizer change.
        need_scene layouts &&
            # shellcheck disable=SC2086
            alternate layout --raster-pixels "${ITERATIONS:-5000}" ${LAYOUTS:-1 2 4 8}
        ;;
    losslayouts)
        # The loss kernels' two layouts (train --loss-layout) on the packed scene at full size,
        # ITERATIONS (default 3000) each, --timestamps, alternated twice: whether the tiles
        # (shared memory, one pixel an invocation) beat the segments on this GPU.
        need_scene losslayouts &&
            alternate loss --loss-layout "${ITERATIONS:-3000}" segments tiles
        ;;
    lossbench)
        # The loss kernels' GPU time alone (benches/loss.rs, carried in tests.tar.xz), each
        # layout at 162x242, 245x137, 979x546 and 1352x1014, twice: a minute's answer to which
        # layout this GPU wants, before losslayouts spends a scene's training on it.
        if [ -x "$work/tests/bench_loss" ]; then
            for r in 1 2; do
                step "lossbench-$r" 60 "$work/tests/bench_loss"
            done
        else
            echo "lossbench: skipped (carry .device/tests.tar.xz)" >>"$summary"
        fi
        ;;
    stgs)
        # SpacetimeGaussians (full) on the packed video scene (panoptic_basketball) at full
        # size: ADC and ADC+LPM interleaved, ITERATIONS (default 12000) with an evaluation at
        # half, each over the test cameras' 50 frames; then each trained model's FPS at
        # 1352x1014 at mid-segment (issue 18).
        need_scene stgs && {
            n=${ITERATIONS:-12000}
            step stgs 900 "$bin" bench trade "$scene" -r 1 --model spacetime-full \
                --iterations "$n" --eval-at $((n / 2)) --runs adc,lpm --init-points 30000 \
                --seed "${SEED:-0}" --fps-frames 5 -o "$work/stgs"
            for run in adc adc+lpm; do
                [ -f "$work/stgs/$run.ply" ] &&
                    step "fps-stgs-$run" 60 "$bin" bench fps --ply "$work/stgs/$run.ply" \
                        --model spacetime-full --time 0.5 --json "$res/fps-stgs-$run.json"
            done
        }
        ;;
    local7k)
        # LPM with and without the zones wider than the scene (bench trade's lpm-local-zones,
        # `--lpm-max-zone-radius 1`) and with slab zones (`--lpm-zone slab`) beside ADC, 7k of
        # the 30k calendar, interleaved.
        need_scene local7k &&
            step local7k 900 "$bin" bench trade "$scene" -r 1 --iterations 7000 --calendar 30000 \
                --runs "${TRADE_RUNS:-adc,lpm,lpm-local-zones,lpm-slab}" --seed "${SEED:-0}" --eval-at 3500 --fps-frames 5 \
                "${model_args[@]}" -o "$work/local7k"
        ;;
    budget7k)
        # ADC and LPM at one count: both under the same cap, interleaved.
        # MATCH=1: the LPM runs follow ADC's count at every iteration (--match-adc-count)
        # instead of a cap guessed beforehand; CAP then applies only when given.
        if [ -n "${MATCH:-}" ]; then
            count_args=(--match-adc-count ${CAP:+--max-gaussians "$CAP"})
        else
            count_args=(--max-gaussians "${CAP:-1000000}")
        fi
        need_scene budget7k &&
            step budget7k 900 "$bin" bench trade "$scene" -r 1 --iterations 7000 --calendar 30000 \
                --runs "${TRADE_RUNS:-adc,lpm}" "${count_args[@]}" --seed "${SEED:-0}" --eval-at 3500 \
                --fps-frames 5 ${BLOCK_FRACTION:+--lpm-block-fraction "$BLOCK_FRACTION"} \
                ${THRESHOLD_RATIO:+--lpm-threshold-ratio "$THRESHOLD_RATIO"} "${model_args[@]}" \
                -o "$work/budget7k"
        ;;
    blend7k)
        # The blended score against the gradient ranking at one exact count, interleaved.
        need_scene blend7k &&
            step blend7k 900 "$bin" bench trade "$scene" -r 1 --iterations 7000 --calendar 30000 \
                --runs "${TRADE_RUNS:-adc-exact,adc-exact-blend}" --budget "${COUNT:-1M}" \
                --seed "${SEED:-0}" --eval-at 3500 --fps-frames 5 "${model_args[@]}" \
                -o "$work/blend7k"
        ;;
    train30k)
        need_scene train30k &&
            step train30k 900 "$bin" train "$scene" -r 1 --iterations 30000 --lpm --eval-every 5000 \
                --timestamps -o "$work/train30k"
        ;;
    *) echo "$s: unknown step (info tests demo ahead fps sortdigits fpspair trade7k trade30k ablate7k pair30k serial30k layouts lossbench losslayouts stgs local7k budget7k blend7k train30k)" >>"$summary" ;;
    esac
    collect
done
kill "$collector" 2>/dev/null

# The small outputs come back (no PLY, no renders): JSON, metrics, the per-stage logs.
(cd "$work" && find . -name '*.json' -size -4M ! -path './results/*' -exec cp --parents {} "$res" \;)
tar -czf "$OUT/results.tar.gz" -C "$work" results
cat "$summary"
head -n 8 "$res/vulkan-setup.txt"
for f in "$res"/*.log; do
    echo "== $(basename "$f")"
    grep -E "test result|FAILED|panicked|it/s|PSNR|FPS|Gaussians|error|Error|subgroup|device|rasterize|sum to|host recording" "$f" | tail -n 14
done
