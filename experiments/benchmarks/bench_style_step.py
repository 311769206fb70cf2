"""The multi-style heads' training step on a NeRF run's frozen trunk, by the field's chunking
(issue 47, item 4: "style heads as fast on the hash trunk as on the MLP trunk").

Usage:
  python experiments/benchmarks/bench_style_step.py --nerf NERF_RUN [--styles 3] [--steps 8]
      [--chunks 0 1 8192]

For each `mlp_chunk` the step (train_step, jitted, one device; random stylized pixels, the
default MultistyleConfig) and its forward render alone are timed over --steps batches after
one compiling call, and XLA's cost analysis of the step is printed (a loop body is
counted once: the mlp_chunk 1 row undercounts). mlp_chunk 0 is one field
call (the fast preset's setting); 1 is what 0 did in the conditioned path before the fix (a
lax.map over the rays one at a time), so the two rows are the before and after of one run on
one machine.
"""

import argparse
import dataclasses
import functools
import time

import jax
import jax.numpy as jnp
import numpy as np

from msnerf_jax.core.config import MultistyleConfig
from msnerf_jax.kinds import runs
from msnerf_jax.models.multistyle import MultistyleField
from msnerf_jax.nerf import render as render_lib
from msnerf_jax.train import multistyle
from common import machine


def seconds(fn, n):
  jax.block_until_ready(fn(0))
  start = time.perf_counter()
  for i in range(1, n + 1):
    out = fn(i)
  jax.block_until_ready(out)
  return (time.perf_counter() - start) / n


def main():
  parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
  parser.add_argument("--nerf", required=True)
  parser.add_argument("--styles", type=int, default=3)
  parser.add_argument("--steps", type=int, default=8)
  parser.add_argument("--chunks", type=int, nargs="+", default=[0, 1, 8192])
  args = parser.parse_args()
  print(machine())
  run, scene = runs.load_run_and_scene(args.nerf, "nerf")
  idx = scene.splits["train"]
  rng = np.random.default_rng(0)
  images = jnp.asarray(rng.integers(0, 256, (len(idx), scene.height, scene.width, args.styles, 3),
                                    dtype=np.uint8))
  c2w = jnp.asarray(scene.c2w[idx])
  K, coeffs = jax.tree_util.tree_map(jnp.asarray, scene.cameras_of(idx))
  styles = jnp.asarray(rng.normal(size=(args.styles, 1024)).astype(np.float32) ** 2)
  print(f"{args.nerf}: trunk {run.config.trunk}, sampler {run.config.sampler}, "
        f"{args.styles} styles")
  print(f"{'mlp_chunk':>9} {'step_s':>8} {'forward_s':>9} {'GFLOP':>7} {'GB moved':>8}")
  for chunk in args.chunks:
    nerf = dataclasses.replace(run.config, mlp_chunk=chunk)
    config = dataclasses.replace(MultistyleConfig(), nerf=nerf).validate()
    state = multistyle.init_state(config, run.params)
    batches = [multistyle.sample_batch(jax.random.PRNGKey(i), images, c2w, K, config, scene,
                                       coeffs) for i in range(args.steps + 1)]
    step = jax.jit(functools.partial(multistyle.train_step, config=config,
                                     white_background=scene.white_background))
    field = MultistyleField(config)
    forward = jax.jit(lambda p, b: render_lib.render_rays_styles(
        field, p, b["rays"], styles, config.nerf, b["random"], scene.white_background))  # pylint: disable=cell-var-from-loop
    step_s = seconds(lambda i: step(state, batches[i], styles), args.steps)  # pylint: disable=cell-var-from-loop
    forward_s = seconds(lambda i: forward(state.params, batches[i]), args.steps)  # pylint: disable=cell-var-from-loop
    cost = step.lower(state, batches[0], styles).compile().cost_analysis()
    cost = cost[0] if isinstance(cost, list) else cost
    print(f"{chunk:9d} {step_s:8.3f} {forward_s:9.3f} {cost.get('flops', 0) / 1e9:7.2f} "
          f"{cost.get('bytes accessed', 0) / 1e9:8.2f}", flush=True)


if __name__ == "__main__":
  main()
