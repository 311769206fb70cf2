#!/usr/bin/env bash
# Issue 5: the stylized-3D evaluation of multi-style runs against per-frame AdaIN on the same
# camera path (40 frames): short/long-range warped RMSE + LPIPS and style distances, written as
# results.md/.csv/.json and frames.png per run. Usage:
#   experiments/evaluate_multistyle.sh OUT RUN [RUN ...]
# e.g. experiments/evaluate_multistyle.sh runs/eval_lego runs/lego_multistyle/run runs/lego_density/run
set -euo pipefail
OUT="$1"; shift
start=$(date +%s)
for RUN in "$@"; do
  name=$(basename "$(dirname "$RUN")")_$(basename "$RUN")
  msnerf evaluate --run "$RUN" --frames 40 --out "$OUT/$name"
done
echo "evaluated $# run(s) in $(( $(date +%s) - start )) s on $(nproc) cores ($(uname -m))"
