"""Camera rays: pixel -> world rays (OpenGL convention) and the NDC warp for forward-facing scenes."""

from typing import Tuple

import chex
import jax.numpy as jnp

from msnerf_jax.nerf import cameras


def get_rays(height: int, width: int, K: jnp.ndarray, c2w: jnp.ndarray, coeffs=None
             ) -> Tuple[jnp.ndarray, jnp.ndarray]:
  """Rays through every pixel of a camera, as in the reference NeRF code for a pinhole.

  OpenGL camera: x right, y up, looking down -z. Pixels sit at integer coordinates
  (i, j) = (column, row), no half-pixel offset (reference behaviour).

  Args:
    height, width: image size in pixels.
    K: [3, 3] intrinsics (focal lengths K[0,0], K[1,1]; principal point K[0,2], K[1,2]).
    c2w: [3, 4] or [4, 4] camera-to-world matrix.
    coeffs: [5] lens distortion (msnerf_jax.nerf.cameras) or None: rays are undistorted.
  Returns:
    origins, directions: each [height, width, 3]; directions are not normalised (their
    z component in camera space is -1), as volume rendering scales intervals by their norm.
  """
  K = jnp.asarray(K, jnp.float32)
  c2w = jnp.asarray(c2w, jnp.float32)
  chex.assert_shape(K, (3, 3))
  chex.assert_rank(c2w, 2)
  c2w = c2w[:3, :4]
  i, j = jnp.meshgrid(jnp.arange(width, dtype=jnp.float32),
                      jnp.arange(height, dtype=jnp.float32), indexing="xy")
  camera_dirs = cameras.pixel_directions(K, i, j, coeffs)
  directions = camera_dirs @ c2w[:3, :3].T  # rotate into the world frame.
  origins = jnp.broadcast_to(c2w[:3, 3], directions.shape)
  return origins, directions


def ndc_rays(height: int, width: int, focal: float, near: float,
             origins: jnp.ndarray, directions: jnp.ndarray
             ) -> Tuple[jnp.ndarray, jnp.ndarray]:
  """Warps rays into normalised device coordinates (NeRF paper, appendix C).

  Rays are first moved to the near plane z = -near; in NDC the scene's depth range
  [near, inf) maps to [-1, 1), so samples are taken for t in [0, 1].

  Args:
    height, width, focal: the camera (focal in pixels).
    near: the near plane (1.0 for recentred LLFF scenes).
    origins, directions: [..., 3] world rays.
  Returns:
    NDC origins and directions, [..., 3] each.
  """
  chex.assert_equal_shape([origins, directions])
  # Shift origins to the near plane.
  t = -(near + origins[..., 2]) / directions[..., 2]
  origins = origins + t[..., None] * directions
  ox, oy, oz = origins[..., 0], origins[..., 1], origins[..., 2]
  dx, dy, dz = directions[..., 0], directions[..., 1], directions[..., 2]
  # Projection (eq. 25 of the NeRF appendix).
  o0 = -1.0 / (width / (2.0 * focal)) * ox / oz
  o1 = -1.0 / (height / (2.0 * focal)) * oy / oz
  o2 = 1.0 + 2.0 * near / oz
  d0 = -1.0 / (width / (2.0 * focal)) * (dx / dz - ox / oz)
  d1 = -1.0 / (height / (2.0 * focal)) * (dy / dz - oy / oz)
  d2 = -2.0 * near / oz
  return jnp.stack([o0, o1, o2], -1), jnp.stack([d0, d1, d2], -1)


def normalize(v: jnp.ndarray) -> jnp.ndarray:
  """Unit vectors along the last axis (view directions)."""
  return v / jnp.linalg.norm(v, axis=-1, keepdims=True)


def pixel_rays(K: jnp.ndarray, c2w: jnp.ndarray, rows: jnp.ndarray, cols: jnp.ndarray,
               coeffs=None) -> Tuple[jnp.ndarray, jnp.ndarray]:
  """Rays through chosen pixels, each with its own camera (training batches).

  Args:
    K: [3, 3] intrinsics shared by all cameras, or [..., 3, 3] one per ray.
    c2w: [..., 3, 4] one camera per ray.
    rows, cols: [...] integer pixel coordinates.
    coeffs: [..., 5] lens distortion per ray (msnerf_jax.nerf.cameras), or None (pinholes).
  Returns:
    origins, directions: [..., 3], identical to `get_rays` at those pixels.
  """
  camera_dirs = cameras.pixel_directions(K, cols.astype(jnp.float32),
                                         rows.astype(jnp.float32), coeffs)
  directions = jnp.einsum("...k,...ik->...i", camera_dirs, c2w[..., :3, :3])
  origins = jnp.broadcast_to(c2w[..., :3, 3], directions.shape)
  return origins, directions


def ray_bundle(origins: jnp.ndarray, directions: jnp.ndarray, near: float, far: float,
               ndc: bool = False, height: int = 0, width: int = 0, focal: float = 0.0):
  """A dict of everything rendering needs per ray: origins, directions, viewdirs, near, far.

  View directions are taken from the world rays before any NDC warp (reference code); in
  NDC the samples span t in [0, 1].

  Args:
    origins, directions: [..., 3].
  Returns:
    {"origins", "directions", "viewdirs"}: [..., 3] each, {"near", "far"}: [...].
  """
  viewdirs = normalize(directions)
  if ndc:
    origins, directions = ndc_rays(height, width, focal, 1.0, origins, directions)
    near, far = 0.0, 1.0
  shape = origins.shape[:-1]
  return {"origins": origins, "directions": directions, "viewdirs": viewdirs,
          "near": jnp.full(shape, near, jnp.float32), "far": jnp.full(shape, far, jnp.float32)}
