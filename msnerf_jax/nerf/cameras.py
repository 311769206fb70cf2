"""Camera models: pinhole intrinsics with OpenCV radial-tangential lens distortion.

Conventions (every camera of the library):
  * K [3, 3] holds fx, fy, cx, cy in the pixel grid of the reference NeRF code, where pixel
    (column i, row j) sits at the integer coordinates (i, j). Readers of formats whose pixel
    centres sit at (i + 0.5, j + 0.5) (COLMAP, nerfstudio, instant-ngp) subtract 0.5 from
    their principal point (`centre_origin_K`).
  * Distortion coefficients [..., 5] are OpenCV's order (k1, k2, p1, p2, k3): on normalised
    image coordinates (x, y) = ((u - cx) / fx, (v - cy) / fy) (y down), with r2 = x^2 + y^2,
      x_d = x (1 + k1 r2 + k2 r2^2 + k3 r2^3) + 2 p1 x y + p2 (r2 + 2 x^2)
      y_d = y (1 + k1 r2 + k2 r2^2 + k3 r2^3) + p1 (r2 + 2 y^2) + 2 p2 x y.
    COLMAP's SIMPLE_RADIAL, RADIAL and OPENCV models and nerfstudio / instant-ngp's OPENCV
    `k1 k2 k3 p1 p2` are all this model with some coefficients zero.
  * Camera space is OpenGL's: x right, y up, looking down -z; ray directions have z = -1.

Rays are undistorted (not images): a pixel's ray is the undistorted direction of its
distorted position, found with Newton's method, so photos are used exactly as captured.
"""

import dataclasses
from typing import Optional, Tuple

import jax
import jax.numpy as jnp
import numpy as np

N_COEFFS = 5  # k1, k2, p1, p2, k3
UNDISTORT_ITERATIONS = 10


@dataclasses.dataclass(frozen=True, eq=False)
class Camera:
  """A whole camera: pose c2w [3, 4] (OpenGL), intrinsics K [3, 3], image size, lens
  distortion [5] or None. Camera paths (msnerf_jax.data.camera_path) are lists of them."""
  c2w: np.ndarray
  K: np.ndarray
  height: int
  width: int
  coeffs: Optional[np.ndarray] = None


def intrinsics(fx: float, fy: float, cx: float, cy: float) -> np.ndarray:
  """K [3, 3] float32 from focal lengths and principal point (library pixel grid)."""
  return np.array([[fx, 0.0, cx], [0.0, fy, cy], [0.0, 0.0, 1.0]], np.float32)


def centre_origin_K(fx: float, fy: float, cx: float, cy: float, scale_x: float = 1.0,
                    scale_y: float = 1.0) -> np.ndarray:
  """K [3, 3] of a camera given in the corner-origin pixel convention (COLMAP, nerfstudio,
  instant-ngp: the first pixel's centre at (0.5, 0.5)), for images resized by
  (scale_x, scale_y), in the library's grid (pixel centres at integers)."""
  return intrinsics(fx * scale_x, fy * scale_y, cx * scale_x - 0.5, cy * scale_y - 0.5)


def distort(x, y, coeffs) -> Tuple[jnp.ndarray, jnp.ndarray]:
  """Distorted normalised coordinates of undistorted ones x, y [...] (coeffs [..., 5])."""
  k1, k2, p1, p2, k3 = (coeffs[..., n] for n in range(N_COEFFS))
  r2 = x * x + y * y
  radial = 1.0 + r2 * (k1 + r2 * (k2 + r2 * k3))
  xd = x * radial + 2.0 * p1 * x * y + p2 * (r2 + 2.0 * x * x)
  yd = y * radial + p1 * (r2 + 2.0 * y * y) + 2.0 * p2 * x * y
  return xd, yd


def undistort(xd, yd, coeffs, iterations: int = UNDISTORT_ITERATIONS
              ) -> Tuple[jnp.ndarray, jnp.ndarray]:
  """Undistorted normalised coordinates of distorted ones xd, yd [...] (coeffs [..., 5]).

  Newton's method on distort(x, y) = (xd, yd) from x = xd, y = yd, a fixed number of
  steps (jit-friendly; phone lenses converge to float32 precision in 3-4).
  """
  k1, k2, p1, p2, k3 = (coeffs[..., n] for n in range(N_COEFFS))

  def newton_step(_, xy):
    x, y = xy
    r2 = x * x + y * y
    radial = 1.0 + r2 * (k1 + r2 * (k2 + r2 * k3))
    d_radial = k1 + r2 * (2.0 * k2 + 3.0 * k3 * r2)  # d radial / d r2
    fx = x * radial + 2.0 * p1 * x * y + p2 * (r2 + 2.0 * x * x) - xd
    fy = y * radial + p1 * (r2 + 2.0 * y * y) + 2.0 * p2 * x * y - yd
    # Jacobian of the residual (d r2/dx = 2x, d r2/dy = 2y).
    fx_x = radial + 2.0 * x * x * d_radial + 2.0 * p1 * y + 6.0 * p2 * x
    fx_y = 2.0 * x * y * d_radial + 2.0 * p1 * x + 2.0 * p2 * y
    fy_x = fx_y
    fy_y = radial + 2.0 * y * y * d_radial + 6.0 * p1 * y + 2.0 * p2 * x
    det = fx_x * fy_y - fx_y * fy_x
    det = jnp.where(jnp.abs(det) < 1e-12, 1e-12, det)
    return x - (fx * fy_y - fy * fx_y) / det, y - (fy * fx_x - fx * fy_x) / det

  # A loop, not unrolled steps: XLA's fusion would duplicate the shared subexpressions of
  # unrolled steps exponentially (minutes of compilation for 10 steps).
  return jax.lax.fori_loop(0, iterations, newton_step, (xd, yd))


def pixel_directions(K, cols, rows, coeffs: Optional[jnp.ndarray] = None) -> jnp.ndarray:
  """Camera-space ray directions [..., 3] (OpenGL, z = -1) through pixels (cols, rows) [...].

  K: [..., 3, 3] broadcastable against the pixels; coeffs: [..., 5] distortion or None
  (a pinhole: the reference code's formula exactly).
  """
  K = jnp.asarray(K, jnp.float32)
  x = (cols - K[..., 0, 2]) / K[..., 0, 0]
  y = (rows - K[..., 1, 2]) / K[..., 1, 1]
  if coeffs is not None:
    x, y = undistort(x, y, jnp.asarray(coeffs, jnp.float32))
  return jnp.stack([x, -y, -jnp.ones_like(x)], axis=-1)


def project(K, points, coeffs: Optional[jnp.ndarray] = None
            ) -> Tuple[jnp.ndarray, jnp.ndarray, jnp.ndarray]:
  """Pixel (cols, rows) [...] and depth [...] of camera-space points [..., 3] (OpenGL):
  the inverse of pixel_directions."""
  K = jnp.asarray(K, jnp.float32)
  depth = -points[..., 2]
  safe = jnp.where(depth > 1e-6, depth, 1e-6)
  x, y = points[..., 0] / safe, -points[..., 1] / safe
  if coeffs is not None:
    x, y = distort(x, y, jnp.asarray(coeffs, jnp.float32))
  return K[..., 0, 0] * x + K[..., 0, 2], K[..., 1, 1] * y + K[..., 1, 2], depth


def is_pinhole(coeffs: Optional[np.ndarray]) -> bool:
  """True when distortion coefficients [..., 5] are None or all zero."""
  if coeffs is None:
    return True
  return not np.any(np.asarray(coeffs))
