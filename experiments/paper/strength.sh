#!/usr/bin/env bash
# Strength from the original scene to a style (paper: interpolating with the original's
# vector): 5 strengths x 3 views with the style distance and the PSNR against the photo-real
# NeRF, and a video whose style grows from the original to the style.
# Needs OUT from multistyle.sh. Usage: experiments/paper/strength.sh lego|fern OUT [STYLE]
. "$(dirname "$0")/common.sh" "$1"
OUT="$2"; STYLE="${3:-brushstrokes}"
python "$(dirname "$0")/style_controls.py" --run "$OUT/ms" --out "$OUT/strength_$STYLE" strength "$STYLE"
msnerf render --run "$OUT/ms" --out "$OUT/strength_$STYLE/video" --style "$STYLE" --strength 0.5 \
  --morph original "$STYLE" --frames "$FRAMES"
footer "strength original -> $STYLE, $SCENE"
