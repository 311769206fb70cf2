#!/usr/bin/env bash
# Multi-style NeRF on lego at 100x100 with 4 shared styles (+ the original views), issue 4:
# stylize every view with a trained AdaIN decoder, train the style heads on the frozen trunk
# of a trained lego NeRF (experiments/bench_lego_cpu.py or `msnerf nerf train ... --downscale 8`),
# evaluate per-style PSNR/SSIM on the 9 held-out val views, render videos and the grid.
# Usage: experiments/multistyle_lego.sh NERF_RUN ADAIN_RUN [OUT] [STEPS]
set -euo pipefail
NERF="$1"
DECODER="$2"
OUT="${3:-runs/lego_multistyle}"
STEPS="${4:-3000}"
D="${MSNERF_DATA:-$(dirname "$0")/../../shared/data}"
S="$D/styles"
start=$(date +%s)
msnerf stylize-scene --data "$D/nerf_synthetic/lego" --downscale 8 --decoder "$DECODER" \
  --styles "$S/asheville.jpg" "$S/brushstrokes.jpg" "$S/mondrian.jpg" \
  "$S/woman_in_peasant_dress.jpg" --include-original --out "$OUT/styles"
msnerf multistyle train --nerf "$NERF" --stylized "$OUT/styles" --out "$OUT/run" --steps "$STEPS"
msnerf multistyle eval --run "$OUT/run"
msnerf render --run "$OUT/run" --out "$OUT/video" --style mondrian --morph asheville mondrian \
  --grid-steps 5 --grid-views 3
msnerf render --run "$OUT/run" --out "$OUT/strength" --style brushstrokes --strength 0.5 \
  --frames 20
echo "lego multi-style: $STEPS steps, total $(( $(date +%s) - start )) s on $(nproc) cores ($(uname -m))"
