"""Seconds to render one held-out view with a preset's network, untrained: the hierarchical
sampler's cost does not depend on training (a fixed number of samples a ray), so this times
a preset's rendering without training it first. (The grid sampler's does depend on it: time
a trained run with experiments/benchmarks/render_segments.py.)

Usage:
  python experiments/benchmarks/render_untrained.py --data SCENE [--preset cpu] [--downscale 8]
      [--split test]
"""

import argparse
import time

import jax

from msnerf_jax.core.config import DataConfig, nerf_preset
from msnerf_jax.data.scene import load_scene
from msnerf_jax.models.nerf import init_nerf_params
from msnerf_jax.train import nerf
from msnerf_jax.kinds.views import render_view
from common import machine


def main():
  parser = argparse.ArgumentParser(description=__doc__,
                                   formatter_class=argparse.RawDescriptionHelpFormatter)
  parser.add_argument("--data", required=True)
  parser.add_argument("--preset", default="cpu")
  parser.add_argument("--downscale", type=int, default=8)
  parser.add_argument("--split", default="test")
  args = parser.parse_args()
  scene, _ = load_scene(DataConfig(path=args.data, downscale=args.downscale))
  config = nerf.resolve_config(nerf_preset(args.preset, scene.format), scene)
  if config.sampler == "grid":
    parser.error(f"--preset {args.preset}: the grid sampler's cost depends on training; "
                 "use experiments/benchmarks/render_segments.py on a trained run")
  params = init_nerf_params(config, jax.random.PRNGKey(0))
  view = int(scene.split(args.split)[0])
  render_view(scene, params, config, view)  # compile
  start = time.time()
  render_view(scene, params, config, view)
  print(f"# machine: {machine()}")
  print(f"preset {args.preset}, {args.split} view {view} ({scene.width}x{scene.height}): "
        f"{time.time() - start:.2f} s")


if __name__ == "__main__":
  main()
