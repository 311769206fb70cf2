"""Empty space stays empty: the same NeRF trained with and without the fix, in one run.

lego (100x100, --downscale 8): preset `cpu` (or `paper`) with white backgrounds, as the
reference code trains, against random backgrounds (`random_background`). At every
evaluation: training seconds (evaluation excluded), val PSNR/SSIM, and the mean rendered
opacity on the val pixels whose ground-truth alpha is 0 (empty space) and 255 (the object).

fern (504x378, factor 8, NDC): preset `cpu` (or `fast`) without and with the distortion
loss (`distortion_weight`). At every evaluation: test PSNR/SSIM, the mean distortion of the
fine weights per ray and the share of each ray's weight lying more than 0.05 (in NDC
depth) from the ray's weighted median depth (semi-transparent floaters), on every 4th pixel;
at the end, the seconds to render one test view (after a warm-up render) and, for the
occupancy grid, the share of its cells that are occupied.

Usage:
  python experiments/benchmarks/bench_empty_space.py lego [--steps 3000] [--eval-every 1000]
      [--preset cpu] [--out runs/bench_empty_space]
  python experiments/benchmarks/bench_empty_space.py fern [--steps 1000] [--weight 0.01]
      [--preset fast]

Writes RUN/<variant>/ for each variant, OUT/<scene>_bench.json and OUT/<scene>_opacity.png
(rows: variants; columns: render, opacity, depth of the first two val/test views).
"""

import argparse
import dataclasses
import functools
import json
import os
import shutil
import time

import jax
import jax.numpy as jnp
import numpy as np

import msnerf_jax
from msnerf_jax.core import files
from msnerf_jax.nerf import occupancy
from msnerf_jax.nerf import regularizers
from msnerf_jax.nerf import render as render_lib
from msnerf_jax.nerf.samplers.grid import render_rays_grid
from msnerf_jax.data import video
from msnerf_jax.core.config import DataConfig, nerf_preset
from msnerf_jax.data import images as images_lib
from msnerf_jax.data.scene import load_scene
from msnerf_jax.eval.evaluate import evaluate_nerf
from msnerf_jax.models.nerf import NerfField
from msnerf_jax.train import nerf
from msnerf_jax.kinds.views import render_view
from msnerf_jax.nerf.volume_rendering import ray_starts, segment_cumsum
from common import DATA, machine


def _weight_stats_packed(config, params, rays):
  """_weight_stats for the occupancy-grid sampler's packed samples (every kept step)."""
  n = rays["origins"].shape[0]
  out = render_rays_grid(NerfField(config), params, rays, config, {}, False,
                                    budget=n * config.march_steps)
  w, ray, interval = out["weights"], out["sample_ray"], out["sample_interval"]
  dist = regularizers.distortion_packed(w, interval, ray, rays["near"], rays["far"])
  safe = jnp.minimum(ray, n - 1)
  span = (rays["far"] - rays["near"])[safe]
  s = (interval.mean(-1) - rays["near"][safe]) / span
  per_ray = lambda x: jax.ops.segment_sum(x, ray, n + 1, indices_are_sorted=True)[:n]
  acc = jnp.maximum(per_ray(w), 1e-10)
  cdf = segment_cumsum(w, ray_starts(ray)) / acc[safe]
  median = jax.ops.segment_min(jnp.where(cdf >= 0.5, s, jnp.inf), ray, n + 1,
                               indices_are_sorted=True)[:n]
  spread = per_ray(w * (jnp.abs(s - median[safe]) > 0.05)) / acc
  return dist, spread


@functools.partial(jax.jit, static_argnums=(0,))
def _weight_stats(config, params, rays):
  if config.sampler == "grid":
    return _weight_stats_packed(config, params, rays)
  out = render_lib.render_rays(NerfField(config), params, rays, config)["fine"]
  w, z = out["weights"], out["z_vals"]
  dist = regularizers.distortion(w, z, rays["near"], rays["far"])
  cdf = jnp.cumsum(w, -1) / jnp.maximum(jnp.sum(w, -1, keepdims=True), 1e-10)
  median = jnp.take_along_axis(z, jnp.argmax(cdf >= 0.5, -1)[..., None], -1)
  s = (z - rays["near"][..., None]) / (rays["far"] - rays["near"])[..., None]
  s_median = (median - rays["near"][..., None]) / (rays["far"] - rays["near"])[..., None]
  spread = jnp.sum(w * (jnp.abs(s - s_median) > 0.05), -1) / jnp.maximum(jnp.sum(w, -1), 1e-10)
  return dist, spread


def weight_stats(scene, params, config, views, stride=4, chunk=4096):
  """Mean distortion and off-surface weight share over every stride-th pixel of the views."""
  dists, spreads = [], []
  for i in views:
    rays = jax.tree_util.tree_map(lambda x: np.asarray(x)[::stride, ::stride].reshape(
        -1, *x.shape[2:]), scene.camera_rays(int(i)))
    n = rays["origins"].shape[0]
    for start in range(0, n, chunk):
      piece = {k: v[start:start + chunk] for k, v in rays.items()}
      size = piece["origins"].shape[0]
      piece = {k: np.concatenate([v, np.repeat(v[:1], chunk - size, 0)]) for k, v in piece.items()}
      d, s = _weight_stats(config, params, piece)
      dists.append(np.asarray(d)[:size])
      spreads.append(np.asarray(s)[:size])
  return float(np.concatenate(dists).mean()), float(np.concatenate(spreads).mean())


def main():
  parser = argparse.ArgumentParser(description=__doc__,
                                   formatter_class=argparse.RawDescriptionHelpFormatter)
  parser.add_argument("scene", choices=("lego", "fern"))
  parser.add_argument("--data", default=DATA)
  parser.add_argument("--preset", default="cpu", choices=("cpu", "paper", "fast"))
  parser.add_argument("--steps", type=int, default=None, help="lego 3000, fern 1000")
  parser.add_argument("--eval-every", type=int, default=None, help="lego 1000, fern 500")
  parser.add_argument("--weight", type=float, default=0.01, help="fern: distortion weight")
  parser.add_argument("--out", default="runs/bench_empty_space")
  parser.add_argument("--view-stride", type=int, default=1,
                      help="evaluate every Nth val/test view (the paper preset on CPU)")
  parser.add_argument("--variants", nargs="+", default=None, metavar="NAME",
                      help="run only these variants (lego: white random; fern: plain "
                           "distortion_W)")
  parser.add_argument("--keep-runs", action="store_true",
                      help="resume (or just evaluate) the variants' runs left in OUT by an "
                           "earlier call instead of training them again")
  parser.add_argument("--precrop-steps", type=int, default=None,
                      help="override the preset's centre-crop steps (for shorter runs)")
  args = parser.parse_args()

  lego = args.scene == "lego"
  steps = args.steps or (3000 if lego else 1000)
  every = args.eval_every or (1000 if lego else 500)
  path = os.path.join(args.data, *(("nerf_synthetic", "lego") if lego
                                   else ("nerf_llff_data", "fern")))
  scene, data_config = load_scene(DataConfig(path=path, downscale=8))
  split = "val" if lego else "test"
  base = nerf_preset(args.preset, data_config.format, steps=steps, checkpoint_every=every)
  if args.precrop_steps is not None:
    base = dataclasses.replace(base, precrop_steps=args.precrop_steps)
  eval_scene = dataclasses.replace(
      scene, splits={**scene.splits, split: scene.split(split)[::args.view_stride]})
  if lego:
    variants = {"white": dataclasses.replace(base, random_background=False),
                "random": dataclasses.replace(base, random_background=True)}
  else:
    variants = {"plain": base,
                f"distortion_{args.weight:g}": dataclasses.replace(base,
                                                                   distortion_weight=args.weight)}
  if args.variants:
    unknown = set(args.variants) - set(variants)
    if unknown:
      parser.error(f"--variants: unknown {sorted(unknown)}; choose from {sorted(variants)}")
    variants = {k: v for k, v in variants.items() if k in args.variants}
  print(f"# {args.scene} {scene.width}x{scene.height}, preset {args.preset}, {steps} steps, "
        f"precrop {base.precrop_steps}, every {args.view_stride}. {split} view; "
        f"machine: {machine()}")
  extra = ("opacity_background", "opacity_object") if lego else ("distortion", "off_surface")
  print(f"{'variant':<18} {'step':>6} {'train_s':>8} {'psnr':>7} {'ssim':>7} "
        + " ".join(f"{k:>18}" for k in extra))
  table, views = {}, scene.split(split)[:2]
  for name, config in variants.items():
    config = nerf.resolve_config(config, scene)  # the scene's box, as training resolves it.
    run = os.path.join(args.out, f"{args.scene}_{args.preset}_{name}")
    if not args.keep_runs:
      shutil.rmtree(run, ignore_errors=True)
    rows, clock = [], {"start": time.time(), "eval": 0.0}

    def on_checkpoint(step, params, config=config, rows=rows, clock=clock, name=name,
                      train_s=None):
      t = time.time()
      _, mean, _ = evaluate_nerf(eval_scene, params, config, split, progress=False)
      if not lego:
        mean["distortion"], mean["off_surface"] = weight_stats(scene, params, config,
                                                               scene.split(split))
      clock["eval"] += time.time() - t
      if train_s is None:
        train_s = time.time() - clock["start"] - clock["eval"]
      rows.append({"step": step, "train_seconds": round(train_s, 1), **mean})
      print(f"{name:<18} {step:6d} {train_s:8.1f} {mean['psnr']:7.2f} {mean['ssim']:7.4f} "
            + " ".join(f"{mean[k]:18.4f}" for k in extra), flush=True)

    nerf.train(scene, config, data_config, run, progress=False, callback=on_checkpoint)
    params = msnerf_jax.load_run(run).params
    if not rows:  # --keep-runs: trained before; evaluated once, its training time from history.
      with open(os.path.join(run, "history.jsonl")) as f:
        last = json.loads(f.read().splitlines()[-1])
      on_checkpoint(last["step"], params, train_s=last["time"])
    table[name] = {"config": dataclasses.asdict(config), "rows": rows}
    renders = [render_view(scene, params, config, int(i)) for i in views]
    t = time.time()
    render_view(scene, params, config, int(views[0]))
    table[name]["render_seconds"] = round(time.time() - t, 2)
    if config.sampler == "grid":
      table[name]["occupied"] = float(np.mean(np.asarray(occupancy.occupied(
          jnp.asarray(params["occupancy"]), config.grid_threshold))))
    print(f"# {name}: one {split} view renders in {table[name]['render_seconds']} s"
          + (f"; {table[name]['occupied']:.1%} of the grid occupied"
             if "occupied" in table[name] else ""), flush=True)
    table[name]["figure"] = renders
  # Figure: per variant, render | opacity | depth of each view.
  lo = min(float(np.percentile(r["depth"][r["accumulation"] > 0.5], 1))
           for v in table.values() for r in v["figure"] if (r["accumulation"] > 0.5).any())
  hi = max(float(np.percentile(r["depth"][r["accumulation"] > 0.5], 99))
           for v in table.values() for r in v["figure"] if (r["accumulation"] > 0.5).any())
  rows_img = []
  for v in table.values():
    tiles = []
    for r in v.pop("figure"):
      tiles += [r["rgb"], np.repeat(r["accumulation"][..., None], 3, -1),
                video.depth_to_image(r["depth"], r["accumulation"], lo, hi)]
    rows_img.append(np.concatenate([np.clip(t, 0, 1) for t in tiles], 1))
  figure = os.path.join(args.out, f"{args.scene}_{args.preset}_opacity.png")
  images_lib.write_image(figure, np.concatenate(rows_img, 0))
  out = os.path.join(args.out, f"{args.scene}_{args.preset}_bench.json")
  files.atomic_write_bytes(out, json.dumps(table, indent=1).encode())
  print(f"# written {out}, {figure} (rows: {', '.join(variants)}; per view: render, "
        "opacity, depth)")


if __name__ == "__main__":
  main()
