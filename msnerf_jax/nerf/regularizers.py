"""Losses on the rendering weights themselves (not on colours): what keeps empty space empty."""

import chex
import jax
import jax.numpy as jnp

from msnerf_jax.nerf.volume_rendering import ray_starts, segment_cumsum


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


def distortion_packed(weights: jnp.ndarray, interval: jnp.ndarray, ray: jnp.ndarray,
                      near: jnp.ndarray, far: jnp.ndarray) -> jnp.ndarray:
  """`distortion` of packed samples (occupancy.march): the same loss, per ray, where each
  slot's sample stands for its own step and the steps between a ray's slots (empty cells)
  carry no weight.

  Args:
    weights: [B] volume-rendering weights of the slots (0 in empty slots).
    interval: [B, 2] each slot's step [start, end) in ray parameter t.
    ray: [B] int32 ray of each slot, sorted (R for an empty slot).
    near, far: [R] the rays' bounds.
  Returns:
    [R] the loss of each ray (>= 0).
  """
  chex.assert_rank([weights, interval, ray], [1, 2, 1])
  n_rays = near.shape[0]
  safe = jnp.minimum(ray, n_rays - 1)
  span = jnp.maximum(far - near, 1e-10)[safe]
  s = jnp.clip((interval - near[safe][:, None]) / span[:, None], 0.0, 1.0)
  mids = 0.5 * (s[:, 0] + s[:, 1])
  widths = s[:, 1] - s[:, 0]
  starts = ray_starts(ray)
  w_before = segment_cumsum(weights, starts) - weights
  wm_before = segment_cumsum(weights * mids, starts) - weights * mids
  per_slot = 2.0 * weights * (mids * w_before - wm_before) + weights ** 2 * widths / 3.0
  return jax.ops.segment_sum(per_slot, ray, n_rays + 1, indices_are_sorted=True)[:n_rays]
