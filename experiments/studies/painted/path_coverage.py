"""Where a painted run's render path draws its colours from: the share of the composite
weight along the scene's camera path that falls on unpainted vertices (outside the run's
index: the grey row) and on painted vertices none of the painting's views sees (the
training views, and the path's cameras for runs painted with --path-views; the trainer
fills those from the nearest seen vertex since paint_coverage), with how grey the painted
frames are there. A render path that leaves the photos' sight (the cup capture's) shows it.

  python experiments/studies/painted/path_coverage.py --run RUNS/painted [--frames 20]

Prints one line per run, and the machine line.
"""

import argparse
import os
import platform
import sys

import numpy as np


def coverage(run_dir: str, frames: int):
  """{"unpainted", "unseen"}: shares of the path's composite weight; "vertices", "painted"."""
  # pylint: disable=g-import-not-at-top
  from msnerf_jax.eval.paths import path_poses
  from msnerf_jax.kinds.runs import load_run, scene_of
  from msnerf_jax.models.nerf import NerfField
  from msnerf_jax.models.painted_field import corners
  from msnerf_jax.nerf import sample_cache
  from msnerf_jax.train import paint_data
  from msnerf_jax.train.paint_coverage import seen_vertices
  run = load_run(run_dir, "painted")
  scene, _ = scene_of(run)
  nerf_run = load_run(run.record["nerf_run"], "nerf")
  cache = paint_data.read_cache(os.path.join(run_dir, paint_data.CACHE_FILE),
                                paint_data.cache_source(nerf_run))
  index = np.asarray(run.params["paint"]["index"])
  count, box = run.params["paint"]["colours"].shape[1] - 1, run.config.scene_box
  cache, _ = paint_data.painting_views(cache, scene, nerf_run, run.config)
  seen = seen_vertices(cache, index, count, box)
  field = NerfField(nerf_run.config)
  total = unpainted = unseen = 0.0
  for c2w in path_poses(scene, frames):
    lists = sample_cache.view_samples(field, nerf_run.params, scene.camera_rays(c2w),
                                      nerf_run.config, run.config.top_k,
                                      run.config.cache_threshold)
    flat, tri = corners(lists["points"], index.shape[0], box, np)
    rows = index.reshape(-1)[flat]
    spread = lists["weights"][:, None] * tri
    total += spread.sum()
    unpainted += spread[rows == count].sum()
    unseen += spread[(rows < count) & ~seen[rows]].sum()
  return {"unpainted": unpainted / total, "unseen": unseen / total, "painted": count,
          "vertices": index.size}


def main(argv=None):
  parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
  parser.add_argument("--run", nargs="+", required=True, help="painted runs")
  parser.add_argument("--frames", type=int, default=20, help="cameras along the path")
  args = parser.parse_args(argv)
  for run_dir in args.run:
    c = coverage(run_dir, args.frames)
    print(f"{run_dir}: {c['painted']:,} of {c['vertices']:,} vertices painted; along the "
          f"path {100 * c['unpainted']:.1f}% of the composite weight on unpainted vertices, "
          f"{100 * c['unseen']:.1f}% on painted ones no training view sees")
  print(f"machine: {platform.processor() or platform.machine()}, {os.cpu_count()} cores, "
        f"python {sys.version.split()[0]}")


if __name__ == "__main__":
  main()
