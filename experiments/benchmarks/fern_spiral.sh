#!/usr/bin/env bash
# Fern at factor 8 (504x378) with NDC rays, preset cpu: train, evaluate on the held-out views,
# render the spiral path as MP4/GIF (+ depth).
# Usage: experiments/benchmarks/fern_spiral.sh [STEPS] [OUT] [FRAMES]
set -euo pipefail
DATA="${MSNERF_DATA:-../shared/data}/nerf_llff_data/fern"
STEPS="${1:-3500}"
OUT="${2:-runs/fern_cpu}"
FRAMES="${3:-16}"
start=$(date +%s)
msnerf nerf train --data "$DATA" --out "$OUT" --preset cpu --steps "$STEPS"
t_train=$(date +%s)
msnerf nerf eval --run "$OUT" --split test
t_eval=$(date +%s)
msnerf nerf render --run "$OUT" --out "$OUT/spiral" --frames "$FRAMES" --fps 8
end=$(date +%s)
echo "fern: $STEPS steps, train $(( t_train - start )) s, eval $(( t_eval - t_train )) s," \
     "render $FRAMES frames $(( end - t_eval )) s, total $(( end - start )) s" \
     "(nproc $(nproc), affinity $(taskset -pc $$ | sed 's/.*: //'), $(uname -m))"
