"""The GPU benchmark (issue 47, item 5): lego at full size with the `fast` preset for five
minutes of training, then held-out PSNR, training rays/s, render frames/s (exact and baked)
and peak device memory, in one table. Under 8 minutes end to end on one GPU.

Usage (on the GPU machine, after `pip install -U "jax[cuda12]" && pip install .`):
  python experiments/benchmarks/gpu_bench.py [--scene lego800] [--minutes 5] [--views 8]
On a CPU, to see that it works (lego 100x100, one minute):
  python experiments/benchmarks/gpu_bench.py --scene lego --minutes 1

Training stops at the first checkpoint (every --checkpoint-every steps) past the budget;
PSNR is the mean over the first --views val views; a frame is one val view, rendered three
times after a compiling call, by the exact renderer and from the run's bake.
"""

import argparse
import os
import resource
import shutil
import time

import jax
import numpy as np

from msnerf_jax.core.config import DataConfig, nerf_preset, override
from msnerf_jax.data.scene import load_scene
from msnerf_jax.eval import metrics
from msnerf_jax.kinds import baked as baked_run
from msnerf_jax.kinds import runs
from msnerf_jax.kinds.views import render_view
from msnerf_jax.train import nerf
from bench_presets import SCENES
from common import DATA, machine
from timed_training import train_within


def peak_memory() -> str:
  """The device's peak memory in use (GPU), else this process's peak resident memory."""
  stats = jax.devices()[0].memory_stats() or {}
  if "peak_bytes_in_use" in stats:
    return f"{stats['peak_bytes_in_use'] / 2**30:.2f} GiB on {jax.devices()[0].platform}"
  return f"{resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 2**20:.2f} GiB (host RSS)"


def frames_per_second(draw, repeats=3) -> float:
  draw()
  start = time.perf_counter()
  for _ in range(repeats):
    draw()
  return repeats / (time.perf_counter() - start)


def main():
  parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
  parser.add_argument("--data", default=DATA)
  parser.add_argument("--scene", default="lego800", choices=sorted(SCENES))
  parser.add_argument("--minutes", type=float, default=5.0)
  parser.add_argument("--views", type=int, default=8)
  parser.add_argument("--checkpoint-every", type=int, default=500)
  parser.add_argument("--out", default="runs/gpu_bench")
  args = parser.parse_args()
  start = time.time()
  print(f"# machine: {machine()}", flush=True)
  folder, downscale, split = SCENES[args.scene]
  scene, data = load_scene(DataConfig(path=os.path.join(args.data, folder), downscale=downscale))
  config = nerf_preset("fast", scene.format, checkpoint_every=args.checkpoint_every)
  config = nerf.resolve_config(override(config, steps=10 ** 7), scene)
  run_dir = os.path.join(args.out, args.scene)
  shutil.rmtree(run_dir, ignore_errors=True)
  rows, _ = train_within(
      args.minutes,
      lambda callback: nerf.train(scene, config, data, run_dir, progress=False,
                                  callback=callback),
      lambda step, params: {},
      lambda r: print(f"  step {r['step']:6d} after {r['train_seconds']:6.1f} s of training",
                      flush=True))
  steps, seconds = rows[-1]["step"], rows[-1]["train_seconds"]
  run = runs.load_run(run_dir)
  views = scene.split(split)[:args.views]
  psnr = np.mean([float(metrics.psnr(render_view(scene, run.params, run.config, int(v))["rgb"],
                                     scene.images[v])) for v in views])
  view = int(views[0])
  exact_fps = frames_per_second(lambda: render_view(scene, run.params, run.config, view))
  draw = baked_run.baked_views(run, scene)
  baked_fps = frames_per_second(lambda: draw(view))
  rows_out = [
      ("scene", f"{args.scene} ({scene.width}x{scene.height}), preset fast"),
      ("training", f"{steps} steps in {seconds:.0f} s"),
      ("training rays/s", f"{steps * config.batch_rays / seconds:,.0f}"),
      (f"held-out PSNR ({len(views)} {split} views)", f"{psnr:.2f} dB"),
      ("render frames/s, exact", f"{exact_fps:.2f}"),
      ("render frames/s, baked", f"{baked_fps:.2f}"),
      ("peak memory", peak_memory()),
      ("end to end", f"{time.time() - start:.0f} s"),
  ]
  print("\n| measurement | value |\n|---|---|")
  for name, value in rows_out:
    print(f"| {name} | {value} |")


if __name__ == "__main__":
  main()
