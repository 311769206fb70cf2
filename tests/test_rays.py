"""Rays: reference conventions (OpenGL camera, integer pixels), pixel rays, NDC warp."""

import jax.numpy as jnp
import numpy as np

from msnerf_jax.nerf import rays


def reference_get_rays(H, W, K, c2w):
  """The reference (nerf-pytorch) formula, in numpy, loop-free but independent."""
  i, j = np.meshgrid(np.arange(W, dtype=np.float32), np.arange(H, dtype=np.float32), indexing="xy")
  dirs = np.stack([(i - K[0][2]) / K[0][0], -(j - K[1][2]) / K[1][1], -np.ones_like(i)], -1)
  rays_d = np.sum(dirs[..., np.newaxis, :] * c2w[:3, :3], -1)
  rays_o = np.broadcast_to(c2w[:3, -1], np.shape(rays_d))
  return rays_o, rays_d


def random_pose(seed):
  rng = np.random.default_rng(seed)
  q, _ = np.linalg.qr(rng.normal(size=(3, 3)))
  return np.concatenate([q, rng.normal(size=(3, 1))], 1).astype(np.float32)


def test_get_rays_matches_reference_formula():
  K = np.array([[50.0, 0, 20.0], [0, 55.0, 15.0], [0, 0, 1]], np.float32)
  c2w = random_pose(0)
  o, d = rays.get_rays(30, 40, K, c2w)
  ro, rd = reference_get_rays(30, 40, K, c2w)
  assert o.shape == (30, 40, 3) and d.shape == (30, 40, 3)
  np.testing.assert_allclose(o, ro, atol=1e-6)
  np.testing.assert_allclose(d, rd, atol=1e-5)


def test_opengl_convention_and_4x4_pose():
  K = np.array([[10.0, 0, 2.0], [0, 10.0, 2.0], [0, 0, 1]], np.float32)
  o, d = rays.get_rays(5, 5, K, np.eye(4))
  np.testing.assert_allclose(d[2, 2], [0, 0, -1])  # principal pixel looks down -z
  assert d[2, 4, 0] > 0 and d[0, 2, 1] > 0  # right is +x, the top row is +y
  np.testing.assert_allclose(o, 0.0)


def test_pixel_rays_equal_full_image_rays():
  K = np.array([[40.0, 0, 16.0], [0, 40.0, 12.0], [0, 0, 1]], np.float32)
  poses = np.stack([random_pose(1), random_pose(2)])
  rows = jnp.array([0, 5, 23]); cols = jnp.array([31, 0, 7]); which = jnp.array([0, 1, 1])
  o, d = rays.pixel_rays(jnp.asarray(K), jnp.asarray(poses)[which], rows, cols)
  for n in range(3):
    fo, fd = rays.get_rays(24, 32, K, poses[int(which[n])])
    np.testing.assert_allclose(o[n], fo[int(rows[n]), int(cols[n])], atol=1e-6)
    np.testing.assert_allclose(d[n], fd[int(rows[n]), int(cols[n])], atol=1e-5)


def test_ndc_maps_near_plane_to_minus_one_and_infinity_to_one():
  H, W, focal = 30, 40, 35.0
  K = np.array([[focal, 0, W / 2], [0, focal, H / 2], [0, 0, 1]], np.float32)
  o, d = rays.get_rays(H, W, K, np.eye(4)[:3])
  o = o + jnp.array([0.1, -0.2, 0.0])
  no, nd = rays.ndc_rays(H, W, focal, 1.0, o, d)
  np.testing.assert_allclose(no[..., 2], -1.0, atol=1e-5)  # origins on the near plane
  np.testing.assert_allclose((no + nd)[..., 2], 1.0, atol=1e-5)  # t = 1 is infinitely far
  # A world point on the ray projects to the same NDC point as the NDC ray at some t.
  t_world = 3.7
  p = o[7, 11] + t_world * d[7, 11]
  ndc_p = np.array([-focal / (W / 2) * p[0] / p[2], -focal / (H / 2) * p[1] / p[2], 1 + 2 / p[2]])
  t_ndc = (ndc_p[2] - no[7, 11, 2]) / nd[7, 11, 2]
  np.testing.assert_allclose(no[7, 11] + t_ndc * nd[7, 11], ndc_p, atol=1e-4)


def test_ray_bundle_ndc_keeps_world_viewdirs():
  o = jnp.zeros((4, 3)); d = jnp.array([[0.1, 0.0, -1.0]] * 4)
  b = rays.ray_bundle(o, d, 2.0, 6.0, ndc=True, height=10, width=10, focal=10.0)
  np.testing.assert_allclose(b["viewdirs"], d / np.linalg.norm(d, axis=-1, keepdims=True), atol=1e-6)
  np.testing.assert_allclose(b["near"], 0.0); np.testing.assert_allclose(b["far"], 1.0)
