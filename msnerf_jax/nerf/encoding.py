"""Positional encoding gamma(p) of the NeRF paper (eq. 4)."""

import jax.numpy as jnp


def positional_encoding(x: jnp.ndarray, num_freqs: int) -> jnp.ndarray:
  """gamma(x) = [x, sin(2^0 x), cos(2^0 x), ..., sin(2^(L-1) x), cos(2^(L-1) x)].

  The input is kept (reference code) and frequencies are powers of two without pi.

  Args:
    x: [..., d] coordinates.
    num_freqs: L, the number of frequency bands.
  Returns:
    [..., d * (1 + 2 L)], ordered band by band, sin before cos, all d coordinates each.
  """
  if num_freqs == 0:
    return x
  scales = 2.0 ** jnp.arange(num_freqs, dtype=x.dtype)  # [L]
  xb = x[..., None, :] * scales[:, None]  # [..., L, d]
  # Per band: sin over the d coordinates, then cos.
  features = jnp.concatenate([jnp.sin(xb), jnp.cos(xb)], axis=-1)  # [..., L, 2d]
  features = features.reshape(*x.shape[:-1], num_freqs * 2 * x.shape[-1])
  return jnp.concatenate([x, features], axis=-1)


def encoded_size(d: int, num_freqs: int) -> int:
  """Length of gamma(x) for x of size d."""
  return d * (1 + 2 * num_freqs)
