"""PSNR of NeRF runs on a Blender scene's val views, split by the ground truth's alpha: the
object (alpha 255), empty space (alpha 0) and the partly covered edge pixels between.

Usage:
  python experiments/studies/region_psnr/region_psnr.py RUN [RUN ...]

Renders every val view of each run (composited over white, as evaluation does) and pools
the squared errors of all views per region. Whole-image PSNR rewards a NeRF that explains a
white background, or an antialiased edge, with semi-transparent density; the object's PSNR
does not (the empty-space benchmark, issue 21).
"""

import argparse
import os
import platform

import jax
import numpy as np

from msnerf_jax.eval import metrics
from msnerf_jax.kinds import runs
from msnerf_jax.kinds.views import render_view


def region_errors(run, scene):
  """{region: [P] squared errors (mean over RGB)} pooled over the scene's val views."""
  errors = {"object": [], "empty": [], "edge": [], "all": []}
  for view in scene.split("val"):
    rgb = np.clip(render_view(scene, run.params, run.config, int(view))["rgb"], 0, 1)
    err = np.mean((rgb - scene.images[view]) ** 2, -1)
    alpha = scene.alphas[view]
    errors["object"].append(err[alpha == 255])
    errors["empty"].append(err[alpha == 0])
    errors["edge"].append(err[(alpha > 0) & (alpha < 255)])
    errors["all"].append(err.ravel())
  return {k: np.concatenate(v) for k, v in errors.items()}


def main():
  parser = argparse.ArgumentParser(description=__doc__,
                                   formatter_class=argparse.RawDescriptionHelpFormatter)
  parser.add_argument("runs", nargs="+")
  args = parser.parse_args()
  print(f"# machine: {platform.processor() or platform.machine()}, {os.cpu_count()} cores, jax "
        f"{jax.__version__} on {jax.devices()[0].platform}")
  print(f"{'run':<44} {'object':>7} {'empty':>7} {'edge':>7} {'all':>7} {'edge px':>8} "
        f"{'edge err':>8}")
  for path in args.runs:
    run, scene = runs.load_run_and_scene(path, "nerf")
    if scene.alphas is None:
      parser.error(f"{path}: its scene has no alpha channel")
    errors = region_errors(run, scene)
    psnr = {k: float(metrics.mse_to_psnr(np.mean(v))) for k, v in errors.items()}
    share = errors["edge"].size / errors["all"].size
    error_share = errors["edge"].sum() / errors["all"].sum()
    print(f"{path:<44} {psnr['object']:7.2f} {psnr['empty']:7.2f} {psnr['edge']:7.2f} "
          f"{psnr['all']:7.2f} {share:8.1%} {error_share:8.1%}", flush=True)


if __name__ == "__main__":
  main()
