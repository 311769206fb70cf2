"""A baked scene: a trained grid-sampler NeRF's density and trunk features stored at the
vertices of fine bricks in the occupied cells of its occupancy grid (SNeRG's and Plenoxels'
sparse grids), so that a view is trilinear lookups, compositing and the small view-dependent
colour layers at the samples that carry weight: no hash encoding, no trunk MLP.

Layout. Each occupied cell of the [G, G, G] occupancy grid holds a brick of (b + 1)^3
vertices (b = `resolution` sub-cells a side; G = 64, b = 4 is a 256^3 grid where it
matters). At each vertex: the density (activated, >= 0) and the trunk's `feature` [W] (what
its view layers read), the latter as `components` principal components (PCA over the
scene's vertices): feature = mean + coefficients @ basis.

Rendering (`baked_rays`): the rays are marched exactly as the occupancy-grid sampler marches
them (occupancy.march: the same sample positions), each sample's density is the trilinear
interpolation of its brick's vertices, the compositing weights follow; only the samples
whose weight exceeds `threshold` are shaded (features interpolated, decoded, the field's
view and colour layers applied), and each ray's kept weights are scaled back to its full
opacity. Everything is a pure function of a BakedScene pytree: it jits and vmaps.
"""

import functools
from typing import Callable, Dict, Optional

import chex
import flax.struct
import jax
import jax.numpy as jnp
import numpy as np

from msnerf_jax.nerf import occupancy
from msnerf_jax.nerf.render import flat_rays, keep_complete, padded
from msnerf_jax.nerf.volume_rendering import disparity_of, ray_starts, segment_cumsum

THRESHOLD = 1e-3  # samples lighter than this in a composite are not shaded.
SHADE_SHARE = 4  # a call shades at most budget // SHADE_SHARE samples.


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
                    basis=basis, mean=mean, bound=float(config.scene_box))


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


def _corners(baked: BakedScene, points: jnp.ndarray):
  """(flat vertex rows [P, 8], trilinear weights [P, 8], inside an occupied cell [P]) of
  points [P, 3]: the 8 vertices of each point's sub-cell in its brick."""
  grid, b = baked.index.shape[0], baked.resolution
  side = b + 1
  unit = (points + baked.bound) / (2.0 * baked.bound) * grid
  cell = jnp.clip(jnp.floor(unit), 0, grid - 1).astype(jnp.int32)
  brick = baked.index[cell[:, 0], cell[:, 1], cell[:, 2]]
  local = jnp.clip(unit - cell, 0.0, 1.0) * b
  low = jnp.clip(jnp.floor(local), 0, b - 1).astype(jnp.int32)
  frac = local - low
  base = (jnp.maximum(brick, 0) * side ** 3 + low[:, 0] * side * side + low[:, 1] * side
          + low[:, 2])
  rows, weights = [], []
  for dx in (0, 1):
    for dy in (0, 1):
      for dz in (0, 1):
        rows.append(base + dx * side * side + dy * side + dz)
        weights.append((frac[:, 0] if dx else 1.0 - frac[:, 0])
                       * (frac[:, 1] if dy else 1.0 - frac[:, 1])
                       * (frac[:, 2] if dz else 1.0 - frac[:, 2]))
  return jnp.stack(rows, -1), jnp.stack(weights, -1), brick >= 0


def density_at(baked: BakedScene, points: jnp.ndarray) -> jnp.ndarray:
  """[P] the baked density at points [P, 3] (0 outside the baked cells)."""
  rows, weights, inside = _corners(baked, points)
  values = baked.density.reshape(-1)[rows]
  return jnp.where(inside, jnp.sum(weights * values, -1), 0.0)


def feature_at(baked: BakedScene, points: jnp.ndarray) -> jnp.ndarray:
  """[P, W] the baked trunk feature at points [P, 3]."""
  rows, weights, _ = _corners(baked, points)
  table = baked.coefficients.reshape(-1, baked.coefficients.shape[-1])
  coefficients = jnp.einsum("pc,pck->pk", weights, table[rows])
  return baked.mean + coefficients @ baked.basis


def baked_rays(baked: BakedScene, shade: Callable, rays: Dict[str, jnp.ndarray], config,
               budget: int, white_background: bool = False,
               threshold: float = THRESHOLD) -> Dict[str, jnp.ndarray]:
  """Renders rays [R] from a baked scene.

  Args:
    baked: the BakedScene.
    shade: `(feature [P, W], viewdirs [P, 3]) -> rgb [*L, P, 3]` (the field's view and
      colour layers with its params, and style codes if any, bound: L = [M] styles).
    rays: ray_bundle [R] (may carry "alive").
    config: the NerfConfig (march_steps, scene_box).
    budget: sample slots of the march (static); at most budget // SHADE_SHARE are shaded.
  Returns:
    {"rgb": [*L, R, 3], "depth", "disparity", "accumulation": [R], "complete": [R] bool
    (False: the ray's samples did not fit the budgets; render it again in a smaller call)}.
  """
  chex.assert_rank(rays["origins"], 2)
  n = rays["origins"].shape[0]
  samples = occupancy.march(rays, baked.index >= 0, config, budget)
  ray = samples["ray"]
  safe = jnp.minimum(ray, n - 1)
  points = rays["origins"][safe] + rays["directions"][safe] * samples["t"][:, None]
  tau = jnp.where(samples["valid"], density_at(baked, points) * samples["delta"], 0.0)
  trans = jnp.exp(-(segment_cumsum(tau, ray_starts(ray)) - tau))
  weights = trans * (1.0 - jnp.exp(-tau))
  per_ray = lambda x: jax.ops.segment_sum(x, ray, n + 1, indices_are_sorted=True)[:n]
  acc = per_ray(weights)
  depth = per_ray(weights * samples["t"])
  heavy = weights > threshold
  shaded = budget // SHADE_SHARE
  pick = jnp.nonzero(heavy, size=shaded, fill_value=budget)[0]
  got = pick < budget
  pick = jnp.minimum(pick, budget - 1)
  pick_ray = jnp.where(got, ray[pick], n)
  pick_weight = jnp.where(got, weights[pick], 0.0)
  kept = jax.ops.segment_sum(pick_weight, pick_ray, n + 1, indices_are_sorted=True)[:n]
  scale = jnp.where(kept > 0, acc / jnp.maximum(kept, 1e-10), 0.0)
  rgb = shade(feature_at(baked, points[pick]), rays["viewdirs"][jnp.minimum(pick_ray, n - 1)])
  w = (pick_weight * jnp.append(scale, 0.0)[pick_ray])[:, None]
  colour = jnp.moveaxis(jax.ops.segment_sum(jnp.moveaxis(w * rgb, -2, 0), pick_ray, n + 1,
                                            indices_are_sorted=True)[:n], 0, -2)
  if white_background:
    colour = colour + (1.0 - acc)[:, None]
  fits = jnp.cumsum(jax.ops.segment_sum(heavy.astype(jnp.int32), ray, n + 1,
                                        indices_are_sorted=True)[:n]) <= shaded
  return {"rgb": colour, "depth": depth, "disparity": disparity_of(depth, acc),
          "accumulation": acc, "complete": samples["complete"] & fits}


@functools.partial(jax.jit, static_argnums=(1, 4, 5, 6))
def _baked_chunk(baked, field, params, styles, config, budget, white_background, rays):
  codes = None if styles is None else field.codes(params["fine"], styles)
  out = baked_rays(baked, lambda f, d: field.shade(params["fine"], f, d, codes), rays, config,
                   budget, white_background)
  if styles is not None:  # every output with the styles first, as render_image's.
    m = styles.shape[0]
    out = {k: v if k in ("rgb", "complete") else jnp.broadcast_to(v, (m, *v.shape))
           for k, v in out.items()}
  return out


def render_baked_image(baked: BakedScene, field, params, rays: Dict[str, jnp.ndarray], config,
                       white_background: bool = False, chunk: int = 1 << 14,
                       styles: Optional[jnp.ndarray] = None) -> Dict[str, np.ndarray]:
  """render.render_image's outputs from a baked scene: rays of any leading shape [...] in
  fixed calls of `chunk` rays (one compilation per chunk size and field, whatever the
  image size), each with a budget of chunk x config.samples_per_ray samples; a ray that
  does not fit goes again at the front of a later call.

  Args:
    field: a field with `shade` (and `codes` with `styles`): NerfField, MultistyleField.
    params: the run's params (params["fine"] is the field's).
    styles: None, or [M, style_dim] style vectors (a style field): outputs with a leading
      [M].
  Returns: numpy {"rgb": [..., 3], "depth", "disparity", "accumulation": [...]}.
  """
  shape, flat, blank = flat_rays(rays)
  n = flat["origins"].shape[0]
  budget = chunk * config.samples_per_ray
  axis = 0 if styles is None else 1
  outputs: Dict[str, np.ndarray] = {}
  pending = np.arange(n)
  while pending.size:
    take, pending = pending[:chunk], pending[chunk:]
    piece = padded(flat, blank, take, chunk)
    out = _baked_chunk(baked, field, params, styles, config, budget, white_background, piece)
    out = {k: np.asarray(v) for k, v in out.items()}
    done = out["complete"][:take.size]
    keep_complete(outputs, out, take, done, n, axis)
    pending = np.concatenate([take[~done], pending])
  return {k: joined.reshape(*joined.shape[:axis], *shape, *joined.shape[axis + 1:])
          for k, joined in outputs.items()}
