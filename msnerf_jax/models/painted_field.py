"""Painted colour fields: one view-independent colour field per style over a NeRF's frozen
geometry, each a table of colour logits at the vertices of a sparse R^3 grid over the scene
box, read by trilinear interpolation (ARF's shape: a style's strokes live in its own table,
at the grid's resolution; no network shared by the styles that would average them into a
palette).

Only the vertices near the surfaces the training views see hold a colour (`paint_index`:
those around the samples that carry weight, grown by a margin); the others share one last
row (unpainted). params {"colours": [M, V + 1, 3] logits (the colour is their sigmoid),
"index": [R, R, R] int32, the row of each vertex (V: unpainted)} for M styles over
[-bound, bound]^3 (points outside take the colour of the nearest face).
"""

import dataclasses
from typing import Dict, Iterable, Tuple

import chex
import jax
import jax.numpy as jnp
import numpy as np

# The eight corners of a cell, as (x, y, z) offsets.
_CORNERS = np.array([[i, j, k] for i in (0, 1) for j in (0, 1) for k in (0, 1)], np.int32)


def corners(points: jnp.ndarray, resolution: int, bound: float, xnp=jnp
            ) -> Tuple[jnp.ndarray, jnp.ndarray]:
  """The grid vertices around points [P, 3] and their trilinear weights: (flat vertex
  indices [P, 8] into the R^3 grid, weights [P, 8] summing to 1). `xnp`: jnp, or np on the
  host."""
  r = resolution
  unit = xnp.clip((points + bound) / (2.0 * bound), 0.0, 1.0) * (r - 1)
  low = xnp.clip(xnp.floor(unit).astype(np.int32), 0, r - 2)
  frac = unit - low
  at = low[:, None, :] + _CORNERS  # [P, 8, 3]
  flat = (at[..., 0] * r + at[..., 1]) * r + at[..., 2]
  weights = xnp.prod(xnp.where(_CORNERS == 1, frac[:, None, :], 1.0 - frac[:, None, :]), -1)
  return flat, weights


def trilinear(table: jnp.ndarray, index: jnp.ndarray, points: jnp.ndarray, bound: float
              ) -> jnp.ndarray:
  """Values of a sparse grid at points [..., 3] of [-bound, bound]^3, trilinearly
  interpolated: table [M, V + 1, C] (rows), index [R, R, R] (each vertex's row) ->
  [M, ..., C]."""
  chex.assert_rank([table, index], [3, 3])
  shape = points.shape[:-1]
  flat, weights = corners(points.reshape(-1, 3), index.shape[0], bound)
  values = jnp.asarray(table)[:, jnp.asarray(index).reshape(-1)[flat]]  # [M, P, 8, C]
  out = jnp.einsum("mpkc,pk->mpc", values, weights)
  return out.reshape(table.shape[0], *shape, table.shape[-1])


def paint_index(point_sets: Iterable[np.ndarray], resolution: int, bound: float,
                margin: int = 1) -> Tuple[np.ndarray, int]:
  """(index [R, R, R] int32, V): the vertices around the points of every set (e.g. each
  training view's cached samples, [P, 3]), grown by `margin` vertices in every direction,
  numbered 0..V-1 in raster order; every other vertex is V (unpainted)."""
  r = resolution
  painted = np.zeros(r ** 3, bool)
  for points in point_sets:
    painted[corners(np.asarray(points, np.float32), r, bound, np)[0].reshape(-1)] = True
  painted = painted.reshape(r, r, r)
  grown = painted
  for axis in range(3):
    for _ in range(margin):
      grown = _grow(grown, axis)
  index = np.full(r ** 3, 0, np.int32)
  flat = grown.reshape(-1)
  count = int(flat.sum())
  index[flat] = np.arange(count, dtype=np.int32)
  index[~flat] = count
  return index.reshape(r, r, r), count


def _grow(mask: np.ndarray, axis: int) -> np.ndarray:
  """`mask` [R, R, R] grown by one vertex both ways along `axis`."""
  moved = np.moveaxis(mask, axis, 0)
  out = moved.copy()
  out[1:] |= moved[:-1]
  out[:-1] |= moved[1:]
  return np.moveaxis(out, 0, axis)


@dataclasses.dataclass(frozen=True)
class PaintedField:
  """The colour fields of a painted run as a hashable value (a static jit argument).

  `colours(params, points [..., 3]) -> [M, ..., 3]` in [0, 1]; calling it gives the
  feature-field form the one renderer composites (render.render_feature_image):
  [..., M * 3], style-major.
  """
  bound: float

  def colours(self, params, points: jnp.ndarray) -> jnp.ndarray:
    return jax.nn.sigmoid(trilinear(params["colours"], params["index"], points, self.bound))

  def __call__(self, params, points: jnp.ndarray) -> jnp.ndarray:
    colours = self.colours(params, points)  # [M, ..., 3]
    return jnp.moveaxis(colours, 0, -2).reshape(*points.shape[:-1], -1)


def init_painted_params(n_styles: int, index: np.ndarray, count: int) -> Dict[str, jnp.ndarray]:
  """{"colours": [M, V + 1, 3] zeros (grey until painted), "index": the paint_index}."""
  return {"colours": jnp.zeros((n_styles, count + 1, 3), jnp.float32),
          "index": jnp.asarray(index, jnp.int32)}
