"""A baked scene: a trained grid-sampler NeRF's density and trunk features stored at the
vertices of fine bricks in the occupied cells of its occupancy grid (SNeRG's and Plenoxels'
sparse grids), so that a view is trilinear lookups, compositing and the small view-dependent
colour layers at the samples that carry weight: no hash encoding, no trunk MLP.

Layout. Each occupied cell of the [G, G, G] occupancy grid holds a brick of (b + 1)^3
vertices (b = `resolution` sub-cells a side; G = 64, b = 4 is a 256^3 grid where it
matters). At each vertex: the density (activated, >= 0) and the trunk's `feature` [W] (what
its view layers read), the latter as `components` principal components (PCA over the
scene's vertices): feature = mean + coefficients @ basis.

Rendering: heavy_samples marches the rays exactly as the occupancy-grid sampler does
(occupancy.march in the baked cells: the same sample positions), interpolates each sample's
density in its brick and composites; only the samples heavier than THRESHOLD are shaded
(shade_samples: the feature interpolated and decoded, the field's own view and colour layers
applied, for any style vectors of a multi-style field), each ray's shaded weights scaled to
its full opacity. Both are pure functions of a BakedScene pytree (they jit); the image
driver render_baked_image calls them in fixed sizes (one compilation each, whatever the
image size). Measured against the exact renderer: experiments/benchmarks/bench_render.py.
"""

import functools
from typing import Callable, Dict, Optional

import chex
import flax.struct
import jax
import jax.numpy as jnp
import numpy as np

from msnerf_jax.nerf import occupancy
from msnerf_jax.nerf.render import flat_rays, padded
from msnerf_jax.nerf.volume_rendering import disparity_of

THRESHOLD = 3e-3  # samples lighter than this in a composite are not shaded.


@flax.struct.dataclass
class BakedScene:
  """A baked scene (a pytree of arrays; `bound` static).

  Attributes:
    index: [G, G, G] int32: the brick of each occupancy cell, -1 for an empty cell.
    density: [N, S, S, S] float32: density at the N bricks' vertices (S = resolution + 1).
    coefficients: [N, S, S, S, K] float32: the trunk feature's principal components there.
    basis: [K, W] float32 principal directions; mean: [W] float32.
    bound: the scene box's half side (static).
  """
  index: jnp.ndarray
  density: jnp.ndarray
  coefficients: jnp.ndarray
  basis: jnp.ndarray
  mean: jnp.ndarray
  bound: float = flax.struct.field(pytree_node=False)

  @property
  def resolution(self) -> int:
    return int(self.density.shape[-1]) - 1


def brick_vertices(cells: np.ndarray, grid: int, resolution: int, bound: float) -> np.ndarray:
  """World positions [N, S, S, S, 3] of the vertices of the bricks of `cells` [N, 3]
  (occupancy cell indices of a [grid]^3 grid over [-bound, bound]^3)."""
  lin = np.arange(resolution + 1, dtype=np.float64) / resolution
  offsets = np.stack(np.meshgrid(lin, lin, lin, indexing="ij"), -1)  # [S, S, S, 3]
  unit = (cells[:, None, None, None, :] + offsets[None]) / grid
  return ((unit * 2.0 - 1.0) * bound).astype(np.float32)


def bake(geometry: Callable, occupancy_values, config, resolution: int = 4,
         components: int = 16, chunk: int = 1 << 15) -> BakedScene:
  """Bakes a field over the occupied cells of its occupancy grid.

  Deterministic (the same params give the same arrays): the vertices are evaluated in fixed
  chunks of one jitted function, and the PCA basis is fitted on a fixed subsample.

  Args:
    geometry: jitted `(points [P, 3]) -> (density [P] >= 0, feature [P, W])` (the field's
      `geometry` with its params bound).
    occupancy_values: the run's params["occupancy"] [G, G, G].
    config: the NerfConfig (grid_threshold, scene_box).
    resolution: sub-cells a side of each occupied cell.
    components: principal components kept of the W-wide feature.
    chunk: vertices per call.
  """
  occupied = np.asarray(occupancy.occupied(jnp.asarray(occupancy_values), config.grid_threshold))
  grid = occupied.shape[0]
  cells = np.argwhere(occupied)
  index = np.full(occupied.shape, -1, np.int32)
  index[tuple(cells.T)] = np.arange(len(cells), dtype=np.int32)
  points = brick_vertices(cells, grid, resolution, config.scene_box).reshape(-1, 3)
  n = points.shape[0]
  densities, features = [], []
  for start in range(0, n, chunk):
    size = min(chunk, n - start)
    piece = np.zeros((chunk, 3), np.float32)
    piece[:size] = points[start:start + size]
    sigma, feature = geometry(jnp.asarray(piece))
    densities.append(np.asarray(sigma)[:size])
    features.append(np.asarray(feature)[:size])
  density = np.concatenate(densities) if densities else np.zeros((0,), np.float32)
  feature = np.concatenate(features) if features else np.zeros((0, 1), np.float32)
  mean, basis = principal_components(feature, components)
  coefficients = ((feature - mean) @ basis.T).astype(np.float32)
  side = resolution + 1
  return BakedScene(index=index, density=density.reshape(-1, side, side, side),
                    coefficients=coefficients.reshape(-1, side, side, side, basis.shape[0]),
                    basis=basis, mean=mean,
                    bound=float(config.scene_box))


def principal_components(features: np.ndarray, components: int, sample: int = 1 << 17):
  """(mean [W], basis [K, W]) of features [P, W]: the top K = min(components, W) principal
  directions, fitted (in float64) on at most `sample` evenly spaced rows."""
  width = features.shape[-1]
  k = min(components, width)
  if features.shape[0] == 0:
    return np.zeros(width, np.float32), np.eye(k, width, dtype=np.float32)
  rows = features[::max(1, features.shape[0] // sample)].astype(np.float64)
  mean = rows.mean(0)
  _, _, vt = np.linalg.svd(rows - mean, full_matrices=False)
  basis = np.zeros((k, width))
  basis[:vt.shape[0]] = vt[:k]
  return mean.astype(np.float32), basis.astype(np.float32)


def _interpolate(baked: BakedScene, table: jnp.ndarray, points: jnp.ndarray) -> jnp.ndarray:
  """Trilinear interpolation [P, C] at points [P, 3] of `table` [N * S^3, C] (one row per
  brick vertex, bricks in the order of baked.index), 0 outside the baked cells: the 8
  vertices of each point's sub-cell are 8 row gathers, blended by 7 lerps."""
  grid, b = baked.index.shape[0], baked.resolution
  side = b + 1
  unit = (points + baked.bound) * (grid / (2.0 * baked.bound))
  cell = jnp.clip(jnp.floor(unit), 0, grid - 1)
  inside = jnp.all((unit >= 0.0) & (unit <= grid), -1)
  icell = cell.astype(jnp.int32)
  brick = baked.index[icell[:, 0], icell[:, 1], icell[:, 2]]
  local = jnp.clip(unit - cell, 0.0, 1.0) * b
  low = jnp.minimum(jnp.floor(local), b - 1)
  f = (local - low)[:, :, None]
  low = low.astype(jnp.int32)
  base = (jnp.maximum(brick, 0) * side ** 3 + low[:, 0] * (side * side) + low[:, 1] * side
          + low[:, 2])
  at = lambda dx, dy, dz: table[base + (dx * side * side + dy * side + dz)]
  lerp = lambda a, c, w: a + w * (c - a)
  z = [[lerp(at(dx, dy, 0), at(dx, dy, 1), f[:, 2]) for dy in (0, 1)] for dx in (0, 1)]
  y = [lerp(z[dx][0], z[dx][1], f[:, 1]) for dx in (0, 1)]
  value = lerp(y[0], y[1], f[:, 0])
  return jnp.where((inside & (brick >= 0))[:, None], value, 0.0)


def density_at(baked: BakedScene, points: jnp.ndarray) -> jnp.ndarray:
  """[P] the baked density at points [P, 3] (0 outside the baked cells)."""
  return _interpolate(baked, baked.density.reshape(-1, 1), points)[:, 0]


def feature_at(baked: BakedScene, points: jnp.ndarray) -> jnp.ndarray:
  """[P, W] the baked trunk feature at points [P, 3]."""
  table = baked.coefficients.reshape(-1, baked.coefficients.shape[-1])
  return baked.mean + _interpolate(baked, table, points) @ baked.basis


def ray_cumsum(values: jnp.ndarray, ray: jnp.ndarray, step: jnp.ndarray, n_rays: int,
               n_steps: int) -> jnp.ndarray:
  """Each packed sample's running sum along its ray (volume_rendering.segment_cumsum's):
  values [B] of rays `ray` [B] (n_rays: empty) at steps `step` [B] are scattered into a
  dense [n_rays + 1, n_steps] array, summed along the steps and gathered back. (Over
  interpolated densities the segmented scan took 63 ms for 196,608 slots on the 2-core CPU,
  this 6 ms: docs/results/render-speed.md.)"""
  index = ray * n_steps + step
  dense = jnp.zeros(((n_rays + 1) * n_steps,), values.dtype).at[index].add(values)
  return jnp.cumsum(dense.reshape(n_rays + 1, n_steps), 1).reshape(-1)[index]


def heavy_samples(baked: BakedScene, rays: Dict[str, jnp.ndarray], config, budget: int,
                  threshold: float = THRESHOLD) -> Dict[str, jnp.ndarray]:
  """The geometry of rays [R] from a baked scene: the occupancy-grid sampler's samples
  (occupancy.march in the baked cells), their density interpolated in the bricks,
  composited; the samples heavier than `threshold` packed first (the ones worth shading),
  each ray's weights scaled so that its shaded ones sum to its opacity (a ray none of
  whose samples is that heavy keeps its opacity and gets no colour).

  Returns: {"points": [budget, 3], "weights": [budget], "ray": [budget] (R: an empty slot),
  "count": [] int32 (how many slots are used), "accumulation", "depth": [R], "complete":
  [R] bool (the ray's samples fit the budget)}.
  """
  chex.assert_rank(rays["origins"], 2)
  n = rays["origins"].shape[0]
  samples = occupancy.march(rays, baked.index >= 0, config, budget)
  ray = samples["ray"]
  safe = jnp.minimum(ray, n - 1)
  points = rays["origins"][safe] + rays["directions"][safe] * samples["t"][:, None]
  tau = jnp.where(samples["valid"], density_at(baked, points) * samples["delta"], 0.0)
  trans = jnp.exp(-(ray_cumsum(tau, ray, samples["step"], n, config.march_steps) - tau))
  weights = trans * (1.0 - jnp.exp(-tau))
  per_ray = lambda x, r=ray: jax.ops.segment_sum(x, r, n + 1, indices_are_sorted=True)[:n]
  acc = per_ray(weights)
  heavy = weights > threshold
  pick = jnp.nonzero(heavy, size=budget, fill_value=budget - 1)[0]
  count = jnp.sum(heavy, dtype=jnp.int32)
  used = jnp.arange(budget) < count
  pick_ray = jnp.where(used, ray[pick], n)
  pick_weight = jnp.where(used, weights[pick], 0.0)
  kept = per_ray(pick_weight, pick_ray)
  scale = jnp.append(jnp.where(kept > 0, acc / jnp.maximum(kept, 1e-10), 0.0), 0.0)
  return {"points": points[pick], "weights": pick_weight * scale[pick_ray], "ray": pick_ray,
          "count": count, "accumulation": acc, "depth": per_ray(weights * samples["t"]),
          "complete": samples["complete"]}


def shade_samples(baked: BakedScene, shade: Callable, points: jnp.ndarray, weights: jnp.ndarray,
                  viewdirs: jnp.ndarray) -> jnp.ndarray:
  """Weighted colours [*L, P, 3] of samples at points [P, 3] with weights [P] seen along
  viewdirs [P, 3]: the baked feature decoded, then `shade` (feature [P, W], viewdirs
  [P, 3]) -> rgb [*L, P, 3] (the field's view and colour layers; L = [M] styles or none)."""
  return weights[:, None] * shade(feature_at(baked, points), viewdirs)


@functools.partial(jax.jit, static_argnums=(1, 2))
def _geometry_call(baked, config, budget, rays):
  return heavy_samples(baked, rays, config, budget)


@functools.partial(jax.jit, static_argnums=(1,))
def _shade_call(baked, field, params, styles, points, weights, viewdirs):
  codes = None if styles is None else field.codes(params["fine"], styles)
  return shade_samples(baked, lambda f, d: field.shade(params["fine"], f, d, codes), points,
                       weights, viewdirs)


def render_baked_image(baked: BakedScene, field, params, rays: Dict[str, jnp.ndarray], config,
                       white_background: bool = False, chunk: int = 1 << 12,
                       styles: Optional[jnp.ndarray] = None, shade_chunk: int = 1 << 13,
                       per_ray: Optional[int] = None) -> Dict[str, np.ndarray]:
  """render.render_image's outputs from a baked scene: rays of any leading shape [...].

  The rays go through heavy_samples in fixed calls of `chunk` rays (a budget of chunk x
  per_ray samples, per_ray default half of config.samples_per_ray: a ray that does not fit
  goes again at the front of a later call), the heavy samples through the field's view and
  colour layers in fixed calls of `shade_chunk` samples: one compilation each, whatever the
  image size.

  Args:
    field: a field with `shade` (and `codes` with `styles`): NerfField, MultistyleField.
    params: the run's params (params["fine"] is the field's).
    styles: None, or [M, style_dim] style vectors (a style field): outputs with a leading
      [M].
  Returns: numpy {"rgb": [..., 3], "depth", "disparity", "accumulation": [...]}.
  """
  shape, flat, blank = flat_rays(rays)
  n = flat["origins"].shape[0]
  lead = () if styles is None else (styles.shape[0],)
  budget = chunk * (per_ray or max(1, config.samples_per_ray // 2))
  rgb = np.zeros((*lead, n, 3), np.float32)
  acc, depth = np.zeros(n, np.float32), np.zeros(n, np.float32)
  pending = np.arange(n)
  while pending.size:
    take, pending = pending[:chunk], pending[chunk:]
    out = _geometry_call(baked, config, budget, padded(flat, blank, take, chunk))
    done = np.asarray(out["complete"])[:take.size]
    count = int(out["count"])
    ray = np.asarray(out["ray"])[:count]
    lists = {k: np.asarray(out[k])[:count] for k in ("points", "weights")}
    lists["viewdirs"] = flat["viewdirs"][take[np.minimum(ray, take.size - 1)]]
    for start in range(0, count, shade_chunk):
      part = {k: v[start:start + shade_chunk] for k, v in lists.items()}
      size = part["weights"].shape[0]
      part = {k: np.concatenate([v, np.zeros((shade_chunk - size, *v.shape[1:]), v.dtype)])
              for k, v in part.items()}
      colour = np.asarray(_shade_call(baked, field, params, styles, part["points"],
                                      part["weights"], part["viewdirs"]))[..., :size, :]
      where = ray[start:start + size]
      for channel in np.ndindex(*lead, 3):  # per style and channel: a bincount per ray.
        into = rgb[channel[:-1]][:, channel[-1]]
        into[take[done]] += np.bincount(where, colour[channel[:-1]][:, channel[-1]],
                                        take.size + 1)[:take.size][done]
    acc[take[done]] = np.asarray(out["accumulation"])[:take.size][done]
    depth[take[done]] = np.asarray(out["depth"])[:take.size][done]
    pending = np.concatenate([take[~done], pending])
  if white_background:
    rgb = rgb + (1.0 - acc)[:, None]
  result = {"rgb": rgb, "depth": depth, "disparity": np.asarray(disparity_of(depth, acc)),
            "accumulation": acc}
  result = {k: v if k == "rgb" else np.broadcast_to(v, (*lead, n)) for k, v in result.items()}
  return {k: v.reshape(*lead, *shape, *v.shape[len(lead) + 1:]) for k, v in result.items()}
