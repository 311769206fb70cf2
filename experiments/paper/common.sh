# Shared by the paper experiments: the scene, its split and the four shared training styles.
# Usage (sourced): . "$(dirname "$0")/common.sh" SCENE   (SCENE: lego or fern)
set -euo pipefail
D="${MSNERF_DATA:-$(cd "$(dirname "${BASH_SOURCE[0]}")/../../.." && pwd)/shared/data}"
S="$D/styles"
case "${1:-}" in
  # STYLIZE_SCALE: views are stylized at the reference code's resolution (lego 400x400, fern
  # 504x378), then trained on at ours (stylize-scene --stylize-scale).
  # FRAMES: frames of the evaluated and rendered camera paths (fern's are 19x lego's pixels).
  lego) DATA="$D/nerf_synthetic/lego"; SPLIT=val; STYLIZE_SCALE=4; FRAMES=${FRAMES:-40} ;;  # 100x100 (--downscale 8), 9 val views
  fern) DATA="$D/nerf_llff_data/fern"; SPLIT=test; STYLIZE_SCALE=1; FRAMES=${FRAMES:-16} ;; # 504x378 (factor 8), every 8th view held out
  *) echo "first argument: lego or fern" >&2; exit 2 ;;
esac
SCENE="$1"
DOWNSCALE=8
STYLES=("$S/asheville.jpg" "$S/brushstrokes.jpg" "$S/mondrian.jpg" "$S/woman_in_peasant_dress.jpg")
NAMES=(asheville brushstrokes mondrian woman_in_peasant_dress)
UNSEEN=("$S/picasso_seated_nude_hr.jpg" "$S/scene_de_rue.jpg" "$S/sketch.png")
START=$(date +%s)
footer() {  # the wall time and the hardware, last line of every experiment
  echo "$1: $(( $(date +%s) - START )) s wall on $(nproc) cores, $(grep -m1 'model name' /proc/cpuinfo | sed 's/.*: //') ($(uname -m))"
}
