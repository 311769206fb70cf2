"""The hash-grid trunk (`--trunk hash`): a multiresolution hash encoding with small MLPs, the
same interface as NerfTrunk, so the `rgb` layer, the multi-style heads and the freeze mask
attach to it unchanged.

Its feature tables are the param `tables` [L, T, F] inside the `trunk` subtree: freezing the
trunk freezes them, and they get no optimizer state.
"""

from typing import Dict, Optional

import flax.linen as nn
import jax
import jax.numpy as jnp

from msnerf_jax.nerf.encoding import positional_encoding
from msnerf_jax.nerf.hash_encoding import hash_encode, level_resolutions
from msnerf_jax.models.layers import ConcatInputDense


@jax.custom_jvp
def trunc_exp(x: jnp.ndarray) -> jnp.ndarray:
  """exp(x) whose derivative is exp(min(x, 15)): instant-NGP's density activation (a density
  that shoots up does not blow up its own gradient)."""
  return jnp.exp(x)


@trunc_exp.defjvp
def _trunc_exp_jvp(primals, tangents):
  (x,), (dx,) = primals, tangents
  return jnp.exp(x), jnp.exp(jnp.minimum(x, 15.0)) * dx


def init_tables(key, shape, dtype=jnp.float32):
  """instant-NGP's initialisation: uniform in [-1e-4, 1e-4]."""
  return jax.random.uniform(key, shape, dtype, -1e-4, 1e-4)


def encode_in_box(module: nn.Module, points: jnp.ndarray) -> jnp.ndarray:
  """Inside the compact `__call__` of a module with fields levels, features, table_size,
  min_res, max_res and bound: declares its `tables` param [levels, table_size, features] and
  hash-encodes points [..., 3] of the box [-bound, bound]^3 -> [..., levels * features]."""
  tables = module.param("tables", init_tables,
                        (module.levels, module.table_size, module.features))
  unit = (points + module.bound) / (2.0 * module.bound)
  return hash_encode(tables, unit,
                     level_resolutions(module.levels, module.min_res, module.max_res))


class HashTrunk(nn.Module):
  """Points -> hash features -> `point_0` (W, ReLU) -> density `density` (W -> 1, exp) and
  `feature` (W -> W); view layers `view` ((W + encoded dirs) -> W, ReLU) and `view_1`
  (W -> W/2, ReLU): a colour MLP of two hidden layers, as instant-NGP's.

  Points are mapped from the scene box [-bound, bound]^3 to the unit cube (outside it they
  are clipped to its faces; the renderer samples only inside).
  """
  width: int = 64
  bound: float = 1.5
  levels: int = 16
  features: int = 2
  table_size: int = 2 ** 17
  min_res: int = 16
  max_res: int = 512
  dir_freqs: int = 4

  @property
  def hidden_width(self) -> int:
    """Width of `hidden`, what a density-aware head reads."""
    return self.width

  @nn.compact
  def __call__(self, points: jnp.ndarray, viewdirs: jnp.ndarray,
               feature: Optional[jnp.ndarray] = None) -> Dict[str, jnp.ndarray]:
    """Args: points [..., 3]; viewdirs [..., 3] or [..., 1, 3] (one per ray). With `feature`
    [..., W] (a `feature` output, e.g. a baked scene's, msnerf_jax.nerf.baked) the points
    are not read: only the view layers run on it.

    Returns: dict of `sigma` [...] (already non-negative: trunc_exp), `hidden` [..., W],
    `feature` [..., W] (what the view layers read) and `view_features` [..., W/2]; with a
    `feature` given, `view_features` alone.
    """
    out = {}
    if feature is None:
      x = encode_in_box(self, points)
      h = nn.relu(ConcatInputDense(self.width, name="point_0")([x]))
      sigma = trunc_exp(ConcatInputDense(1, name="density")([h])[..., 0])
      feature = ConcatInputDense(self.width, name="feature")([h])
      out = {"sigma": sigma, "hidden": h, "feature": feature}
    d = positional_encoding(viewdirs, self.dir_freqs)
    d = jnp.broadcast_to(d, (*feature.shape[:-1], d.shape[-1]))
    view = nn.relu(ConcatInputDense(self.width, name="view")([feature, d]))
    view = nn.relu(ConcatInputDense(self.width // 2, name="view_1")([view]))
    return {**out, "view_features": view}


def hash_trunk(config) -> HashTrunk:
  """The hash trunk of a NerfConfig with trunk = "hash"."""
  return HashTrunk(width=config.net_width, bound=config.scene_box, levels=config.hash_levels,
                   features=config.hash_features, table_size=config.hash_table_size,
                   min_res=config.hash_min_res, max_res=config.hash_max_res,
                   dir_freqs=config.dir_freqs)

