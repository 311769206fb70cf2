"""Positional encoding: size and the reference ordering."""

import jax
import jax.numpy as jnp
import numpy as np

from msnerf_jax.nerf.encoding import encoded_size, positional_encoding


def test_shape_and_order():
  x = jnp.array([[0.3, -1.2, 2.0]])
  y = positional_encoding(x, 4)
  assert y.shape == (1, encoded_size(3, 4)) == (1, 27)
  expected = [x[0]]
  for k in range(4):
    expected += [jnp.sin(2.0 ** k * x[0]), jnp.cos(2.0 ** k * x[0])]
  np.testing.assert_allclose(y[0], jnp.concatenate(expected), atol=1e-6)


def test_batch_dims_and_jit():
  x = jax.random.normal(jax.random.PRNGKey(0), (2, 5, 7, 3))
  y = jax.jit(positional_encoding, static_argnums=1)(x, 10)
  assert y.shape == (2, 5, 7, 63)
  np.testing.assert_allclose(y[..., :3], x)
  assert positional_encoding(x, 0).shape == x.shape
