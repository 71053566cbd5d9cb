#!/bin/bash
# Issue 13, item 3 on a lent GPU: does `codeslam adapt` help the held-out half of a recording when it may run
# long and move further? One timed command; every job adapts the shipped weights on the adaptation half of a pack
# (scripts/issue13/adapt_sweep.py pack: frames, validity, `codeslam slam` poses of that half; no depth) and
# measures the zero-code prior on the held-out half before and after.
#
#   OUT=dir PACKS="p1.safetensors p2.safetensors" scripts/issue13/gpu_adapt.sh
#
# Env: DEVICE (cuda), ONLY (a regex: run only the jobs it matches), PAR (jobs at once, 6), BUDGET_S (no job starts after this many seconds, and every job is
#      killed then plus GRACE_S; 420 and 30).
# Writes $OUT/results.jsonl (one line per finished job), $OUT/logs.tar.gz and, per pack, the adapted weights of
# the job with the lowest held-out zero-code RMSE ($OUT/best_<pack>.safetensors).
set -u
out=${OUT:?OUT}; packs=${PACKS:?PACKS}
dev=${DEVICE:-cuda}; par=${PAR:-6}; budget=${BUDGET_S:-420}; grace=${GRACE_S:-30}
work=${WORK:-/tmp/gpu_adapt}
mkdir -p "$out" "$work/logs" "$work/w"
export PYTHONUNBUFFERED=1
py=${PYTHON:-python3}
$py -c "import torch; print('torch', torch.__version__, torch.cuda.is_available() and torch.cuda.get_device_name())"

# name|settings, in the order they start (most informative first). The sweeps of 2026-11-26 adapted all weights,
# the default then; since 2026-11-27 `codeslam adapt` adapts the zero-code path only (AdaptConfig.trainable), so
# those jobs name trainable=all.
all="--set trainable=all"
jobs=(
  "card|"
  "zc_1e-3_3k|--set steps=3000 --set lr=1e-3"
  "card_all|$all --set lr=1e-5"
  "lr1e-4_a1_3k|$all --set steps=3000 --set lr=1e-4 --set anchor=1"
  "lr1e-4_3k|$all --set steps=3000 --set lr=1e-4"
  "lr3e-4_a0.1_3k|$all --set steps=3000 --set lr=3e-4 --set anchor=0.1"
  "lr1e-4_a1_3k_b24|$all --set steps=3000 --set lr=1e-4 --set anchor=1 --set batch=24"
  "lr1e-4_a1_3k_noscale|$all --set steps=3000 --set lr=1e-4 --set anchor=1 --set scale_anchor=0"
  "lr1e-4_a1_8k|$all --set steps=8000 --set lr=1e-4 --set anchor=1"
  "lr1e-4_a1_2k|$all --set steps=2000 --set lr=1e-4 --set anchor=1"
  "lr1e-4_a1_2k_s10|$all --set steps=2000 --set lr=1e-4 --set anchor=1 --set scale_anchor=10"
)
start=$SECONDS
pids=()
for j in "${jobs[@]}"; do
  name=${j%%|*}; sets=${j#*|}
  [[ "$name" =~ ${ONLY:-.} ]] || continue
  for p in $packs; do
    pk=$(basename "$p" .safetensors)
    while [ "$(jobs -rp | wc -l)" -ge "$par" ]; do sleep 1; done
    left=$(( budget - (SECONDS - start) ))
    [ "$left" -le 20 ] && { echo "budget spent: $pk/$name not started"; continue; }
    echo "[$((SECONDS - start)) s] start $pk/$name"
    timeout -k 5 $(( left + grace )) $py scripts/issue13/adapt_sweep.py run "$p" --name "${pk}_$name" \
        --device "$dev" --max-seconds $(( left - 30 )) --results "$out/results.jsonl" --work "$work/w" $sets > "$work/logs/${pk}_$name.log" 2>&1 &
    pids+=($!)
  done
done
wait
echo "[$((SECONDS - start)) s] all done"
cat "$out/results.jsonl" 2>/dev/null | $py -c "
import json, sys, shutil
rows = [json.loads(l) for l in sys.stdin]
best = {}
for r in rows:
    b, a = r['before'], r['after']
    print(f\"{r['name']:40s} {r['seconds']:7.1f} s  zero {b['zero_rmse']:.4f} -> {a['zero_rmse']:.4f}  \"
          f\"scaled {b['si_rmse']:.4f} -> {a['si_rmse']:.4f}  median {b['median_depth_ratio']:.3f} -> \"
          f\"{a['median_depth_ratio']:.3f}  ratio {a['ratio']:.3f}\")
    k = r['pack']
    if r.get('finished') and (k not in best or a['zero_rmse'] < best[k]['after']['zero_rmse']):
        best[k] = r
for k, r in best.items():
    shutil.copyfile(f\"$work/w/{r['name']}/weights.safetensors\", f\"$out/best_{k}\")
    print('kept', r['name'], 'as', f'best_{k}')
"
for d in "$work"/w/*/; do cp "$d/log.csv" "$work/logs/$(basename "$d")_log.csv" 2>/dev/null; done
tar -czf "$out/logs.tar.gz" -C "$work" logs
