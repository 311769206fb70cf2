"""Stratified and inverse-transform sampling against the reference algorithm."""

import jax
import jax.numpy as jnp
import numpy as np

from msnerf_jax.nerf.sampling import sample_pdf, stratified_samples


def reference_sample_pdf(bins, weights, n, u):
  """The reference code's sample_pdf in numpy (explicit loops over rays)."""
  weights = weights + 1e-5
  pdf = weights / weights.sum(-1, keepdims=True)
  cdf = np.concatenate([np.zeros_like(pdf[..., :1]), np.cumsum(pdf, -1)], -1)
  out = np.zeros(u.shape)
  for r in range(u.shape[0]):
    inds = np.searchsorted(cdf[r], u[r], side="right")
    below = np.maximum(0, inds - 1)
    above = np.minimum(cdf.shape[-1] - 1, inds)
    denom = cdf[r, above] - cdf[r, below]
    denom = np.where(denom < 1e-5, 1.0, denom)
    t = (u[r] - cdf[r, below]) / denom
    out[r] = bins[r, below] + t * (bins[r, above] - bins[r, below])
  return out


def test_sample_pdf_matches_reference_deterministic_and_random():
  rng = np.random.default_rng(0)
  bins = np.sort(rng.uniform(2, 6, (5, 11)), -1).astype(np.float32)
  weights = rng.uniform(0, 1, (5, 10)).astype(np.float32)
  weights[1] = 0.0  # an empty ray
  weights[2, 3] = 50.0  # a peaked ray
  det = sample_pdf(jnp.asarray(bins), jnp.asarray(weights), 17)
  u = np.broadcast_to(np.linspace(0, 1, 17), (5, 17))
  np.testing.assert_allclose(det, reference_sample_pdf(bins, weights, 17, u), atol=1e-4)
  key = jax.random.PRNGKey(3)
  rnd = sample_pdf(jnp.asarray(bins), jnp.asarray(weights), 17, key=key)
  u = np.asarray(jax.random.uniform(key, (5, 17)))
  np.testing.assert_allclose(rnd, reference_sample_pdf(bins, weights, 17, u), atol=1e-4)


def test_sample_pdf_any_batch_shape_and_concentration():
  bins = jnp.broadcast_to(jnp.linspace(0.0, 1.0, 9), (2, 3, 9))
  weights = jnp.zeros((2, 3, 8)).at[..., 5].set(1.0)
  s = sample_pdf(bins, weights, 64, key=jax.random.PRNGKey(0))
  assert s.shape == (2, 3, 64)
  inside = jnp.mean((s >= 5 / 8) & (s <= 6 / 8))
  assert inside > 0.95
  assert jnp.all((s >= 0) & (s <= 1))


def test_empty_weights_sample_uniformly():
  bins = jnp.linspace(0.0, 1.0, 65)[None]
  s = sample_pdf(bins, jnp.zeros((1, 64)), 1000, key=jax.random.PRNGKey(1))
  hist, _ = np.histogram(np.asarray(s), bins=4, range=(0, 1))
  assert hist.min() > 200 and not np.any(np.isnan(s))


def test_stratified_bins():
  near, far = jnp.full((3,), 2.0), jnp.full((3,), 6.0)
  z = stratified_samples(near, far, 8)
  np.testing.assert_allclose(z[0], np.linspace(2, 6, 8), atol=1e-6)
  u = jax.random.uniform(jax.random.PRNGKey(0), (3, 8))
  zr = stratified_samples(near, far, 8, u=u)
  assert jnp.all(jnp.diff(zr, axis=-1) >= 0) and jnp.all((zr >= 2) & (zr <= 6))
  zd = stratified_samples(near, far, 5, lindisp=True)
  np.testing.assert_allclose(1 / zd[0], np.linspace(1 / 2, 1 / 6, 5), atol=1e-6)
