"""The volume-rendering equation (NeRF eq. 3): over a ray's sorted samples, and over packed
samples of many rays (occupancy-grid sampling)."""

from typing import Dict, Optional

import chex
import jax
import jax.numpy as jnp


def disparity_of(depth: jnp.ndarray, acc: jnp.ndarray) -> jnp.ndarray:
  """Inverse of the expected depth of what was hit, depth [...] / accumulation [...]. An
  empty ray (acc = 0) gets depth 0 and disparity 1e10, never 0/0: the guard keeps NaN out
  of both values and their gradients."""
  safe_acc = jnp.maximum(acc, 1e-10)
  return 1.0 / jnp.maximum(1e-10, jnp.where(acc > 1e-10, depth / safe_acc, 0.0))


def volume_render(rgb: jnp.ndarray, sigma: jnp.ndarray, z_vals: jnp.ndarray,
                  directions: jnp.ndarray, white_background: bool = False,
                  background: Optional[jnp.ndarray] = None) -> Dict[str, jnp.ndarray]:
  """Composites samples along rays into pixel colours.

  C = sum_i T_i alpha_i c_i with alpha_i = 1 - exp(-sigma_i delta_i) and
  T_i = prod_{j<i} (1 - alpha_j); the last interval is 1e10 (the ray escapes) and every
  delta is scaled by |direction| so depths are in world units.

  Args:
    rgb: [..., n, 3] colours in [0, 1] (activated).
    sigma: [..., n] densities >= 0 (activated).
    z_vals: [..., n] sample depths along the ray, increasing.
    directions: [..., 3] ray directions (not necessarily unit length).
    white_background: composite over white: rgb + (1 - accumulation).
    background: [..., 3] (or broadcastable) colours to composite over instead,
      rgb + (1 - accumulation) * background: training against random backgrounds.
  Returns:
    dict of rgb [..., 3], depth [...], disparity [...], accumulation [...], weights [..., n].
  """
  chex.assert_equal_shape([rgb[..., 0], sigma, z_vals])
  deltas = z_vals[..., 1:] - z_vals[..., :-1]
  deltas = jnp.concatenate([deltas, jnp.full_like(deltas[..., :1], 1e10)], -1)
  deltas = deltas * jnp.linalg.norm(directions[..., None, :], axis=-1)
  alpha = 1.0 - jnp.exp(-sigma * deltas)
  # T_i: the reference code adds 1e-10 inside the product to keep it from reaching 0 exactly.
  trans = jnp.cumprod(
      jnp.concatenate([jnp.ones_like(alpha[..., :1]), 1.0 - alpha + 1e-10], -1), -1)[..., :-1]
  weights = alpha * trans
  acc = jnp.sum(weights, -1)
  color = jnp.sum(weights[..., None] * rgb, -2)
  depth = jnp.sum(weights * z_vals, -1)
  disparity = disparity_of(depth, acc)
  if background is not None:
    color = color + (1.0 - acc[..., None]) * background
  elif white_background:
    color = color + (1.0 - acc[..., None])
  return {"rgb": color, "depth": depth, "disparity": disparity, "accumulation": acc,
          "weights": weights}


def segment_cumsum(values: jnp.ndarray, starts: jnp.ndarray) -> jnp.ndarray:
  """Inclusive cumulative sum along axis 0 that restarts where starts [B] is True."""
  def combine(a, b):
    (fa, va), (fb, vb) = a, b
    return fa | fb, jnp.where(fb, vb, va + vb)
  return jax.lax.associative_scan(combine, (starts, values))[1]


def ray_starts(ray: jnp.ndarray) -> jnp.ndarray:
  """[B] bool: the slot is the first of its ray in a pack sorted by ray (occupancy.march)."""
  return jnp.concatenate([jnp.ones((1,), bool), ray[1:] != ray[:-1]])


def volume_render_packed(rgb: jnp.ndarray, sigma: jnp.ndarray, samples: Dict[str, jnp.ndarray],
                         n_rays: int, white_background: bool = False,
                         background: Optional[jnp.ndarray] = None) -> Dict[str, jnp.ndarray]:
  """volume_render of packed samples (occupancy.march): each sample covers its own step.

  C = sum_i T_i alpha_i c_i over a ray's samples with alpha_i = 1 - exp(-sigma_i delta_i),
  T_i = exp(-sum_{j<i} sigma_j delta_j) (the same ray's earlier samples; empty space between
  them has no density), computed with a segmented scan, so it is exact whatever the number
  of rays in the pack.

  Args:
    rgb: [B, *L, 3] colours of the slots (L: optional conditioning axes, e.g. [M] styles).
    sigma: [B] densities >= 0 (shared by every conditioning).
    samples: march's {"ray", "t", "delta", "valid"} [B].
    n_rays: R.
    background: [R, 3] colours to composite over (replaces white_background), or None.
  Returns:
    dict of rgb [R, *L, 3], depth [R], disparity [R], accumulation [R], weights [B].
  """
  chex.assert_rank(sigma, 1)
  chex.assert_equal_shape_prefix([rgb, sigma, samples["t"]], 1)
  ray, valid = samples["ray"], samples["valid"]
  tau = jnp.where(valid, sigma * samples["delta"], 0.0)
  starts = ray_starts(ray)
  trans = jnp.exp(-(segment_cumsum(tau, starts) - tau))
  weights = trans * (1.0 - jnp.exp(-tau))
  per_ray = lambda x: jax.ops.segment_sum(x, ray, n_rays + 1,
                                          indices_are_sorted=True)[:n_rays]
  w = weights.reshape(-1, *([1] * (rgb.ndim - 1)))
  color = per_ray(w * rgb)
  acc = per_ray(weights)
  depth = per_ray(weights * samples["t"])
  disparity = disparity_of(depth, acc)
  lead = (slice(None),) + (None,) * (rgb.ndim - 2)
  if background is not None:
    color = color + (1.0 - acc[lead])[..., None] * background[lead]
  elif white_background:
    color = color + (1.0 - acc[lead])[..., None]
  return {"rgb": color, "depth": depth, "disparity": disparity, "accumulation": acc,
          "weights": weights}
