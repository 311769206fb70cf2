"""The figure of a painted run: per style, its picture and the run's render from `--views`
cameras spread along the scene's render path (all styles in one render per camera).

  python experiments/studies/painted/orbit_figure.py --run RUNS/lego_painted \\
      --out experiments/figures/lego_painted_orbit.png [--views 5] [--scale 2]
"""

import argparse

import numpy as np

from msnerf_jax.data import images as images_lib
from msnerf_jax.data import video
from msnerf_jax.kinds.painted import render_painted, style_images
from msnerf_jax.kinds.runs import load_run, scene_of


def main(argv=None):
  parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
  parser.add_argument("--run", required=True)
  parser.add_argument("--out", required=True)
  parser.add_argument("--views", type=int, default=5)
  parser.add_argument("--scale", type=int, default=2, help="each tile enlarged N times")
  args = parser.parse_args(argv)
  run = load_run(args.run, "painted")
  scene, _ = scene_of(run)
  poses = scene.render_poses[np.linspace(0, len(scene.render_poses), args.views,
                                         endpoint=False).astype(int)]
  frames = [render_painted(scene, run.params, run.config, c2w)["rgb"] for c2w in poses]
  h, w = scene.height * args.scale, scene.width * args.scale
  big = lambda x: images_lib.resize(np.asarray(x, np.float32), h, w)
  rows = [[big(images_lib.cover_crop(picture, scene.height, scene.width))]
          + [big(f[m]) for f in frames] for m, picture in enumerate(style_images(run))]
  print(video.write_grid(args.out, rows))


if __name__ == "__main__":
  main()
