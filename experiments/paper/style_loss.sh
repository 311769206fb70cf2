#!/usr/bin/env bash
# Patch style loss (beyond the paper's method: `--style-weight`). Trains the style heads on the
# same stylized dataset and trunk with the AdaIN statistics loss on rendered patches added, and
# evaluates it beside the standard variant in one table (PSNR and style distance trade off).
# Needs OUT from multistyle.sh. Usage: experiments/paper/style_loss.sh lego|fern NERF_RUN OUT [WEIGHT] [STEPS]
. "$(dirname "$0")/common.sh" "$1"
NERF="$2"; OUT="$3"; WEIGHT="${4:-0.01}"; STEPS="${5:-1000}"
msnerf multistyle train --nerf "$NERF" --stylized "$OUT/styles" --out "$OUT/ms_style$WEIGHT" \
  --style-weight "$WEIGHT" --style-patch 32 --steps "$STEPS"
msnerf multistyle eval --run "$OUT/ms_style$WEIGHT" --split $SPLIT
msnerf evaluate --run "$OUT/ms" "$OUT/ms_style$WEIGHT" --frames "$FRAMES" --out "$OUT/evaluate_style$WEIGHT"
footer "patch style loss (weight $WEIGHT), $SCENE"
