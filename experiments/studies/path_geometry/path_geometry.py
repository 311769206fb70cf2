"""What a NeRF's geometry does to the consistency measurement along its camera path.

For each NeRF run: render the scene's path (as `msnerf evaluate` does), then report what
`consistency.warp` counts (the share of pixels where both frames see a surface, opacity
> 0.5, and the warp lands unoccluded) and the warped RMSE of the NeRF's own photo-real
frames at k = 1 and 7, plus the share of pixels the NeRF renders opaque (what the per-frame
AdaIN baseline keeps stylized on Blender scenes). Fog in empty space inflates the counted
share with pixels that are not the object.

Usage: python experiments/studies/path_geometry/path_geometry.py --run NERF_RUN [NERF_RUN ...]
    [--frames 40]
"""

import argparse
import os
import platform
import time

import jax
import numpy as np

from msnerf_jax.eval import consistency
from msnerf_jax.kinds.runs import load_run_and_scene
from msnerf_jax.kinds import views


def main():
  parser = argparse.ArgumentParser(description=__doc__,
                                   formatter_class=argparse.RawDescriptionHelpFormatter)
  parser.add_argument("--run", nargs="+", required=True)
  parser.add_argument("--frames", type=int, default=40)
  args = parser.parse_args()
  print(f"# {platform.machine()}, {os.cpu_count()} cores, jax {jax.__version__} on "
        f"{jax.devices()[0].platform}; {args.frames} frames of the render path")
  print(f"{'run':<40} {'opaque':>7} {'counted_k1':>10} {'rmse_k1':>8} {'counted_k7':>10} "
        f"{'rmse_k7':>8} {'seconds':>8}")
  for run_dir in args.run:
    t0 = time.time()
    run, scene = load_run_and_scene(run_dir, "nerf")
    poses = scene.path_poses(args.frames)
    outs = [views.render_view(scene, run.params, run.config, c2w) for c2w in poses]
    frames = [o["rgb"] for o in outs]
    depths = [o["depth"] for o in outs]
    accs = [o["accumulation"] for o in outs]
    opaque = float(np.mean([(a > 0.5).mean() for a in accs]))
    row = {}
    for k in (1, 7):
      row[k] = consistency.consistency(frames, depths, accs, poses, scene.K, scene.ndc, k)
    print(f"{run_dir:<40} {opaque:7.3f} {row[1]['coverage']:10.3f} {row[1]['rmse']:8.4f} "
          f"{row[7]['coverage']:10.3f} {row[7]['rmse']:8.4f} {time.time() - t0:8.1f}",
          flush=True)


if __name__ == "__main__":
  main()
