#!/bin/bash
# Issue 13 on a lent GPU, as one timed command: render training data on the machine's cores, then train the
# networks named in RUNS side by side on the GPU for a fixed wall-clock budget, and export each. By default:
#   finetune: the default (version 3) weights, continued on fresh data (gpu_finetune.yaml)
#   scratch:  the same data from random weights (gpu_scratch.yaml)
# (gpu_*_scale.yaml: the same with the code path's targets scaled, train.code_scale.)
# Data: generator versions 1 and 3 (seeds 1000 and 5000, as the default weights' card; more views than the CPU
# run had) and the real fine-tuning halves of ../shared/train_data (scripts/split_real_rgbd.py), 8x each.
# The step count of each run comes from its own rate measured in a short calibration with all running, so that
# every cosine schedule ends inside the budget.
#
# Usage (repository root): OUT=DIR REAL=DIR/real_split/train scripts/issue13/gpu.sh
# Env: RUNS (configs scripts/issue13/gpu_RUN.yaml, trained side by side; "finetune scratch"), DEVICE (cuda),
#      SYNTH_S (seconds of rendering, 160), TRAIN_S (seconds of training, 300), WORKERS (cores),
#      VIEWS_PER_CORE_S (rendering rate assumed per core, 11), BATCH (images per step, 128), CAL_STEPS (100),
#      WORK (/tmp/issue13_gpu).
set -u
cd "$(dirname "$0")/../.."
export PYTHONPATH="$PWD${PYTHONPATH:+:$PYTHONPATH}"  # the scripts import codeslam from this checkout
DEVICE=${DEVICE:-cuda}
SYNTH_S=${SYNTH_S:-160}
TRAIN_S=${TRAIN_S:-300}
WORKERS=${WORKERS:-$(nproc)}
RATE=${VIEWS_PER_CORE_S:-11}
BATCH=${BATCH:-128}
CAL_STEPS=${CAL_STEPS:-100}
WORK=${WORK:-/tmp/issue13_gpu}
RUNS=${RUNS:-finetune scratch}
OUT=${OUT:?OUT: where the weights and logs go}
REAL=${REAL:?REAL: the real fine-tuning halves (scripts/split_real_rgbd.py --out D: D/train)}
CS="python3 -m codeslam"
mkdir -p "$WORK" "$OUT"
log() { echo "[$(date +%H:%M:%S)] $*" | tee -a "$OUT/driver.log"; }

# run_for SECONDS CMD...: CMD in a session of its own, killed with all its children after SECONDS
run_for() {
  local secs=$1; shift
  setsid "$@" &
  local pid=$!
  ( sleep "$secs"; kill -TERM -- -"$pid" 2>/dev/null; sleep 20; kill -KILL -- -"$pid" 2>/dev/null ) &
  local guard=$!
  wait "$pid"; local rc=$?
  kill "$guard" 2>/dev/null
  return $rc
}

half=$(( WORKERS / 2 > 0 ? WORKERS / 2 : 1 ))
views=$(( SYNTH_S * RATE * half / 512 * 512 ))
[ "$views" -lt 512 ] && views=512
log "rendering $views views of data versions 1 and 3 on $half workers each, at most ${SYNTH_S} s"
run_for "$SYNTH_S" $CS synth "$WORK/v1" --train --views "$views" --views-per-scene 16 --shard-size 512 \
    --size 128x96 --seed 1000 --workers "$half" > "$WORK/synth_v1.log" 2>&1 &
p1=$!
run_for "$SYNTH_S" $CS synth "$WORK/v3" --train --views "$views" --views-per-scene 16 --shard-size 512 \
    --size 128x96 --seed 5000 --data-version 3 --workers "$half" > "$WORK/synth_v3.log" 2>&1 &
p3=$!
wait $p1 $p3
tail -n 1 "$WORK/synth_v1.log" "$WORK/synth_v3.log" | tee -a "$OUT/driver.log"
log "shards: v1 $(ls "$WORK"/v1/shard_*.safetensors 2>/dev/null | wc -l), v3 $(ls "$WORK"/v3/shard_*.safetensors 2>/dev/null | wc -l)"
DATA="$WORK/v1 $WORK/v3 $REAL/tum_fr3_cabinet_kf:8 $REAL/realsense_room_floorlevel_felixchenfy:8 $REAL/redwood_livingroom_synthetic_open3d:8"

# calibration: all runs at once for CAL_STEPS steps, each rate read from its log (its last 50-step window)
for r in $RUNS; do
  $CS train --data $DATA --out "$WORK/cal_$r" --config "scripts/issue13/gpu_$r.yaml" --device "$DEVICE" \
      --batch-size "$BATCH" --steps 100000 --stop-after "$CAL_STEPS" --no-progress > "$WORK/cal_$r.log" 2>&1 &
done
wait
declare -A steps
for r in $RUNS; do
  rate=$(python3 -c "
import csv
rows = list(csv.DictReader(open('$WORK/cal_$r/log.csv')))
print(rows[-1]['images_per_s'])" 2>/dev/null)
  steps[$r]=$(python3 -c "print(max(100, int(float('${rate:-0}') / $BATCH * $TRAIN_S * 0.9)))")
  log "$r: calibration ${rate:-?} images/s -> ${steps[$r]} steps"
  tail -n 3 "$WORK/cal_$r.log" >> "$OUT/driver.log"
done

for r in $RUNS; do
  run_for $(( TRAIN_S + 40 )) $CS train --data $DATA --out "$WORK/$r" --config "scripts/issue13/gpu_$r.yaml" \
      --device "$DEVICE" --batch-size "$BATCH" --steps "${steps[$r]}" --no-progress > "$WORK/$r.log" 2>&1 &
done
wait
mkdir -p "$WORK/logs"
for r in $RUNS; do
  tail -n 2 "$WORK/$r.log" >> "$OUT/driver.log"
  python3 scripts/export_weights.py "$WORK/$r" "$OUT/$r.safetensors" >> "$OUT/driver.log" 2>&1
  cp "$WORK/$r/log.csv" "$WORK/logs/${r}_log.csv" 2>/dev/null
  cp "$WORK/$r/val.csv" "$WORK/logs/${r}_val.csv" 2>/dev/null
done
log "done"
# the lease returns at most 8 files: the weights, and every log in one archive
cp "$OUT/driver.log" "$WORK/logs/" && tar -cf "$OUT/logs.tar" -C "$WORK" logs
