"""Multiresolution hash encoding (instant-NGP, Mueller et al. 2022), in pure JAX.

Level l is a grid of resolution N_l = floor(N_min * b^l), b = exp((ln N_max - ln N_min) /
(L - 1)), over the unit cube. A point's feature at that level is the trilinear interpolation
of the F-dimensional features stored at its cell's 8 vertices; a level whose (N_l + 1)^3
vertices fit in the table is indexed densely (one entry per vertex), a finer one through the
spatial hash (x * 1) xor (y * 2654435761) xor (z * 805459861) mod T. The L levels' features are
concatenated.

On CPU the gathers (and their scatter-add in the backward pass) dominate: each level gathers
its 8 corners at once from its own [T, F] table, with the indices built from 2 x 2 x 2
broadcast sums rather than 8 separate ones.
"""

from typing import Sequence, Tuple

import chex
import jax.numpy as jnp
import numpy as np

PRIMES = (np.uint32(1), np.uint32(2654435761), np.uint32(805459861))


def level_resolutions(levels: int, min_res: int, max_res: int) -> Tuple[int, ...]:
  """N_l for l = 0 .. levels - 1, geometric from min_res to max_res (both included)."""
  if levels == 1:
    return (int(min_res),)
  growth = np.exp((np.log(max_res) - np.log(min_res)) / (levels - 1))
  return tuple(int(np.floor(min_res * growth ** l + 1e-6)) for l in range(levels))


def corner_indices(cell: jnp.ndarray, resolution: int, table_size: int) -> jnp.ndarray:
  """Table rows of the 8 vertices of each cell: cell [..., 3] uint32 (the lower corner),
  -> [..., 8] int32 ordered (x, y, z) = (0,0,0), (0,0,1), ..., (1,1,1)."""
  axes = [jnp.stack([cell[..., i], cell[..., i] + 1], -1) for i in range(3)]  # 3 x [..., 2]
  x = axes[0][..., :, None, None]
  y = axes[1][..., None, :, None]
  z = axes[2][..., None, None, :]
  if (resolution + 1) ** 3 <= table_size:  # dense: one row per vertex.
    side = np.uint32(resolution + 1)
    rows = x + y * side + z * (side * side)
  else:
    rows = ((x * PRIMES[0]) ^ (y * PRIMES[1]) ^ (z * PRIMES[2])) & np.uint32(table_size - 1)
  return rows.reshape(*cell.shape[:-1], 8).astype(jnp.int32)


def corner_weights(frac: jnp.ndarray) -> jnp.ndarray:
  """Trilinear weights [..., 8] (corner order of corner_indices) of offsets frac [..., 3]
  in [0, 1] inside a cell."""
  w = [jnp.stack([1.0 - frac[..., i], frac[..., i]], -1) for i in range(3)]
  return (w[0][..., :, None, None] * w[1][..., None, :, None]
          * w[2][..., None, None, :]).reshape(*frac.shape[:-1], 8)


def hash_encode(tables: jnp.ndarray, x: jnp.ndarray, resolutions: Sequence[int]) -> jnp.ndarray:
  """Features of points x [..., 3] in the unit cube [0, 1]^3 (clipped to it).

  Args:
    tables: [L, T, F] the levels' feature tables (T a power of two).
    x: [..., 3] points.
    resolutions: the L grid resolutions (level_resolutions).
  Returns:
    [..., L * F] the levels' interpolated features, level by level.
  """
  tables = jnp.asarray(tables)
  chex.assert_rank(tables, 3)
  chex.assert_axis_dimension(x, -1, 3)
  n_levels, table_size, _ = tables.shape
  if len(resolutions) != n_levels:
    raise ValueError(f"{len(resolutions)} resolutions for {n_levels} tables")
  x = jnp.clip(x, 0.0, 1.0)
  outs = []
  for level, res in enumerate(resolutions):
    scaled = x * res
    # The upper face (x = 1) belongs to the last cell, so every corner index stays <= res.
    cell = jnp.minimum(jnp.floor(scaled), res - 1)
    rows = corner_indices(cell.astype(jnp.uint32), res, table_size)
    values = tables[level].at[rows].get(mode="promise_in_bounds")  # [..., 8, F]
    outs.append(jnp.einsum("...c,...cf->...f", corner_weights(scaled - cell), values))
  return jnp.concatenate(outs, -1)
