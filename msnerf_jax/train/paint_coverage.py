"""Where a painting's colours reach: which grid vertices the NeRF's density occupies (they
are painted even where no training view looks: a render path may go there), how much each
painted vertex weighs in the training views (the ones that weigh nothing get no gradient
from any view), and, for those, the seen vertex they take their colour from (the nearest:
a gather map the trainer applies after every step, so a painting has no grey holes)."""

from typing import Dict, Optional, Sequence, Tuple

import jax
import jax.numpy as jnp
import numpy as np
from scipy import ndimage

from msnerf_jax.models.nerf import NerfField
from msnerf_jax.models.painted_field import corners
from msnerf_jax.nerf import occupancy

DENSE_ALPHA = 0.01  # a vertex is dense when its density stops this much light in one spacing.
SEEN_WEIGHT = 1e-3  # a vertex is seen when its summed weight in the training views is above.


def vertex_positions(resolution: int, bound: float) -> np.ndarray:
  """[R^3, 3] float32: the grid's vertices over [-bound, bound]^3 in raster (x, y, z) order
  (painted_field.corners' numbering)."""
  axis = np.linspace(-bound, bound, resolution, dtype=np.float32)
  return np.stack(np.meshgrid(axis, axis, axis, indexing="ij"), -1).reshape(-1, 3)


def dense_vertices(nerf_params, nerf_config, resolution: int, bound: float,
                   chunk: int = 1 << 16) -> np.ndarray:
  """bool [R, R, R]: the vertices where the NeRF's density (its fine network's) stops at
  least DENSE_ALPHA of the light over one vertex spacing, and, for an occupancy-grid NeRF,
  that lie in a cell its sampler marches."""
  points = vertex_positions(resolution, bound)
  field = NerfField(nerf_config)
  density = jax.jit(lambda p, x: field.geometry(p, x)[0])
  fine = jax.device_put(nerf_params["fine"])
  sigma = np.concatenate([np.asarray(density(fine, jnp.asarray(points[i:i + chunk])))
                          for i in range(0, len(points), chunk)])
  spacing = 2.0 * bound / (resolution - 1)
  dense = 1.0 - np.exp(-sigma * spacing) >= DENSE_ALPHA
  if "occupancy" in nerf_params:
    cells = occupancy.occupied(jnp.asarray(nerf_params["occupancy"]), nerf_config.grid_threshold)
    dense &= np.asarray(occupancy.lookup(cells, jnp.asarray(points), nerf_config.scene_box))
  return dense.reshape((resolution,) * 3)


def view_spread(cache: Dict[str, np.ndarray], view: int, index: np.ndarray, bound: float
                ) -> Tuple[np.ndarray, np.ndarray, np.ndarray]:
  """How one cached view's samples spread over the painted vertices: (rows [S * 8] the
  vertices' rows, spread [S * 8] each sample's weight x trilinear weight, pixel [S * 8] the
  sample's pixel) for its S samples of weight > 0."""
  weights, points = cache["weights"][view], cache["points"][view]
  keep = weights > 0
  flat, tri = corners(points[keep].astype(np.float32), index.shape[0], bound, np)
  rows = index.reshape(-1)[flat].reshape(-1)
  spread = (weights[keep][:, None] * tri).reshape(-1)
  return rows, spread, np.repeat(cache["pixel"][view][keep], 8)


def seen_vertices(cache: Dict[str, np.ndarray], index: np.ndarray, count: int, bound: float,
                  views: Optional[Sequence[int]] = None) -> np.ndarray:
  """bool [V + 1]: the painted vertices whose summed weight in the cached views (all, or
  `views`) is above SEEN_WEIGHT (row V, unpainted, never)."""
  total = np.zeros(count + 1)
  for view in range(len(cache["weights"])) if views is None else views:
    rows, spread, _ = view_spread(cache, view, index, bound)
    total += np.bincount(rows, spread, count + 1)
  seen = total > SEEN_WEIGHT
  seen[-1] = False
  return seen


def nearest_seen(index: np.ndarray, seen: np.ndarray) -> np.ndarray:
  """int32 [V + 1]: for each painted vertex (rows of `index` [R, R, R]), itself when `seen`
  [V + 1], else the row of the nearest seen vertex (Euclidean, in grid steps); row V
  (unpainted) maps to itself, and so does everything when no vertex is seen."""
  source = np.arange(len(seen), dtype=np.int32)
  if not seen.any():
    return source
  rows = index.reshape(-1)
  grid_seen = (rows < len(seen) - 1) & seen[rows]
  nearest = ndimage.distance_transform_edt(~grid_seen.reshape(index.shape),
                                              return_distances=False, return_indices=True)
  nearest_rows = index[tuple(nearest)].reshape(-1)
  unseen = (rows < len(seen) - 1) & ~seen[rows]
  source[rows[unseen]] = nearest_rows[unseen]
  return source
