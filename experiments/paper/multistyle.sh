#!/usr/bin/env bash
# Multi-style results (paper: the multi-style NeRF in every training style). Stylizes every view
# with the 4 shared styles (+ the original), trains the style heads on the frozen trunk of
# NERF_RUN, reports per-style PSNR/SSIM on the held-out stylized views, renders a video and
# an interpolation grid, and the consistency/style table against per-frame AdaIN.
# Usage: experiments/paper/multistyle.sh lego|fern NERF_RUN ADAIN_RUN OUT [STEPS]
. "$(dirname "$0")/common.sh" "$1"
NERF="$2"; DECODER="$3"; OUT="$4"; STEPS="${5:-3000}"
msnerf stylize-scene --data "$DATA" --downscale $DOWNSCALE --decoder "$DECODER" \
  --styles "${STYLES[@]}" --include-original --stylize-scale $STYLIZE_SCALE --out "$OUT/styles"
msnerf multistyle train --nerf "$NERF" --stylized "$OUT/styles" --out "$OUT/ms" --steps "$STEPS"
msnerf multistyle eval --run "$OUT/ms" --split $SPLIT
msnerf render --run "$OUT/ms" --out "$OUT/video" --style mondrian --morph asheville mondrian \
  --grid-steps 5 --grid-views 3
msnerf evaluate --run "$OUT/ms" --frames "$FRAMES" --out "$OUT/evaluate"
footer "multi-style results, $SCENE"
