#!/usr/bin/env bash
# Trains the CPU-budget AdaIN decoder on the shared content photos + lego/fern views and the shared
# styles (every 3rd image of each content folder held out for experiments/eval_adain.py), then
# evaluates it. Style weight 10 (the AdaIN paper's). 2800 steps at the 1.35 s/step measured on one
# free core of a 2-core AMD EPYC = ~63 min (the run in README was stopped at step 1500, ratio
# 0.33; the 0.25 target is not reached yet). Run pinned: nice -n 5 taskset -c 0 ... Re-running resumes. Usage: experiments/train_adain_decoder.sh [RUN_DIR]
set -euo pipefail
D="${MSNERF_DATA:-$(dirname "$0")/../../shared/data}"
RUN="${1:-runs/adain_cpu2}"
msnerf adain train \
  --content "$D/content" "$D/nerf_synthetic/lego/train" "$D/nerf_llff_data/fern/images_8" \
  --styles "$D/styles" --out "$RUN" \
  --size 96 --resize 192 --batch 2 --steps 2800 --lr 2e-4 --style-weight 10 \
  --holdout-every 3 --sample-every 100 --checkpoint-every 100
python "$(dirname "$0")/eval_adain.py" --decoder "$RUN" \
  --grid "$RUN/eval_grid.png" --json "$RUN/eval.json"
