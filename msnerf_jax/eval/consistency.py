"""Multi-view consistency of a rendered camera path: warp frame t+k onto frame t with the rendered
depth and the known poses, mask occluded and empty pixels, compare.

Protocol (per pair (t, t+k), averaged over t = 0 .. T-1-k):
  1. Every pixel of frame t is lifted to its 3D point: the camera ray at the rendered
     (expected) depth; NDC depths (LLFF) are mapped back to world space first.
  2. The point is projected into camera t+k, giving a sub-pixel position (u, v) and its
     depth z in that camera; frame t+k is sampled there bilinearly (backward warping).
  3. A pixel counts only if it lands inside frame t+k, both frames see something there
     (accumulated opacity > 0.5: no empty background), and it is not occluded: z agrees with
     frame t+k's own rendered depth at (u, v) within `depth_tolerance` (relative).
  4. RMSE over the counted pixels (and channels), and LPIPS between frame t and the warped
     frame with uncounted pixels set to 0 in both.
Short range uses k = 1, long range k = 7. Stylized-3D papers (StyleRF, StyleGaussian, Styl3R)
report the same short/long-range warped RMSE and LPIPS, with optical flow (RAFT) instead of
rendered depth for the warp; with a radiance field the depth-based warp is exact up to the
expected-depth approximation and needs no flow network.
"""

import functools
from typing import Dict, Sequence

import chex
import jax
import jax.numpy as jnp
import numpy as np

from msnerf_jax.nerf import rays as rays_lib


def world_points(K, c2w, depth, ndc: bool = False) -> jnp.ndarray:
  """3D points [H, W, 3] of the pixels of a camera at rendered depths [H, W].

  Non-NDC: origin + depth * direction (directions have z = -1 in the camera, so the depth is
  the camera-space depth). NDC (near plane 1): the point in NDC space, mapped back.
  """
  h, w = depth.shape
  origins, directions = rays_lib.get_rays(h, w, K, c2w)
  if not ndc:
    return origins + depth[..., None] * directions
  focal = K[0, 0]
  o, d = rays_lib.ndc_rays(h, w, focal, 1.0, origins, directions)
  p = o + depth[..., None] * d
  # Inverse of the NDC map x' = -f/(W/2) x/z, y' = -f/(H/2) y/z, z' = 1 + 2 near / z.
  z = 2.0 / jnp.minimum(p[..., 2] - 1.0, -1e-6)
  return jnp.stack([-p[..., 0] * z * w / (2 * focal), -p[..., 1] * z * h / (2 * focal), z], -1)


def project(K, c2w, points):
  """Pixel (col, row) [H, W] each and camera depth [H, W] of world points [H, W, 3]."""
  c2w = jnp.asarray(c2w)
  cam = (points - c2w[:3, 3]) @ c2w[:3, :3]  # R^T (X - t), row-vector form
  depth = -cam[..., 2]
  safe = jnp.where(depth > 1e-6, depth, 1e-6)
  cols = K[0, 0] * cam[..., 0] / safe + K[0, 2]
  rows = K[1, 2] - K[1, 1] * cam[..., 1] / safe
  return cols, rows, depth


def _sample(image, rows, cols, order=1):
  """image [H, W, C] at float pixel positions (rows, cols) [H, W] (bilinear, edge clamped)."""
  return jnp.stack([jax.scipy.ndimage.map_coordinates(image[..., c], [rows, cols], order=order,
                                                      mode="nearest")
                    for c in range(image.shape[-1])], -1)


@functools.partial(jax.jit, static_argnames=("ndc",))
def warp(frame_s, depth_t, depth_s, acc_t, acc_s, c2w_t, c2w_s, K, ndc: bool = False,
         depth_tolerance=0.05):
  """Frame s warped onto frame t, and the mask of pixels where that is valid.

  Args:
    frame_s: [H, W, 3]; depth_*, acc_*: [H, W] rendered depth and opacity of frames t and s;
    c2w_*: [3, 4] cameras; K: [3, 3]; ndc: depths are NDC ray parameters (LLFF).
  Returns:
    (warped [H, W, 3], mask [H, W] bool).
  """
  h, w = depth_t.shape
  cols, rows, z = project(K, c2w_s, world_points(K, c2w_t, depth_t, ndc))
  z_s = project(K, c2w_s, world_points(K, c2w_s, depth_s, ndc))[2]  # frame s's own camera depth map
  # Pixel centres: get_rays puts pixel (i, j) at integer coordinates.
  inside = (cols >= 0) & (cols <= w - 1) & (rows >= 0) & (rows <= h - 1) & (z > 0)
  seen = _sample(z_s[..., None], rows, cols, order=0)[..., 0]
  visible = jnp.abs(seen - z) <= depth_tolerance * jnp.maximum(seen, 1e-6)
  solid = (acc_t > 0.5) & (_sample(acc_s[..., None], rows, cols)[..., 0] > 0.5)
  return _sample(frame_s, rows, cols), inside & visible & solid


def consistency(frames: Sequence[np.ndarray], depths: Sequence[np.ndarray],
                accumulations: Sequence[np.ndarray], poses: np.ndarray, K: np.ndarray,
                ndc: bool, gap: int, lpips_fn=None, depth_tolerance: float = 0.05,
                batch: int = 8) -> Dict[str, float]:
  """Warped RMSE (and LPIPS) between frames t and t + gap along a path, averaged over t.

  Args:
    frames: T images [H, W, 3] in [0, 1]; depths, accumulations: T maps [H, W] (the
      geometry used for the warp: for every method compared, the same radiance field's);
    poses: [T, 3, 4]; K: [3, 3]; gap: k (1 short range, 7 long range).
    lpips_fn: optional (images [B, H, W, 3], targets [B, H, W, 3]) -> LPIPS [B] (called on
      `batch` pairs at a time).
  Returns:
    {"rmse", "lpips" (when lpips_fn), "coverage" (mean fraction of valid pixels), "pairs"}.
  """
  chex.assert_equal(len(frames), len(poses))
  if len(frames) <= gap:
    raise ValueError(f"need more than {gap} frames for gap {gap}, got {len(frames)}")
  rmses, coverage, warped_pairs, targets = [], [], [], []
  for t in range(len(frames) - gap):
    s = t + gap
    warped, mask = warp(jnp.asarray(frames[s]), jnp.asarray(depths[t]), jnp.asarray(depths[s]),
                        jnp.asarray(accumulations[t]), jnp.asarray(accumulations[s]),
                        jnp.asarray(poses[t]), jnp.asarray(poses[s]), jnp.asarray(K),
                        ndc, depth_tolerance)
    mask = np.asarray(mask)
    coverage.append(float(mask.mean()))
    if not mask.any():
      continue
    diff = (np.asarray(frames[t]) - np.asarray(warped))[mask]
    rmses.append(float(np.sqrt(np.mean(diff ** 2))))
    if lpips_fn is not None:
      m = mask[..., None]
      warped_pairs.append(np.where(m, np.asarray(warped), 0.0).astype(np.float32))
      targets.append(np.where(m, np.asarray(frames[t]), 0.0).astype(np.float32))
  out = {"rmse": float(np.mean(rmses)) if rmses else float("nan"),
         "coverage": float(np.mean(coverage)), "pairs": len(rmses)}
  if lpips_fn is not None:
    scores = [np.asarray(lpips_fn(np.stack(warped_pairs[i:i + batch]),
                                  np.stack(targets[i:i + batch])))
              for i in range(0, len(warped_pairs), batch)]
    out["lpips"] = float(np.mean(np.concatenate(scores))) if scores else float("nan")
  return out
