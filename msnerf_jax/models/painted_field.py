"""Painted colour fields: one view-independent colour field per style over a NeRF's frozen
geometry, each a dense grid of colour logits over the scene box, read by trilinear
interpolation (ARF's shape: a style's strokes live in its own table, at the grid's
resolution; no network shared by the styles that would average them to a palette).

params {"grids": [M, R, R, R, 3]} (logits; the colour is their sigmoid), for M styles at
resolution R over [-bound, bound]^3 (points outside take the colour of the nearest face).
"""

import dataclasses
from typing import Dict

import chex
import jax
import jax.numpy as jnp
import numpy as np

# The eight corners of a cell, as (x, y, z) offsets.
_CORNERS = np.array([[i, j, k] for i in (0, 1) for j in (0, 1) for k in (0, 1)], np.int32)


def trilinear(grids: jnp.ndarray, points: jnp.ndarray, bound: float) -> jnp.ndarray:
  """Values of grids [M, R, R, R, C] at points [..., 3] of [-bound, bound]^3 (clipped to
  it), trilinearly interpolated: [M, ..., C]."""
  chex.assert_rank(grids, 5)
  m, r = grids.shape[0], grids.shape[1]
  shape = points.shape[:-1]
  unit = jnp.clip((points.reshape(-1, 3) + bound) / (2.0 * bound), 0.0, 1.0) * (r - 1)
  low = jnp.clip(jnp.floor(unit).astype(jnp.int32), 0, r - 2)
  frac = unit - low  # [P, 3]
  corners = low[:, None, :] + _CORNERS  # [P, 8, 3]
  index = (corners[..., 0] * r + corners[..., 1]) * r + corners[..., 2]  # [P, 8]
  weights = jnp.prod(jnp.where(_CORNERS == 1, frac[:, None, :], 1.0 - frac[:, None, :]), -1)
  values = grids.reshape(m, r ** 3, -1)[:, index]  # [M, P, 8, C]
  out = jnp.einsum("mpkc,pk->mpc", values, weights)
  return out.reshape(m, *shape, -1)


@dataclasses.dataclass(frozen=True)
class PaintedField:
  """The colour fields of a painted run as a hashable value (a static jit argument).

  `colours(params, points [..., 3]) -> [M, ..., 3]` in [0, 1]; calling it gives the
  feature-field form the one renderer composites (render.render_feature_image):
  [..., M * 3], style-major.
  """
  resolution: int
  bound: float

  def colours(self, params, points: jnp.ndarray) -> jnp.ndarray:
    return jax.nn.sigmoid(trilinear(params["grids"], points, self.bound))

  def __call__(self, params, points: jnp.ndarray) -> jnp.ndarray:
    colours = self.colours(params, points)  # [M, ..., 3]
    return jnp.moveaxis(colours, 0, -2).reshape(*points.shape[:-1], -1)


def init_painted_params(n_styles: int, resolution: int, dtype=jnp.float32) -> Dict[str, jnp.ndarray]:
  """{"grids": [M, R, R, R, 3] zeros} (grey everywhere until painted)."""
  return {"grids": jnp.zeros((n_styles, resolution, resolution, resolution, 3), dtype)}
