#!/usr/bin/env bash
# Trains the CPU-budget AdaIN decoder on the shared content photos + lego/fern views and the shared
# styles (every 3rd image of each content folder held out for experiments/tools/eval_adain.py), then
# evaluates it on the held-out images (style-loss ratio, edge correlation, grid). Style weight 10
# (the AdaIN paper's), 96 px crops of images resized to 192, batch 4, Adam 3e-4, 3000 steps:
# about 38 minutes on both cores of an idle 2-core AMD EPYC (1.3 steps/s; see README).
# Re-running resumes; a larger --steps trains longer.
# Usage: experiments/tools/train_adain_decoder.sh [RUN_DIR [STYLES_DIR [FLAG...]]]
#   STYLES_DIR: another styles folder (default: the shared styles); FLAGs go to `msnerf adain
#   train` after the recipe's and override them (e.g. --init-from RUN --steps 500 --shift-weight 1000).
set -euo pipefail
D="${MSNERF_DATA:-$(dirname "$0")/../../../shared/data}"
RUN="${1:-runs/adain_cpu}"
STYLES="${2:-$D/styles}"
shift $(( $# < 2 ? $# : 2 ))
start=$(date +%s)
msnerf adain train \
  --content "$D/content" "$D/nerf_synthetic/lego/train" "$D/nerf_llff_data/fern/images_8" \
  --styles "$STYLES" --out "$RUN" \
  --size 96 --resize 192 --batch 4 --steps 3000 --lr 3e-4 --style-weight 10 \
  --holdout-every 3 --sample-every 250 --checkpoint-every 250 "$@"
t_train=$(date +%s)
python "$(dirname "$0")/eval_adain.py" --decoder "$RUN" \
  --grid "$RUN/eval_grid.png" --json "$RUN/eval.json"
echo "decoder: train $(( t_train - start )) s, eval $(( $(date +%s) - t_train )) s on $(nproc) cores ($(uname -m))"
