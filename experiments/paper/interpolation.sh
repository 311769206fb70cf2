#!/usr/bin/env bash
# Interpolation A -> B (paper: blends of two style vectors): a grid of 5 blends x 3 views with
# the distance of each blend to A and to B, and a video whose style moves from A to B.
# Needs OUT from multistyle.sh. Usage: experiments/paper/interpolation.sh lego|fern OUT [A B]
. "$(dirname "$0")/common.sh" "$1"
OUT="$2"; A="${3:-asheville}"; B="${4:-mondrian}"
python "$(dirname "$0")/style_controls.py" --run "$OUT/ms" --out "$OUT/interp_${A}_$B" interp "$A" "$B"
msnerf render --run "$OUT/ms" --out "$OUT/interp_${A}_$B/video" --interp "$A" "$B" --t 0.5 \
  --morph "$A" "$B" --frames "$FRAMES"
footer "interpolation $A -> $B, $SCENE"
