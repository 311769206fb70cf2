#!/usr/bin/env bash
# Styles never trained on (paper: the style vector of a new image): renders with the vector of
# 3 shared style images that are not among the training styles, against per-frame AdaIN with
# the same images (style distance table + grid), and one video per image.
# Needs OUT from multistyle.sh. Usage: experiments/paper/unseen_styles.sh lego|fern OUT
. "$(dirname "$0")/common.sh" "$1"
OUT="$2"
python "$(dirname "$0")/style_controls.py" --run "$OUT/ms" --out "$OUT/unseen" unseen "${UNSEEN[@]}"
for image in "${UNSEEN[@]}"; do
  name=$(basename "${image%.*}")
  msnerf render --run "$OUT/ms" --out "$OUT/unseen/$name" --style "$image" --frames "$FRAMES" \
    --morph "${NAMES[0]}" "$image"
done
footer "unseen styles, $SCENE"
