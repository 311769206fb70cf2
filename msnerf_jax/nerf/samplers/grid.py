"""The occupancy-grid sampler (instant-NGP's): one network, samples only in the occupied cells
of params["occupancy"], a shared sample budget per batch, and rendering in segments with
early ray termination."""

import dataclasses
import functools
from typing import Dict, Optional

import jax
import jax.numpy as jnp
import numpy as np

from msnerf_jax.nerf import occupancy
from msnerf_jax.nerf.field_samples import field_in_chunks
from msnerf_jax.nerf.samplers.base import Sampler
from msnerf_jax.nerf.volume_rendering import disparity_of, volume_render_packed


def render_rays_grid(field, params, rays: Dict[str, jnp.ndarray], config,
                     randomness: Dict[str, jnp.ndarray], white_background: bool,
                     background: Optional[jnp.ndarray] = None, conditioning=None,
                     budget: Optional[int] = None, first: Optional[jnp.ndarray] = None
                     ) -> Dict[str, jnp.ndarray]:
  """One level of samples in the occupied cells (occupancy.march), composited.

  The sample budget is `budget` slots (static; default config.samples_per_ray x R) for the
  whole batch: rays through empty space take none, rays through the object what they need.

  Args: as render_rays; params {"fine": field params, "occupancy": [G, G, G] grid values};
    rays may carry "alive" [R] bool, and `first` limits the steps to one segment
    (occupancy.march).
  Returns:
    volume_render_packed's outputs (rgb, depth, disparity, accumulation with a leading [M]
    when conditioned; weights [B]) and "complete" [R] bool: False for a ray whose samples
    did not all fit in the budget (render it again in a smaller batch; leave it out of a
    loss); the slots' rays "sample_ray" [B] (R for an empty slot), positions
    "sample_points" [B, 3] and steps "sample_interval" [B, 2] (occupancy.march's interval).
  """
  n = rays["origins"].shape[0]
  grid = occupancy.occupied(params["occupancy"], config.grid_threshold)
  samples = occupancy.march(rays, grid, config, budget or n * config.samples_per_ray,
                            randomness.get("u_march"), first)
  ray = jnp.minimum(samples["ray"], n - 1)
  points = rays["origins"][ray] + rays["directions"][ray] * samples["t"][:, None]
  codes = None if conditioning is None else field.codes(params["fine"], conditioning)
  rgb, sigma = field_in_chunks(field, params["fine"], points[:, None], rays["viewdirs"][ray][:, None],
                               codes, config.mlp_chunk)
  if sigma.ndim != 2:
    raise ValueError("the occupancy-grid sampler needs a density shared by every conditioning")
  rgb = rgb[..., 0, :]  # [B, 3] or [M, B, 3]
  if conditioning is not None:
    rgb = jnp.moveaxis(rgb, 0, 1)
  out = volume_render_packed(rgb, jax.nn.relu(sigma[:, 0]), samples, n, white_background,
                             background)
  if conditioning is not None:  # the styles first, as render_level's outputs.
    m = conditioning.shape[0]
    out = {"rgb": jnp.moveaxis(out["rgb"], 1, 0), "weights": out["weights"],
           **{k: jnp.broadcast_to(out[k], (m, n)) for k in ("depth", "disparity", "accumulation")}}
  return {**out, "complete": samples["complete"], "sample_ray": samples["ray"],
          "sample_points": points, "sample_interval": samples["interval"]}


@functools.partial(jax.jit, static_argnums=(1,))
def _sample_counts(grid, config, rays, first):
  return occupancy.count(rays, occupancy.occupied(grid, config.grid_threshold), config, first)


def sample_budget(needed: int, config) -> int:
  """The static budget of a rendering call that needs `needed` samples: the next power of
  two (so a few compilations serve every call), at least one ray's march_steps."""
  return max(config.march_steps, 1 << max(0, int(needed) - 1).bit_length())


TERMINATED = 1e-4  # rendering stops a ray once its transmittance falls below this.
RENDER_MLP_CHUNK = 16384  # samples per field call when rendering a config with mlp_chunk 0.


def render_piece(call, params, grid, config, white_background, mesh, piece, styles):
  """One call's rays with the grid sampler, marched in config.march_segments segments of
  their steps: after each, rays whose transmittance fell below TERMINATED take no more
  samples (early ray termination), and each segment gets the budget its samples need
  (counted first on the host). The segments' composites are joined front to back."""
  n = piece["origins"].shape[0]
  trans = np.ones(n, np.float32)
  total, complete = None, np.ones(n, bool)
  for first in range(0, config.march_steps, occupancy.segment_length(config)):
    piece = {**piece, "alive": trans > TERMINATED}
    first = np.int32(first)
    needed = np.asarray(_sample_counts(grid, config, piece, first))
    needed = needed.reshape(mesh.size, -1).sum(1).max()
    if needed == 0 and total is not None:
      continue
    out = call(params, config, False, mesh, piece, styles, sample_budget(needed, config), first)
    if total is None:
      total = {k: np.zeros_like(out[k]) for k in ("rgb", "depth", "accumulation")}
    total["rgb"] += trans[:, None] * out["rgb"]
    total["depth"] += trans * out["depth"]
    total["accumulation"] += trans * out["accumulation"]
    acc = out["accumulation"] if styles is None else out["accumulation"][0]
    trans = trans * (1.0 - acc)
    complete &= out["complete"]
  acc = total["accumulation"]
  disparity = np.asarray(disparity_of(total["depth"], acc))
  rgb = total["rgb"] + (1.0 - acc)[..., None] if white_background else total["rgb"]
  return {"rgb": rgb, "depth": total["depth"], "disparity": disparity, "accumulation": acc,
          "complete": complete}


def weighted_samples(field, nerf_params, rays, config, budget: Optional[int] = None):
  """The frozen NeRF's samples of rays and their compositing weights, every sample it
  marched (`budget` slots, as render_rays_grid's): Sampler.weighted_samples' outputs."""
  out = render_rays_grid(field, jax.lax.stop_gradient(nerf_params), rays, config, {}, False,
                         budget=budget)
  return {"points": jax.lax.stop_gradient(out["sample_points"]),
          "weights": jax.lax.stop_gradient(out["weights"]), "ray": out["sample_ray"],
          "complete": out["complete"]}


def feature_rays(field, feature_fn, params, rays, config, budget: Optional[int] = None):
  """A feature field composited with the NeRF's frozen weights at every sample it marched
  (`budget` slots): render.render_feature_rays' outputs."""
  n = rays["origins"].shape[0]
  out = weighted_samples(field, params["nerf"], rays, config, budget)
  weights = out["weights"]
  feats = feature_fn(params["features"], out["points"])
  per_ray = lambda x: jax.ops.segment_sum(x, out["ray"], n + 1, indices_are_sorted=True)[:n]
  return {"features": per_ray(weights[:, None] * feats), "accumulation": per_ray(weights),
          "complete": out["complete"]}


@dataclasses.dataclass(frozen=True)
class GridSampler(Sampler):
  """One network at the samples in the occupied cells; a rendering call marches its rays in
  segments, each with the budget its samples need (counted first on the host)."""
  name: str = "grid"
  levels: tuple = ("fine",)
  occupancy: bool = True

  def draw_randomness(self, key, n_rays, config):
    """{"u_march": [R]} (where in its step each ray's samples sit) when perturbing."""
    return {"u_march": jax.random.uniform(key, (n_rays,))} if config.perturb else {}

  def render_rays(self, field, params, rays, config, randomness, white_background,
                  background=None, conditioning=None):
    return {"fine": render_rays_grid(field, params, rays, config, randomness, white_background,
                                     background, conditioning)}

  def image_rays(self, field, params, rays, config, white_background, conditioning=None,
                 budget=None, first=None):
    return render_rays_grid(field, params, rays, config, {}, white_background,
                            conditioning=conditioning, budget=budget, first=first)

  def render_config(self, config):
    if config.mlp_chunk == 0:  # forward only: chunks are cheap.
      return dataclasses.replace(config, mlp_chunk=RENDER_MLP_CHUNK)
    return config

  def host_state(self, params):
    return np.asarray(params["occupancy"])

  def render_piece(self, call, params, host_state, config, white_background, mesh, piece,
                   styles):
    return render_piece(call, params, host_state, config, white_background, mesh, piece,
                        styles)

  def feature_rays(self, field, feature_fn, params, rays, config, top_k, budget=None):
    del top_k
    return feature_rays(field, feature_fn, params, rays, config, budget)

  def weighted_samples(self, field, nerf_params, rays, config, top_k, budget=None):
    del top_k
    return weighted_samples(field, nerf_params, rays, config, budget)

  def piece_budget(self, host_state, config, piece):
    return sample_budget(np.asarray(_sample_counts(host_state, config, piece, None)).sum(),
                         config)


GRID = GridSampler()
