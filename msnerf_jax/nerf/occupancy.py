"""The occupancy grid: where along a ray there is anything to sample (instant-NGP, nerfacc).

A [G, G, G] grid over the scene box [-bound, bound]^3 holds, per cell, an estimate of the
optical depth of one marching step there (density x step size); -1 means not yet estimated
(counted as occupied). A cell is occupied when its value exceeds min(mean of the estimated
cells, threshold). Training refreshes the estimates from the field's own density
(`update_grid`): every cell while warming up, then a random quarter of them each time, the
rest decaying.

`march` places a ray's candidate samples at even steps through its stretch of the box, keeps
those in occupied cells, and packs the kept samples of all rays into one array of a fixed
size (a static sample budget; under jit every shape is static). Rays whose samples do not all
fit are reported (`complete` False) rather than rendered wrong.

The grid is not trained by gradients: it lives in the field's params as params["occupancy"]
(so checkpoints, renders and the multi-style model carry it), frozen in the optimizer, and
the training step rewrites it (msnerf_jax.train.nerf).
"""

from typing import Callable, Dict, Optional

import chex
import jax
import jax.numpy as jnp

UNKNOWN = -1.0


def init_grid(resolution: int) -> jnp.ndarray:
  """A grid [G, G, G] with every cell unknown (so occupied)."""
  return jnp.full((resolution,) * 3, UNKNOWN, jnp.float32)


def step_size(config) -> float:
  """Nominal length of one marching step: the box diagonal over config.march_steps."""
  return 2.0 * config.scene_box * 3 ** 0.5 / config.march_steps


def occupied(grid: jnp.ndarray, threshold: float) -> jnp.ndarray:
  """bool [G, G, G]: unknown, or above min(mean of the estimated cells, threshold)."""
  known = grid >= 0
  mean = jnp.sum(jnp.where(known, grid, 0.0)) / jnp.maximum(jnp.sum(known), 1)
  return ~known | (grid > jnp.minimum(mean, threshold))


def cell_of(points: jnp.ndarray, bound: float, resolution: int):
  """(cell index [..., 3] int32, inside the box [...] bool) of points [..., 3]."""
  unit = (points + bound) / (2.0 * bound)
  inside = jnp.all((unit >= 0.0) & (unit <= 1.0), -1)
  cell = jnp.clip(jnp.floor(unit * resolution), 0, resolution - 1).astype(jnp.int32)
  return cell, inside


def lookup(occupancy: jnp.ndarray, points: jnp.ndarray, bound: float) -> jnp.ndarray:
  """bool [...]: the points [..., 3] lie inside the box, in an occupied cell of occupancy
  [G, G, G] bool."""
  cell, inside = cell_of(points, bound, occupancy.shape[0])
  return inside & occupancy[cell[..., 0], cell[..., 1], cell[..., 2]]


def update_grid(grid: jnp.ndarray, density_fn: Callable[[jnp.ndarray], jnp.ndarray],
                key: jax.Array, config, all_cells: bool) -> jnp.ndarray:
  """The grid after one refresh from the field's density.

  Every cell (all_cells, static) or a random quarter of them (drawn with replacement) gets
  a new estimate: density_fn at a uniform random point in the cell, times the step size.
  Known cells decay by config.grid_decay first and keep the larger of that and the new
  estimate.

  Args:
    grid: [G, G, G] values (init_grid).
    density_fn: points [M, 3] -> densities [M] (>= 0).
    key: PRNG key of this refresh.
    all_cells: refresh every cell (warm-up) or a random quarter (a static bool).
  """
  g = grid.shape[0]
  n = g ** 3
  k_cells, k_jitter = jax.random.split(key)
  chosen = (jnp.arange(n) if all_cells else
            jax.random.randint(k_cells, (max(1, n // 4),), 0, n))
  ijk = jnp.stack(jnp.unravel_index(chosen, (g, g, g)), -1)
  jitter = jax.random.uniform(k_jitter, ijk.shape)
  points = ((ijk + jitter) / g * 2.0 - 1.0) * config.scene_box
  values = density_fn(points) * step_size(config)
  decayed = jnp.where(grid >= 0, grid * config.grid_decay, grid).reshape(-1)
  return decayed.at[chosen].max(values).reshape(grid.shape)


def box_interval(rays: Dict[str, jnp.ndarray], bound: float):
  """(t_start, t_end) [R]: the stretch of each ray inside both [near, far] and the box
  [-bound, bound]^3 (t_end <= t_start: it misses)."""
  o, d = rays["origins"], rays["directions"]
  safe = jnp.where(jnp.abs(d) < 1e-9, 1e-9, d)
  t0 = (-bound - o) / safe
  t1 = (bound - o) / safe
  t_in = jnp.max(jnp.minimum(t0, t1), -1)
  t_out = jnp.min(jnp.maximum(t0, t1), -1)
  return jnp.maximum(t_in, rays["near"]), jnp.minimum(t_out, rays["far"])


def segment_length(config) -> int:
  """Steps in one of config.march_segments segments (the last may reach past the end)."""
  return -(-config.march_steps // config.march_segments)


def candidates(rays: Dict[str, jnp.ndarray], occupancy: jnp.ndarray, config,
               u: Optional[jnp.ndarray] = None, first: Optional[jnp.ndarray] = None):
  """(t_start [R], dt [R], offset [R], steps [S], keep [R, S] bool) of march's candidates:
  step k of a ray has its sample at t_start + (k + offset) dt, kept when its cell is
  occupied. S = config.march_steps, or with `first` (an int, may be traced) the
  segment_length(config) steps from `first` on. A ray with rays["alive"] False keeps none."""
  n_rays, n_steps = rays["origins"].shape[0], config.march_steps
  t_start, t_end = box_interval(rays, config.scene_box)
  dt = jnp.maximum(t_end - t_start, 0.0) / n_steps  # [R]; 0 for a ray that misses.
  offset = jnp.full((n_rays,), 0.5) if u is None else u
  steps = (jnp.arange(n_steps) if first is None else
           first + jnp.arange(segment_length(config)))
  t = t_start[:, None] + (steps + offset[:, None]) * dt[:, None]  # [R, S]
  points = rays["origins"][:, None, :] + rays["directions"][:, None, :] * t[..., None]
  keep = lookup(occupancy, points, config.scene_box) & (dt > 0)[:, None] & (steps < n_steps)
  if "alive" in rays:
    keep = keep & rays["alive"][:, None]
  return t_start, dt, offset, steps, keep


def count(rays: Dict[str, jnp.ndarray], occupancy: jnp.ndarray, config,
          first: Optional[jnp.ndarray] = None) -> jnp.ndarray:
  """[R] int32: how many samples march keeps on each ray (without jitter)."""
  return jnp.sum(candidates(rays, occupancy, config, None, first)[4], -1, dtype=jnp.int32)


def march(rays: Dict[str, jnp.ndarray], occupancy: jnp.ndarray, config, budget: int,
          u: Optional[jnp.ndarray] = None, first: Optional[jnp.ndarray] = None
          ) -> Dict[str, jnp.ndarray]:
  """Packed samples of a batch of rays in the occupied cells.

  Each ray's stretch inside the box is cut into config.march_steps even steps; a step's
  sample sits at its start plus u (per ray, 0.5 without u) of the step, and is kept when
  it lies in an occupied cell. The kept samples of all rays, ray by ray and in order along
  each ray, fill the first entries of `budget` slots.

  Args:
    rays: ray_bundle [R], optionally with "alive" [R] bool (rays that may take samples).
    occupancy: [G, G, G] bool (occupied).
    budget: number of sample slots B (static).
    u: [R] jitter in [0, 1) (training), or None.
    first: None, or the first step of a segment (candidates): only that segment's steps
      (rendering marches in segments and stops rays whose transmittance is spent).
  Returns:
    {"ray": [B] int32 ray of each slot (R for an empty slot), "t": [B] sample depths,
    "delta": [B] step lengths in world units, "interval": [B, 2] the step each slot's sample
    stands for, [start, end) in ray parameter t, "valid": [B] bool, "step": [B] int32 its
    step's index along the ray (0 for an empty slot), "complete": [R] bool (all of the
    ray's kept samples fit in the budget)}.
  """
  chex.assert_rank(rays["origins"], 2)
  n_rays = rays["origins"].shape[0]
  t_start, dt, offset, steps, keep = candidates(rays, occupancy, config, u, first)
  n_steps = steps.shape[0]
  flat = jnp.nonzero(keep.reshape(-1), size=budget, fill_value=n_rays * n_steps)[0]
  valid = flat < n_rays * n_steps
  ray = jnp.where(valid, flat // n_steps, n_rays).astype(jnp.int32)
  safe_ray = jnp.minimum(ray, n_rays - 1)
  step_index = jnp.where(valid, steps[flat % n_steps], 0).astype(jnp.int32)
  step = step_index.astype(jnp.float32)
  norm = jnp.linalg.norm(rays["directions"], axis=-1)
  lo = jnp.where(valid, t_start[safe_ray] + step * dt[safe_ray], 0.0)
  return {"ray": ray,
          "t": jnp.where(valid, lo + offset[safe_ray] * dt[safe_ray], 0.0),
          "delta": jnp.where(valid, dt[safe_ray] * norm[safe_ray], 0.0),
          "interval": jnp.stack([lo, jnp.where(valid, lo + dt[safe_ray], 0.0)], -1),
          "valid": valid, "step": step_index,
          "complete": jnp.cumsum(jnp.sum(keep, -1)) <= budget}
