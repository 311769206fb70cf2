#!/usr/bin/env bash
# Fern at factor 8 (504x378) with NDC rays, preset cpu: train, evaluate on the held-out views,
# render the spiral path as MP4/GIF (+ depth). Usage: experiments/fern_spiral.sh [STEPS] [OUT]
set -euo pipefail
DATA="${MSNERF_DATA:-../shared/data}/nerf_llff_data/fern"
STEPS="${1:-3000}"
OUT="${2:-runs/fern_cpu}"
start=$(date +%s)
msnerf nerf train --data "$DATA" --out "$OUT" --preset cpu --steps "$STEPS"
msnerf nerf eval --run "$OUT" --split test
msnerf nerf render --run "$OUT" --out "$OUT/spiral" --frames 60
echo "fern: $STEPS steps, total $(( $(date +%s) - start )) s on $(nproc) cores ($(uname -m))"
