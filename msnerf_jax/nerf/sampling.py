"""Where to sample along rays: stratified bins and hierarchical inverse-transform sampling."""

from typing import Optional

import chex
import jax
import jax.numpy as jnp


def stratified_samples(near: jnp.ndarray, far: jnp.ndarray, n_samples: int,
                       u: Optional[jnp.ndarray] = None, lindisp: bool = False) -> jnp.ndarray:
  """Depths of n samples per ray between near and far (NeRF eq. 2).

  The interval is cut into n evenly spaced points (linear in depth, or in disparity with
  `lindisp`); with `u` each sample is jittered uniformly within its bin (stratified).

  Args:
    near, far: [...] per-ray bounds (or scalars broadcastable to the ray shape).
    n_samples: n.
    u: optional [..., n] uniform numbers in [0, 1) for the jitter; None = bin edges.
    lindisp: sample linearly in inverse depth.
  Returns:
    z_vals: [..., n], increasing along the last axis.
  """
  t = jnp.linspace(0.0, 1.0, n_samples)
  near = jnp.asarray(near, jnp.float32)[..., None]
  far = jnp.asarray(far, jnp.float32)[..., None]
  if lindisp:
    z_vals = 1.0 / (1.0 / near * (1.0 - t) + 1.0 / far * t)
  else:
    z_vals = near * (1.0 - t) + far * t
  if u is not None:
    z_vals = jnp.broadcast_to(z_vals, u.shape)
    mids = 0.5 * (z_vals[..., 1:] + z_vals[..., :-1])
    upper = jnp.concatenate([mids, z_vals[..., -1:]], -1)
    lower = jnp.concatenate([z_vals[..., :1], mids], -1)
    z_vals = lower + (upper - lower) * u
  return z_vals


def sample_pdf(bins: jnp.ndarray, weights: jnp.ndarray, n_samples: int,
               key: Optional[jax.Array] = None, u: Optional[jnp.ndarray] = None
               ) -> jnp.ndarray:
  """Inverse-transform sampling of the piecewise-constant pdf given by weights (NeRF eq. 5).

  As in the reference code: weights get +1e-5 (so an empty ray still samples uniformly),
  the search is right-sided, and denominators below 1e-5 become 1.

  Args:
    bins: [..., n_bins + 1] bin edges (midpoints of the coarse samples).
    weights: [..., n_bins] non-negative weights of the bins.
    n_samples: how many samples per ray.
    key: PRNG key for u ~ U[0, 1); None = deterministic u = linspace(0, 1, n_samples).
    u: optional explicit [..., n_samples] uniform numbers (overrides key).
  Returns:
    [..., n_samples] samples inside [bins[..., 0], bins[..., -1]], not sorted when random.
  """
  chex.assert_equal_shape_prefix([bins, weights], weights.ndim - 1)
  chex.assert_axis_dimension(bins, -1, weights.shape[-1] + 1)
  weights = weights + 1e-5  # Keeps the pdf defined on rays with zero weight everywhere.
  pdf = weights / jnp.sum(weights, -1, keepdims=True)
  cdf = jnp.cumsum(pdf, -1)
  cdf = jnp.concatenate([jnp.zeros_like(cdf[..., :1]), cdf], -1)  # [..., n_bins + 1]
  batch_shape = cdf.shape[:-1]
  if u is None:
    if key is None:
      u = jnp.broadcast_to(jnp.linspace(0.0, 1.0, n_samples), (*batch_shape, n_samples))
    else:
      u = jax.random.uniform(key, (*batch_shape, n_samples))
  chex.assert_shape(u, (*batch_shape, n_samples))
  # Right-sided searchsorted: inds = number of cdf entries <= u.
  inds = jnp.sum(u[..., :, None] >= cdf[..., None, :], axis=-1)
  below = jnp.maximum(0, inds - 1)
  above = jnp.minimum(cdf.shape[-1] - 1, inds)
  cdf_below = jnp.take_along_axis(cdf, below, axis=-1)
  cdf_above = jnp.take_along_axis(cdf, above, axis=-1)
  bins_below = jnp.take_along_axis(bins, below, axis=-1)
  bins_above = jnp.take_along_axis(bins, above, axis=-1)
  denom = cdf_above - cdf_below
  denom = jnp.where(denom < 1e-5, 1.0, denom)  # A flat cdf step: avoid dividing by ~0.
  t = (u - cdf_below) / denom
  return bins_below + t * (bins_above - bins_below)
