"""Seconds to render one held-out view of a NeRF run with the occupancy-grid sampler, for
several march_segments (early ray termination between segments), and the view's PSNR.

Usage:
  python experiments/benchmarks/render_segments.py --run RUN [--segments 2 4 8 16] [--split test]

Each count renders the view once to compile, then once timed. The image does not depend on
the count (up to the rays stopped at transmittance 1e-4).
"""

import argparse
import dataclasses
import time

import numpy as np

from msnerf_jax.eval import metrics
from msnerf_jax.kinds import runs
from msnerf_jax.kinds.views import render_view
from common import machine


def main():
  parser = argparse.ArgumentParser(description=__doc__,
                                   formatter_class=argparse.RawDescriptionHelpFormatter)
  parser.add_argument("--run", required=True)
  parser.add_argument("--segments", nargs="+", type=int, default=[2, 4, 8, 16])
  parser.add_argument("--split", default="test")
  args = parser.parse_args()
  run, scene = runs.load_run_and_scene(args.run, "nerf")
  view = int(scene.split(args.split)[0])
  print(f"# {args.run}: {args.split} view {view}, {scene.width}x{scene.height}; machine: "
        f"{machine()}")
  for segments in args.segments:
    config = dataclasses.replace(run.config, march_segments=segments)
    render_view(scene, run.params, config, view)  # compile
    start = time.time()
    out = render_view(scene, run.params, config, view)
    seconds = time.time() - start
    psnr = metrics.mse_to_psnr(np.mean((out["rgb"] - scene.images[view]) ** 2))
    print(f"segments {segments:3d}: {seconds:6.2f} s, PSNR {float(psnr):.2f} dB, mean opacity "
          f"{out['accumulation'].mean():.3f}", flush=True)


if __name__ == "__main__":
  main()
