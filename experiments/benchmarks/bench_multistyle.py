"""Multi-style NeRF speed, measured in one run (issue 4 targets):

1. Training throughput in supervised (ray, style) pairs per second at M styles:
   - ours: every sampled pixel is supervised in all M styles; the style MLPs run once per
     style and the frozen trunk once per sample (`msnerf_jax.train.multistyle.train_step`);
   - the reference formulation: each ray carries one style, and the style MLP runs on every
     sample (the style vector is concatenated to each sample's features), as in the
     authors' PyTorch code. Same model, same weights, same trunk freezing, same optimizer.
   Target: ours >= 8x the reference.
2. Rendering a 100x100 image in K = 8 styles with the vmapped-style sweep vs in 1 style.
   Target: <= 2x.

  python experiments/benchmarks/bench_multistyle.py [--preset cpu|paper] [--styles 4] [--steps 5]
"""

import argparse
import dataclasses
import functools
import os
import platform

import jax
import jax.numpy as jnp
import numpy as np

from msnerf_jax.nerf import render as render_lib
from msnerf_jax.core.config import MultistyleConfig, nerf_preset
from msnerf_jax.models.multistyle import MultistyleField, init_multistyle_params, multistyle_mlp
from msnerf_jax.models.nerf import init_nerf_params
from msnerf_jax.core.parallel import data_parallel
from msnerf_jax.nerf.rays import get_rays, ray_bundle
from msnerf_jax.train import multistyle
from common import call_times, synthetic_rays


def timed(fn, repeats):
  """Mean wall time of fn() over `repeats` calls after one warm-up call (compilation)."""
  return float(np.mean(call_times(fn, repeats)))


# ----------------------------------------------------------------------------- reference formulation


def reference_apply(module, points, packed):
  """One style per ray, style MLP per sample: packed = [viewdir (3), style vector] per ray."""
  viewdirs, style = packed[..., :3], packed[..., 3:]
  style = jnp.broadcast_to(style, (*points.shape[:-1], style.shape[-1]))  # [r, S, 1024]
  out = module.trunk(points, viewdirs)
  code = module.rgb_hidden.project_code(module.style_rgb(style))  # per sample
  h = jax.nn.relu(module.rgb_hidden(out["view_features"], code))
  return jax.nn.sigmoid(module.rgb_out(h)), out["sigma"]


def reference_loss(trainable, frozen, batch, config):
  params = multistyle.merge(trainable, jax.lax.stop_gradient(frozen))
  model = multistyle_mlp(config)
  field = lambda p, x, d: model.apply({"params": p}, x, d, method=reference_apply)
  out = render_lib.render_rays(field, params, batch["rays"], config.nerf, batch["random"], True)
  return sum(jnp.mean((out[k]["rgb"] - batch["rgb"]) ** 2) for k in ("coarse", "fine"))


def reference_step(state, batch, config):
  trainable, frozen = multistyle.split_frozen(state.params)
  grads = jax.grad(reference_loss)(trainable, frozen, batch, config)
  grads = multistyle.merge(grads, jax.tree_util.tree_map(jnp.zeros_like, frozen))
  return state.apply_gradients(grads=grads)


# ----------------------------------------------------------------------------- main


def main():
  parser = argparse.ArgumentParser(description=__doc__,
                                   formatter_class=argparse.RawDescriptionHelpFormatter)
  parser.add_argument("--preset", default="cpu", choices=("cpu", "paper"))
  parser.add_argument("--styles", type=int, default=4, help="M, styles per training step")
  parser.add_argument("--batch-rays", type=int, default=1024)
  parser.add_argument("--steps", type=int, default=5, help="timed steps")
  parser.add_argument("--sweep", type=int, default=8, help="K, styles of the sweep")
  parser.add_argument("--size", type=int, default=100, help="side of the rendered image")
  args = parser.parse_args()
  print(f"# {platform.machine()}, {os.cpu_count()} cores, jax {jax.__version__}, "
        f"devices {jax.devices()}, preset {args.preset}")

  nerf_config = nerf_preset(args.preset, "blender")
  config = MultistyleConfig(nerf=nerf_config, batch_rays=args.batch_rays)
  key = jax.random.PRNGKey(0)
  nerf_params = init_nerf_params(nerf_config, key)
  state = multistyle.init_state(config, nerf_params)
  m, b = args.styles, args.batch_rays
  styles = jax.random.normal(key, (m, 1024))
  sampling = dataclasses.replace(nerf_config, batch_rays=b)
  rays = synthetic_rays(b, key)
  random = render_lib.draw_randomness(key, b, sampling)

  # Ours: B pixels x M styles per step.
  ours_batch = {"rays": rays, "random": random,
                "rgb": jax.random.randint(key, (b, m, 3), 0, 256).astype(jnp.uint8)}
  ours = multistyle.compile_train_step(config, styles, True, data_parallel(1))
  holder = {"s": state}

  def run_ours():
    holder["s"], stats = ours(holder["s"], ours_batch)
    return stats["loss"]
  t_ours = timed(run_ours, args.steps)
  pairs_ours = b * m / t_ours

  # Reference: B rays, each with one of the M styles, style MLP per sample.
  ref_rays = dict(rays)
  ref_rays["viewdirs"] = jnp.concatenate([rays["viewdirs"], styles[jnp.arange(b) % m]], -1)
  ref_batch = {"rays": ref_rays, "random": random, "rgb": jax.random.uniform(key, (b, 3))}
  ref = jax.jit(functools.partial(reference_step, config=config), donate_argnums=0)
  holder["r"] = multistyle.init_state(config, nerf_params)

  def run_ref():
    holder["r"] = ref(holder["r"], ref_batch)
    return holder["r"].step
  t_ref = timed(run_ref, args.steps)
  pairs_ref = b / t_ref
  print(f"training, M={m} styles, {b} rays/step, {nerf_config.n_coarse}+{nerf_config.n_fine} "
        "samples/ray:")
  print(f"  ours (shared samples, style MLP per style): {t_ours * 1e3:8.1f} ms/step  "
        f"{pairs_ours:10.0f} (ray, style) pairs/s")
  print(f"  reference (one style per ray, per sample):  {t_ref * 1e3:8.1f} ms/step  "
        f"{pairs_ref:10.0f} (ray, style) pairs/s")
  print(f"  speed-up: {pairs_ours / pairs_ref:.1f}x (target >= 8x)")

  # Sweep: one image in K styles vs in 1 style.
  params = init_multistyle_params(config, key, nerf_params)
  size = args.size
  focal = size / (2 * np.tan(0.69 / 2))
  K = np.array([[focal, 0, size / 2], [0, focal, size / 2], [0, 0, 1]], np.float32)
  c2w = np.array([[1, 0, 0, 0], [0, 1, 0, 0], [0, 0, 1, 4]], np.float32)
  origins, directions = get_rays(size, size, K, c2w)
  image_rays = ray_bundle(origins, directions, 2.0, 6.0)
  field = MultistyleField(config)
  sweep_styles = jax.random.normal(key, (args.sweep, 1024))
  t_one = timed(lambda: render_lib.render_image(field, params, image_rays, nerf_config, True,
                                                styles=sweep_styles[:1])["rgb"], 3)
  t_k = timed(lambda: render_lib.render_image(field, params, image_rays, nerf_config, True,
                                              styles=sweep_styles)["rgb"], 3)
  print(f"rendering {size}x{size}: 1 style {t_one:.3f} s, {args.sweep} styles (sweep) "
        f"{t_k:.3f} s: {t_k / t_one:.2f}x (target <= 2x); "
        f"{args.sweep} separate renders would be {args.sweep:.0f}x")


if __name__ == "__main__":
  main()
