"""Losses on the rendering weights themselves (not on colours): what keeps empty space empty."""

import chex
import jax.numpy as jnp


def distortion(weights: jnp.ndarray, z_vals: jnp.ndarray, near: jnp.ndarray,
               far: jnp.ndarray) -> jnp.ndarray:
  """The distortion loss of mip-NeRF 360 (Barron et al. 2022, eq. 15), per ray.

  L = sum_ij w_i w_j |m_i - m_j| + 1/3 sum_i w_i^2 (s_{i+1} - s_i), with the ray's
  intervals in normalised distance s = (z - near) / (far - near) and m their midpoints. It
  is smallest when a ray's weight sits in one short interval: it pulls semi-transparent
  floaters onto the surface or removes them. Sample i covers [z_i, z_{i+1}] (how
  volume_render computes its alpha) and the last one ends at `far`.

  The double sum is computed in O(n) with cumulative sums (the midpoints are sorted).

  Args:
    weights: [..., n] volume-rendering weights.
    z_vals: [..., n] sorted sample depths.
    near, far: [...] the ray's bounds.
  Returns:
    [...] the loss of each ray (>= 0).
  """
  chex.assert_equal_shape([weights, z_vals])
  span = jnp.maximum(far - near, 1e-10)[..., None]  # guards a degenerate ray, not a real one.
  s = jnp.clip((z_vals - near[..., None]) / span, 0.0, 1.0)
  edges = jnp.concatenate([s, jnp.ones_like(s[..., :1])], -1)
  mids = 0.5 * (edges[..., 1:] + edges[..., :-1])
  widths = edges[..., 1:] - edges[..., :-1]
  # sum_{j<i} w_j and sum_{j<i} w_j m_j (exclusive cumulative sums).
  w_before = jnp.cumsum(weights, -1) - weights
  wm_before = jnp.cumsum(weights * mids, -1) - weights * mids
  inter = 2.0 * jnp.sum(weights * (mids * w_before - wm_before), -1)
  intra = jnp.sum(weights ** 2 * widths, -1) / 3.0
  return inter + intra
