#!/usr/bin/env bash
# Single vs multi (paper: one NeRF per style against one multi-style NeRF). Trains a NeRF on
# each style's stylized views alone, from scratch (preset cpu, STEPS steps), reports their
# held-out PSNR, and evaluates them beside the multi-style run in one table.
# Needs OUT from multistyle.sh. Usage:
#   experiments/paper/single_vs_multi.sh lego|fern OUT [STEPS [STYLE ...]]  (default: all 4 styles)
. "$(dirname "$0")/common.sh" "$1"
OUT="$2"; STEPS="${3:-3000}"
CHOSEN=("${@:4}")
[ ${#CHOSEN[@]} -gt 0 ] || CHOSEN=("${NAMES[@]}")
SINGLES=()
for name in "${CHOSEN[@]}"; do
  msnerf nerf train --data "$DATA" --downscale $DOWNSCALE --preset cpu --steps "$STEPS" \
    --stylized "$OUT/styles" --style "$name" --out "$OUT/single_$name"
  msnerf nerf eval --run "$OUT/single_$name" --split $SPLIT
  SINGLES+=("$OUT/single_$name")
done
msnerf evaluate --run "$OUT/ms" --single-style "${SINGLES[@]}" --styles "${CHOSEN[@]}" \
  --frames "$FRAMES" \
  --out "$OUT/evaluate_single_vs_multi"
footer "single vs multi, $SCENE"
