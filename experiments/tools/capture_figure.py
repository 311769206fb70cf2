"""Held-out views of NeRF runs next to their photos: one pair of rows (photos, renders) per run.

  python experiments/tools/capture_figure.py --run RUN [RUN ...] --views 4 \
      --out experiments/figures/captures_heldout.jpg

Each run is rendered at `--views` evenly spaced views of its val split, with each view's own
intrinsics and lens (what `msnerf nerf eval` renders); prints the PSNR of each shown view.
"""

import argparse
import os

import numpy as np

from msnerf_jax.eval import metrics
from msnerf_jax.kinds import runs
from msnerf_jax.data import video
from msnerf_jax.kinds import views


def main():
  parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
  parser.add_argument("--run", nargs="+", required=True)
  parser.add_argument("--views", type=int, default=4)
  parser.add_argument("--out", required=True)
  args = parser.parse_args()
  rows = []
  for run_dir in args.run:
    run, scene = runs.load_run_and_scene(run_dir, "nerf")
    val = scene.split("val")
    chosen = val[np.linspace(0, len(val) - 1, args.views).round().astype(int)]
    photos, renders = [], []
    for i in chosen:
      rgb = views.render_view(scene, run.params, run.config, int(i))["rgb"]
      psnr = float(metrics.mse_to_psnr(np.mean((rgb - scene.images[i]) ** 2)))
      print(f"{run_dir} view {os.path.basename(scene.image_paths[i])}: {psnr:.2f} dB")
      photos.append(scene.images[i])
      renders.append(np.clip(rgb, 0, 1))
    rows += [photos, renders]
  heights = {r[0].shape for r in rows}
  if len(heights) > 1:  # runs of different sizes: pad each image to the largest
    h = max(s[0] for s in heights)
    w = max(s[1] for s in heights)
    rows = [[np.pad(x, ((0, h - x.shape[0]), (0, w - x.shape[1]), (0, 0)), constant_values=1.0)
             for x in row] for row in rows]
  print("written", video.write_grid(args.out, rows))


if __name__ == "__main__":
  main()
