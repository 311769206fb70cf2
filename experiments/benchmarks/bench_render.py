"""The exact renderer against a baked scene (msnerf_jax.nerf.baked) on a run's held-out views
(issue 47: "a render path for looking").

Usage:
  python experiments/benchmarks/bench_render.py --run RUN [--views 8] [--resolution 4]
      [--components 16] [--chunk 4096] [--name lego]

RUN is a NeRF run with the occupancy-grid sampler (the `fast` preset). The scene is baked
once (timed; its arrays' size printed, and the size of the RUN/baked.npz they make),
then each held-out view is rendered by render.render_image (the exact renderer) and by
render_baked_image in the same process, each timed on its second call (the first compiles:
the exact renderer compiles once per sample-budget class, the baked one once per chunk
size, both counted and printed). The last line is
`NAME: exact 0.168 s, fast 0.107 s, speedup 1.6x, PSNR exact 27.01 dB fast 26.96 dB`
(median seconds a view; PSNR against the held-out images).
"""

import argparse
import time

import jax
import numpy as np

import msnerf_jax as ms
from msnerf_jax.eval import metrics
from msnerf_jax.kinds.baked import to_bytes
from msnerf_jax.nerf import baked, render as render_lib
from common import machine


def timed(fn):
  start = time.perf_counter()
  out = fn()
  return out, time.perf_counter() - start


def main():
  parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
  parser.add_argument("--run", required=True)
  parser.add_argument("--views", type=int, default=8)
  parser.add_argument("--resolution", type=int, default=4)
  parser.add_argument("--components", type=int, default=16)
  parser.add_argument("--chunk", type=int, default=4096)
  parser.add_argument("--name", default=None)
  args = parser.parse_args()
  print(machine())
  run = ms.load_run(args.run)
  scene = ms.scene_of(run)
  field, config = ms.field_of(run)
  if config.sampler != "grid":
    raise SystemExit(f"{args.run}: bake needs a run with the occupancy-grid sampler")
  geometry = jax.jit(lambda x: field.geometry(run.params["fine"], x))
  bake, seconds = timed(lambda: baked.bake(geometry, run.params["occupancy"], config,
                                           args.resolution, args.components))
  n_bricks = bake.density.shape[0]
  in_memory = sum(np.asarray(x).nbytes for x in jax.tree_util.tree_leaves(bake))
  print(f"bake: {seconds:.1f} s, {n_bricks} bricks of {bake.resolution + 1}^3 vertices, "
        f"{args.components} components: {in_memory / 1e6:.1f} MB in memory (float32), "
        f"{len(to_bytes(bake, '')) / 1e6:.1f} MB as RUN/baked.npz")
  bake = jax.device_put(bake)
  params = jax.device_put(run.params)
  views = scene.split("val" if "val" in scene.splits else "train")[:args.views]
  rows = []
  for view in views:
    rays = scene.camera_rays(int(view))
    exact_fn = lambda: render_lib.render_image(field, params, rays, config,
                                               scene.white_background)
    fast_fn = lambda: baked.render_baked_image(bake, field, params, rays, config,
                                               scene.white_background, args.chunk)
    _, exact_first = timed(exact_fn)
    exact, exact_s = timed(exact_fn)
    _, fast_first = timed(fast_fn)
    fast, fast_s = timed(fast_fn)
    target = scene.images[view]
    rows.append((exact_s, fast_s, float(metrics.psnr(exact["rgb"], target)),
                 float(metrics.psnr(fast["rgb"], target)),
                 float(np.abs(exact["rgb"] - fast["rgb"]).mean())))
    print(f"view {int(view)}: exact {exact_s:.3f} s (first call {exact_first:.2f} s), fast "
          f"{fast_s:.3f} s (first call {fast_first:.2f} s), PSNR {rows[-1][2]:.2f} / "
          f"{rows[-1][3]:.2f} dB, mean |exact - fast| {rows[-1][4] * 255:.2f}/255")
  exact_s, fast_s, psnr_exact, psnr_fast, _ = (np.array(c) for c in zip(*rows))
  name = args.name or run.record.get("data", {}).get("path", args.run).rstrip("/").split("/")[-1]
  # pylint: disable=protected-access
  print(f"compilations: exact renderer {render_lib._render_chunk._cache_size()}, baked "
        f"{baked._geometry_call._cache_size() + baked._shade_call._cache_size()}")
  print(f"{name}: exact {np.median(exact_s):.3f} s, fast {np.median(fast_s):.3f} s, speedup "
        f"{np.median(exact_s) / np.median(fast_s):.1f}x, PSNR exact {psnr_exact.mean():.2f} dB "
        f"fast {psnr_fast.mean():.2f} dB")


if __name__ == "__main__":
  main()
