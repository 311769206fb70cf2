"""LLFF forward-facing scenes: poses_bounds.npy + images_{factor}/, recentred, NDC, spiral path."""

import os
import re

import numpy as np

from msnerf_jax.data import images as images_lib
from msnerf_jax.data.scene import Scene, check_poses
from msnerf_jax.core.errors import UserError
from msnerf_jax.core.progress import progress_bar


def _normalize(x):
  return x / np.linalg.norm(x)


def view_matrix(z, up, pos):
  """[3, 4] camera looking along z with the given up vector and position."""
  vec2 = _normalize(z)
  vec0 = _normalize(np.cross(up, vec2))
  vec1 = _normalize(np.cross(vec2, vec0))
  return np.stack([vec0, vec1, vec2, pos], 1)


def poses_avg(poses):
  """The average camera [3, 4] of poses [N, 3, >=4]."""
  center = poses[:, :3, 3].mean(0)
  z = _normalize(poses[:, :3, 2].sum(0))
  up = poses[:, :3, 1].sum(0)
  return view_matrix(z, up, center)


def recenter_poses(poses):
  """Expresses poses [N, 3, 4] in the frame of their average camera."""
  bottom = np.array([[0, 0, 0, 1.0]])
  c2w = np.concatenate([poses_avg(poses), bottom], 0)
  full = np.concatenate([poses[:, :3, :4], np.tile(bottom[None], (len(poses), 1, 1))], 1)
  return (np.linalg.inv(c2w) @ full)[:, :3, :4]


def spiral_path(poses, bounds, n_views=120, n_rots=2, zrate=0.5):
  """The reference code's spiral render path around the average camera. Returns [n, 3, 4]."""
  c2w = poses_avg(poses)
  up = _normalize(poses[:, :3, 1].sum(0))
  close_depth, inf_depth = bounds.min() * 0.9, bounds.max() * 5.0
  dt = 0.75
  focal = 1.0 / ((1.0 - dt) / close_depth + dt / inf_depth)
  rads = np.concatenate([np.percentile(np.abs(poses[:, :3, 3]), 90, 0), [1.0]])
  path = []
  for theta in np.linspace(0.0, 2.0 * np.pi * n_rots, n_views + 1)[:-1]:
    c = c2w[:3, :4] @ (np.array([np.cos(theta), -np.sin(theta), -np.sin(theta * zrate), 1.0]) * rads)
    z = _normalize(c - c2w[:3, :4] @ np.array([0, 0, -focal, 1.0]))
    path.append(view_matrix(z, up, c))
  return np.stack(path)


def _image_folder(path: str, factor: int):
  """images_{factor}/, or the finest images_{k} with k dividing factor (resized on load)."""
  folder = os.path.join(path, f"images_{factor}")
  if os.path.isdir(folder):
    return folder, 1
  candidates = []
  for name in os.listdir(path):
    m = re.fullmatch(r"images(?:_(\d+))?", name)
    if m and os.path.isdir(os.path.join(path, name)):
      k = int(m.group(1) or 1)
      if factor % k == 0:
        candidates.append((k, name))
  if not candidates:
    raise UserError(f"{folder}: missing (and no images_k folder with k dividing {factor})")
  k, name = max(candidates)
  return os.path.join(path, name), factor // k


def load_llff(path: str, factor: int = 8, holdout: int = 8, bd_factor: float = 0.75) -> Scene:
  """Loads an LLFF scene as the reference code does (recentred, bounds scaled, NDC rays).

  Every `holdout`-th image is held out as the val and test split.
  """
  pb_path = os.path.join(path, "poses_bounds.npy")
  poses_bounds = images_lib.load_numbers(pb_path, "a readable .npy array")
  if poses_bounds.ndim != 2 or poses_bounds.shape[1] != 17:
    raise UserError(f"{pb_path}: shape {poses_bounds.shape}, expected [N, 17] "
                    "(3x5 pose-hwf + 2 bounds per image)")
  if not np.all(np.isfinite(poses_bounds)):
    raise UserError(f"{pb_path}: holds NaN or inf")
  folder, extra = _image_folder(path, factor)
  files = images_lib.list_images(folder)
  if len(files) != len(poses_bounds):
    raise UserError(f"{folder}: {len(files)} images but {pb_path} has {len(poses_bounds)} poses")
  imgs = []
  for f in progress_bar(files, desc="loading images", leave=False, disable=None):
    image = images_lib.read_image(f)
    if extra > 1:
      image = images_lib.resize(image, image.shape[0] // extra, image.shape[1] // extra)
    imgs.append(image)
  images = images_lib.stack_same_size(imgs, files)
  poses = poses_bounds[:, :15].reshape(-1, 3, 5).astype(np.float64)
  bounds = poses_bounds[:, 15:].astype(np.float64)
  if np.any(bounds <= 0):
    raise UserError(f"{pb_path}: depth bounds must be positive")
  h, w = images.shape[1:3]
  with np.errstate(all="ignore"):
    focal = poses[0, 2, 4] * h / poses[0, 0, 4]  # hwf is stored for the full-size images.
  if not np.isfinite(np.float32(focal)) or np.float32(focal) <= 0:
    raise UserError(f"{pb_path}: the first pose's height {poses[0, 0, 4]:g} and focal length "
                    f"{poses[0, 2, 4]:g} give no usable focal length (both must be positive)")
  # LLFF stores [down, right, back]; NeRF wants [right, up, back].
  poses = np.concatenate([poses[:, :, 1:2], -poses[:, :, 0:1], poses[:, :, 2:4]], 2)
  check_poses(poses, pb_path, files)
  poses, bounds, render_poses = forward_facing(poses, bounds, bd_factor, pb_path)
  K = np.array([[focal, 0, 0.5 * w], [0, focal, 0.5 * h], [0, 0, 1]], np.float32)
  return Scene(images=images, c2w=poses.astype(np.float32), K=K, near=float(bounds.min() * 0.9),
               far=float(bounds.max()), ndc=True, white_background=False,
               splits=holdout_splits(len(images), holdout),
               render_poses=render_poses.astype(np.float32), format="llff",
               image_paths=tuple(files))


def forward_facing(poses: np.ndarray, bounds: np.ndarray, bd_factor: float = 0.75,
                   source: str = "the scene"):
  """LLFF's normalisation of a forward-facing capture (reference code): the scene scaled so
  the nearest depth bound is 1 / bd_factor, the poses recentred on their average camera.

  Args:
    poses: [N, 3, 4] camera-to-world (OpenGL axes); bounds: [N, 2] near/far depths.
    source: the file named when they cannot be normalised.
  Returns:
    (poses [N, 3, 4], bounds [N, 2], spiral render path [120, 3, 4]), float64.
  Raises:
    UserError naming `source` when the cameras have no average (they look in opposite
    directions) or the numbers overflow float32.
  """
  with np.errstate(all="ignore"):
    scale = 1.0 / (bounds.min() * bd_factor)
    poses = np.array(poses, np.float64)
    poses[:, :3, 3] *= scale
    bounds = bounds * scale
    try:
      poses = recenter_poses(poses)
      path = spiral_path(poses, bounds)
    except np.linalg.LinAlgError:
      path = np.full((1, 3, 4), np.nan)
  for array in (poses, bounds, path):
    if not np.all(np.isfinite(array.astype(np.float32))):
      raise UserError(f"{source}: the cameras cannot be normalised as a forward-facing scene "
                      "(no average view direction, or positions and depths out of range)")
  return poses, bounds, path


def holdout_splits(n: int, holdout: int):
  """Splits of n views with every `holdout`-th view (from the first) held out as val and test
  (holdout 0: none)."""
  test = np.arange(n)[::holdout] if holdout > 0 else np.array([], np.int64)
  train = np.array([i for i in range(n) if i not in set(test.tolist())])
  return {"train": train, "val": test, "test": test}
