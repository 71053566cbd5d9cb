#!/bin/bash
# The issue-13 ablation: short fine-tunes of the shipped weights on different training data, each measured with
# scripts/depth_prior_eval.py. Data made by (see codeslam/weights/MODEL_CARD.md):
#   codeslam synth /work/train_data/synth128_v2 --train --views 16384 --views-per-scene 16 --shard-size 512 \
#       --size 128x96 --seed 3000 --data-version 2 --workers 2
#   codeslam synth /work/train_data/synth128_v3 --train --views 8192 --views-per-scene 16 --shard-size 512 \
#       --size 128x96 --seed 5000 --data-version 3 --workers 2
#   codeslam synth /work/train_data/synth128_v1 --train --views 8192 --views-per-scene 16 --shard-size 512 \
#       --size 128x96 --seed 1000 --workers 2     # the first half of the shipped weights' own training data
#   python scripts/split_real_rgbd.py             # ../shared/train_data -> real_split/{train,val}
# Usage: [STEPS=N] scripts/issue13/ablation.sh NAME...  (names below; eval-NAME only measures); runs go to $RUNS
# (default /work/train_data/runs); STEPS overrides the configs' 1,500 steps.
set -e
cd "$(dirname "$0")/../.."
RUNS=${RUNS:-/work/train_data/runs}
D=/work/train_data
REAL="$D/real_split/train/tum_fr3_cabinet_kf:8 $D/real_split/train/realsense_room_floorlevel_felixchenfy:8 $D/real_split/train/redwood_livingroom_synthetic_open3d:8"
for name in "$@"; do
  case $name in
    v1) data="$D/synth128_v1"; cfg=scripts/issue13/finetune.yaml ;;
    v2) data="$D/synth128_v2"; cfg=scripts/issue13/finetune.yaml ;;
    v2fx) data="$D/synth128_v2"; cfg=scripts/issue13/effects.yaml ;;
    v2fxreal) data="$D/synth128_v2 $REAL"; cfg=scripts/issue13/effects.yaml ;;
    v1fx) data="$D/synth128_v1"; cfg=scripts/issue13/effects.yaml ;;
    v3) data="$D/synth128_v3"; cfg=scripts/issue13/finetune.yaml ;;
    v3fx) data="$D/synth128_v3"; cfg=scripts/issue13/effects.yaml ;;
    v3fxreal) data="$D/synth128_v3 $REAL"; cfg=scripts/issue13/effects.yaml ;;
    v3border) data="$D/synth128_v3"; cfg=scripts/issue13/border.yaml ;;
    v3borderreal) data="$D/synth128_v3 $REAL"; cfg=scripts/issue13/border.yaml ;;
    v13borderreal) data="$D/synth128_v1 $D/synth128_v3 $REAL"; cfg=scripts/issue13/border.yaml ;;
    v13fxreal) data="$D/synth128_v1 $D/synth128_v3 $REAL"; cfg=scripts/issue13/effects.yaml ;;
    final) data="$D/synth128_v1 $D/synth128_v3 $REAL"; cfg=scripts/issue13/final.yaml ;;
    eval-*) data=""; name=${name#eval-} ;;
    *) echo "unknown run $name"; exit 2 ;;
  esac
  [ -n "$data" ] && python3 -m codeslam train --data $data --out "$RUNS/$name" --config $cfg --threads 1 --no-progress --resume ${STEPS:+--steps $STEPS}
  python3 scripts/depth_prior_eval.py --weights "$RUNS/$name/weights.safetensors" --json "$RUNS/$name/prior_eval.json" \
      --markdown "$RUNS/$name/prior_eval.md" --threads 1
done
