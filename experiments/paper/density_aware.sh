#!/usr/bin/env bash
# Density-aware variant (paper: a style-conditioned density head). Trains it on the same
# stylized dataset and trunk, and evaluates it beside the standard variant in one table.
# Needs OUT from multistyle.sh. Usage: experiments/paper/density_aware.sh lego|fern NERF_RUN OUT [STEPS]
. "$(dirname "$0")/common.sh" "$1"
NERF="$2"; OUT="$3"; STEPS="${4:-3000}"
msnerf multistyle train --nerf "$NERF" --stylized "$OUT/styles" --out "$OUT/ms_density" \
  --density-aware --steps "$STEPS"
msnerf multistyle eval --run "$OUT/ms_density" --split $SPLIT
msnerf evaluate --run "$OUT/ms" "$OUT/ms_density" --frames "$FRAMES" --out "$OUT/evaluate_density"
footer "density-aware, $SCENE"
