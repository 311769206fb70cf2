"""The volume-rendering equation: known cases, empty rays, backgrounds, gradients."""

import jax
import jax.numpy as jnp
import numpy as np

from msnerf_jax.nerf.volume_rendering import volume_render


def test_opaque_first_sample_gives_its_colour_and_depth():
  rgb = jnp.array([[[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]]])
  sigma = jnp.array([[1e4, 0.0, 5.0]])
  z = jnp.array([[2.0, 3.0, 4.0]])
  out = volume_render(rgb, sigma, z, jnp.array([[0.0, 0.0, -1.0]]))
  np.testing.assert_allclose(out["rgb"][0], [1, 0, 0], atol=1e-5)
  np.testing.assert_allclose(out["depth"][0], 2.0, atol=1e-4)
  np.testing.assert_allclose(out["accumulation"][0], 1.0, atol=1e-5)


def test_weights_follow_transmittance_and_direction_norm():
  sigma = jnp.array([[0.5, 0.5, 0.5]])
  z = jnp.array([[0.0, 1.0, 2.0]])
  out = volume_render(jnp.ones((1, 3, 3)), sigma, z, jnp.array([[0.0, 2.0, 0.0]]))
  # |d| = 2 doubles every interval: alpha = 1 - e^-1 for the first two samples.
  a = 1 - np.exp(-1.0)
  np.testing.assert_allclose(out["weights"][0, :2], [a, (1 - a) * a], rtol=1e-5)
  np.testing.assert_allclose(out["weights"][0, 2], (1 - a) ** 2, rtol=1e-4)  # last delta 1e10


def test_empty_ray_has_no_nan_and_white_background():
  rgb = jnp.zeros((2, 4, 3)); sigma = jnp.zeros((2, 4)); z = jnp.tile(jnp.linspace(2, 6, 4), (2, 1))
  d = jnp.array([[0.0, 0.0, -1.0]] * 2)
  out = volume_render(rgb, sigma, z, d, white_background=True)
  for v in out.values():
    assert not jnp.any(jnp.isnan(v))
  np.testing.assert_allclose(out["rgb"], 1.0)
  np.testing.assert_allclose(out["accumulation"], 0.0)
  grad = jax.grad(lambda s: volume_render(rgb, s, z, d)["disparity"].sum())(sigma)
  assert not jnp.any(jnp.isnan(grad))
