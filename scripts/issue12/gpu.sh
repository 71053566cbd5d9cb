#!/bin/bash
# Issue 12, item 4 on a lent GPU: whole-process SLAM speed with --device cuda, in one command.
#
#   OUT=dir TUM=path/to/tum_fr1_rpy [HOLO=path/to/hololens_dvmvs] [STEP_S=75] scripts/issue12/gpu.sh
#
# (DEVICE=cpu EXTRA="--frames 0:20" tries the script itself on a machine without a GPU.)
#
# Renders the generator walk of docs/results/slam_table.md on the machine (seed 11, 10 frames/s, 100 frames), then
# runs `codeslam slam --device cuda --threads 2` sequential and parallel: TUM and the walk with the network's depth
# (128x96, the network's canonical camera), the walk with its own depth at 256x192 (--depth-model standin, the
# issue's GPU resolution; the network has no 256x192 decoder), HoloLens (network) when given; then one Gauss-Newton
# iteration of bench_sfm_gn on the GPU. Each run is cut at STEP_S seconds (a cut run prints no result: slower than
# frames/STEP_S) and none goes past BUDGET_S (default 480) from the start.
# Writes $OUT/summary.txt (one line per run, from each run's result.json) and $OUT/logs.tar.gz.
set -u
out=${OUT:?OUT}; step=${STEP_S:-75}; work=${WORK:-/tmp/gpu12}
mkdir -p "$out" "$work"
export PYTHONUNBUFFERED=1
py=${PYTHON:-python3}
command -v nvidia-smi >/dev/null && nvidia-smi --query-gpu=name,memory.total,driver_version --format=csv,noheader > "$work/gpu.txt" 2>&1
$py -c "import torch; print('torch', torch.__version__, torch.cuda.get_device_name())" >> "$work/gpu.txt" 2>&1
cat "$work/gpu.txt"
$py -m codeslam synth "$work/walk10" --scenes 1 --frames 100 --motion walk --fps 10 --seed 11 --size 320x240 -q \
    > "$work/synth.log" 2>&1 || { cat "$work/synth.log"; }
walk="$work/walk10/scene_000"

deadline=$((SECONDS + ${BUDGET_S:-480}))  # no run starts or goes on past this
run() {  # NAME ARGS...: one SLAM run, its summary line appended
    local name=$1; shift
    local left=$((deadline - SECONDS)); [ "$left" -gt "$step" ] && left=$step
    [ "$left" -lt 10 ] && { echo "$name: not run (budget spent)" | tee -a "$work/summary.txt"; return; }
    local t0=$(date +%s.%N)
    timeout "$left" $py -m codeslam slam "$@" --device "${DEVICE:-cuda}" --threads 2 -q ${EXTRA:-} --out "$work/$name" \
        > "$work/$name.log" 2>&1
    local rc=$? t1=$(date +%s.%N)
    $py - "$name" "$rc" "$t0" "$t1" "$work/$name/result.json" <<'PY' | tee -a "$work/summary.txt"
import json, os, sys
name, rc, t0, t1, f = sys.argv[1], sys.argv[2], float(sys.argv[3]), float(sys.argv[4]), sys.argv[5]
if not os.path.exists(f):
    print(f"{name}: exit {rc} after {t1 - t0:.0f} s, no result"); sys.exit()
d = json.load(open(f))
ms = d.get("ms_per_frame", {}); mk = d.get("ms_per_keyframe", {})
stages = " ".join(f"{k} {v:.1f}" for k, v in ms.items())
kstages = " ".join(f"{k} {v:.0f}" for k, v in mk.items())
print(f"{name}: {d['tracking_failures']}/{d['frames']} failed, ATE Sim3 {d.get('ate_sim3_rmse', float('nan')):.4f} m, "
      f"rot {d.get('rot_aligned_rmse_deg', float('nan')):.2f} deg, kf {d['keyframes']}, {d['fps_with_io']:.2f} f/s with reading ({d['fps']:.2f} without), "
      f"whole process {t1 - t0:.1f} s | ms/frame {stages} | ms/keyframe {kstages}")
PY
}
: > "$work/summary.txt"
# Parallel mode first (the issue's target), then sequential, so that a spent budget cuts the less important runs.
run tum_net_par "${TUM:?TUM}" --parallel
[ -n "${HOLO:-}" ] && run holo_net_par "$HOLO" --parallel
run walk_std256_par "$walk" --depth-model standin --size 256x192 --parallel
run tum_net_seq "$TUM" --sequential
[ -n "${HOLO:-}" ] && run holo_net_seq "$HOLO" --sequential
run walk_net_par "$walk" --parallel
run walk_std256_seq "$walk" --depth-model standin --size 256x192 --sequential
run walk_net_seq "$walk" --sequential
left=$((deadline - SECONDS)); [ "$left" -gt "$step" ] && left=$step; [ "$left" -lt 10 ] && left=10
timeout "$left" $py benchmarks/bench_sfm_gn.py --device "${DEVICE:-cuda}" --skip-autograd --frames 2 4 --codes 32 128 \
    --repeats 10 > "$work/bench_sfm_gn.log" 2>&1
tail -n 12 "$work/bench_sfm_gn.log"
cp "$work/summary.txt" "$work/gpu.txt" "$out/"
(cd "$work" && tar czf "$out/logs.tar.gz" --exclude='*.ply' --exclude='*.npz' --exclude='*.html' --exclude=walk10 .)
