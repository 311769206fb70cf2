#!/usr/bin/env bash
# Trains the CPU-budget AdaIN decoder on the shared content photos + lego/fern views and the shared
# styles (every 3rd image of each content folder held out for experiments/eval_adain.py), then
# evaluates it. Pinned to one core; ~35 min on one core of a 2-core AMD EPYC (1.5-1.7 images/s).
# (Measured pinned to one core with taskset -c 1.) Re-running resumes. Usage: experiments/train_adain_decoder.sh [RUN_DIR]
set -euo pipefail
D="${MSNERF_DATA:-$(dirname "$0")/../../shared/data}"
RUN="${1:-runs/adain_cpu}"
msnerf adain train \
  --content "$D/content" "$D/nerf_synthetic/lego/train" "$D/nerf_llff_data/fern/images_8" \
  --styles "$D/styles" --out "$RUN" \
  --size 96 --resize 192 --batch 2 --steps 1700 --lr 2e-4 --style-weight 1 \
  --holdout-every 3 --sample-every 100 --checkpoint-every 100
python "$(dirname "$0")/eval_adain.py" --decoder "$RUN" \
  --grid "$RUN/eval_grid.png" --json "$RUN/eval.json"
