#!/usr/bin/env bash
# The feature field on fern (factor 8, stylize scale 1) against per-frame AdaIN, from nothing:
#   1. a `fast` fern NeRF (hash trunk + occupancy grid + distortion loss), 3000 steps;
#   2. the AdaIN decoder of tools/train_adain_decoder.sh on the 12 shared styles other than
#      en_campo_gris, picasso_seated_nude_hr and scene_de_rue (held out of the decoder);
#   3. a feature run of 2000 steps on that NeRF, with a 256-channel feature from 16 levels of
#      16 hash features (the default 64 from 4 explains less of fern's relu4_1: README);
#   4. the decoder fine-tuned for shift consistency (500 steps, --shift-source features);
#   5. the decoder fine-tuned on the feature run's own renders (600 steps, half of each batch
#      crops of its maps, --content-features) with three times that shift loss (the decoder
#      that meets every fern target but the warped RMSE);
#      train_adain_decoder.sh evaluates each decoder on its held-out images too;
#   6. feature_field.py with each decoder: 15 spiral frames, 5 styles (scene_de_rue held out).
# About 3 hours on an idle 2-core CPU (README, "Feature field: AdaIN in 3D"). Re-running resumes.
# Usage: experiments/studies/feature_field/feature_field_fern.sh [OUT_DIR]  (default runs/fern_features)
set -euo pipefail
D="${MSNERF_DATA:-$(dirname "$0")/../../../../shared/data}"
OUT="${1:-runs/fern_features}"
HERE="$(cd "$(dirname "$0")" && pwd)"
TOOLS="$HERE/../../tools"
mkdir -p "$OUT/styles12"
for f in "$D"/styles/*; do
  case "$(basename "$f")" in
    en_campo_gris*|picasso_seated_nude_hr*|scene_de_rue*) ;;
    *) ln -sf "$(cd "$(dirname "$f")" && pwd)/$(basename "$f")" "$OUT/styles12/" ;;
  esac
done
S="$D/styles"
STYLES=("$S/asheville.jpg" "$S/brushstrokes.jpg" "$S/mondrian.jpg" "$S/woman_in_peasant_dress.jpg"
  "$S/scene_de_rue.jpg")
start=$(date +%s)
msnerf nerf train --data "$D/nerf_llff_data/fern" --downscale 8 --preset fast --steps 3000 \
  --out "$OUT/nerf"
"$TOOLS/train_adain_decoder.sh" "$OUT/decoder" "$OUT/styles12"
msnerf features train --nerf "$OUT/nerf" --decoder "$OUT/decoder" --out "$OUT/features" \
  --steps 2000 --stylize-scale 1 --hash-features 16 --dim 256
"$TOOLS/train_adain_decoder.sh" "$OUT/decoder_shift" "$OUT/styles12" --init-from "$OUT/decoder" \
  --steps 500 --lr 1e-4 --shift-weight 1000 --shift-source features
"$TOOLS/train_adain_decoder.sh" "$OUT/decoder_field" "$OUT/styles12" --init-from "$OUT/decoder" \
  --steps 600 --lr 1e-4 --content-features "$OUT/features" --shift-weight 3000 \
  --shift-source features
for dec in decoder_field decoder_shift decoder; do
  python "$HERE/feature_field.py" --features "$OUT/features" --decoder "$OUT/$dec" \
    --frames 15 --heldout 3 --styles "${STYLES[@]}" --out "$OUT/compare_$dec"
done
echo "feature_field_fern: $(( $(date +%s) - start )) s on $(nproc) cores ($(uname -m))"
