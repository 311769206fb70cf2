"""How a grid-sampler NeRF run's rays use the occupancy grid: the share of cells occupied,
how many of a ray's march steps land in occupied cells, and how much light is left at the
end of the ray (when it never becomes opaque, early termination stops nothing).

Usage:
  python experiments/studies/grid_rays/grid_rays.py RUN [--split test] [--stride 37]

Takes every stride-th ray of the first held-out view and evaluates the field at all of its
march steps.
"""

import argparse
import os
import platform

import jax
import jax.numpy as jnp
import numpy as np

from msnerf_jax.nerf import occupancy
from msnerf_jax.kinds import runs
from msnerf_jax.nerf import render as render_lib
from msnerf_jax.models.nerf import NerfField


def main():
  parser = argparse.ArgumentParser(description=__doc__,
                                   formatter_class=argparse.RawDescriptionHelpFormatter)
  parser.add_argument("run")
  parser.add_argument("--split", default="test")
  parser.add_argument("--stride", type=int, default=37)
  args = parser.parse_args()
  run, scene = runs.load_run_and_scene(args.run, "nerf")
  config = run.config
  grid = occupancy.occupied(jnp.asarray(run.params["occupancy"]), config.grid_threshold)
  _, flat, _ = render_lib.flat_rays(scene.camera_rays(int(scene.split(args.split)[0])))
  rays = {k: jnp.asarray(v[::args.stride]) for k, v in flat.items()}
  t_start, dt, _, steps, keep = occupancy.candidates(rays, grid, config)
  t = t_start[:, None] + (steps + 0.5) * dt[:, None]
  points = rays["origins"][:, None] + rays["directions"][:, None] * t[..., None]
  viewdirs = jnp.broadcast_to(rays["viewdirs"][:, None], points.shape)
  n, s = keep.shape
  _, sigma = NerfField(config)(run.params["fine"], points.reshape(-1, 1, 3),
                               viewdirs.reshape(-1, 1, 3))
  tau = np.maximum(np.asarray(sigma).reshape(n, s), 0) * np.asarray(
      dt * jnp.linalg.norm(rays["directions"], axis=-1))[:, None]
  light_left = np.exp(-np.cumsum(tau, 1))[:, -1]
  print(f"# {args.run}: {n} rays of {args.split} view; machine: "
        f"{platform.processor() or platform.machine()}, {os.cpu_count()} cores, jax "
        f"{jax.__version__} on {jax.devices()[0].platform}")
  print(f"grid occupied: {float(jnp.mean(grid)):.1%}; steps kept per ray: "
        f"{float(jnp.sum(keep, 1).mean()):.1f} of {s}; light left at the ray's end: median "
        f"{np.median(light_left):.3f}")


if __name__ == "__main__":
  main()
