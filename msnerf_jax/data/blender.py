"""Blender synthetic scenes (NeRF format): transforms_{train,val,test}.json + RGBA PNGs."""

import os

import numpy as np

from msnerf_jax.data import images as images_lib
from msnerf_jax.data.scene import Scene, check_poses
from msnerf_jax.core.errors import UserError
from msnerf_jax.core.progress import progress_bar

SPLITS = ("train", "val", "test")
NEAR, FAR = 2.0, 6.0


def _read_transforms(path: str):
  meta = images_lib.read_json(path)
  if not isinstance(meta, dict):
    raise UserError(f"{path}: expected a JSON object")
  for key in ("camera_angle_x", "frames"):
    if key not in meta:
      raise UserError(f"{path}: missing key {key!r}")
  angle = meta["camera_angle_x"]
  if not isinstance(angle, (int, float)) or not np.isfinite(angle) or not 0 < angle < np.pi:
    raise UserError(f"{path}: camera_angle_x must be an angle in (0, pi) radians, got {angle!r}")
  if not isinstance(meta["frames"], list) or not meta["frames"]:
    raise UserError(f"{path}: 'frames' must be a non-empty list")
  for i, frame in enumerate(meta["frames"]):
    if not isinstance(frame, dict) or "file_path" not in frame or "transform_matrix" not in frame:
      raise UserError(f"{path}: frame {i} needs 'file_path' and 'transform_matrix'")
  return meta


def pose_spherical(theta: float, phi: float, radius: float) -> np.ndarray:
  """Camera on a sphere looking at the origin (reference render path). Returns [4, 4]."""
  trans = np.eye(4)
  trans[2, 3] = radius
  p, t = np.deg2rad(phi), np.deg2rad(theta)
  rot_phi = np.array([[1, 0, 0, 0], [0, np.cos(p), -np.sin(p), 0],
                      [0, np.sin(p), np.cos(p), 0], [0, 0, 0, 1]])
  rot_theta = np.array([[np.cos(t), 0, -np.sin(t), 0], [0, 1, 0, 0],
                        [np.sin(t), 0, np.cos(t), 0], [0, 0, 0, 1]])
  flip = np.array([[-1, 0, 0, 0], [0, 0, 1, 0], [0, 1, 0, 0], [0, 0, 0, 1]])
  return flip @ rot_theta @ rot_phi @ trans


def load_blender(path: str, downscale: int = 1) -> Scene:
  """Loads every split that has a transforms file; RGBA is composited on white.

  Args:
    path: scene folder.
    downscale: integer factor (8 turns 800x800 into 100x100, area averaging).
  """
  if downscale < 1:
    raise UserError(f"--downscale {downscale}: must be >= 1")
  all_images, all_alphas, all_poses, paths, splits = [], [], [], [], {}
  angle = None
  for split in SPLITS:
    tpath = os.path.join(path, f"transforms_{split}.json")
    if not os.path.exists(tpath):
      continue
    meta = _read_transforms(tpath)
    angle = meta["camera_angle_x"] if angle is None else angle
    start = len(all_images)
    for i, frame in enumerate(progress_bar(meta["frames"], desc=f"loading {split}", leave=False,
                                   disable=None)):
      fp = frame["file_path"]
      if not isinstance(fp, str):
        raise UserError(f"{tpath}: frame {i} file_path is not a string")
      image_path = os.path.normpath(os.path.join(path, fp))
      if not os.path.splitext(image_path)[1]:
        image_path += ".png"
      pose = np.asarray(frame["transform_matrix"], dtype=object)
      try:
        pose = pose.astype(np.float64)
      except (TypeError, ValueError, OverflowError):  # (10**400)
        raise UserError(f"{tpath}: frame {i} transform_matrix is not numeric") from None
      if pose.shape != (4, 4) and pose.shape != (3, 4):
        raise UserError(f"{tpath}: frame {i} transform_matrix has shape {pose.shape}, "
                        "expected 4x4")
      rgba = images_lib.read_image(image_path, keep_alpha=True, reduce=downscale)
      rgb = rgba[..., :3] * rgba[..., 3:] + (1.0 - rgba[..., 3:])  # white background
      all_images.append(rgb.astype(np.float32))
      all_alphas.append(np.round(rgba[..., 3] * 255).astype(np.uint8))
      all_poses.append(pose[:3, :4])
      paths.append(image_path)
    splits[split] = np.arange(start, len(all_images))
  if not all_images:
    raise UserError(f"{path}: no transforms_{{train,val,test}}.json")
  if "train" not in splits:
    raise UserError(f"{os.path.join(path, 'transforms_train.json')}: missing")
  images = images_lib.stack_same_size(all_images, paths)
  poses = np.stack(all_poses).astype(np.float32)
  check_poses(poses, path, paths)
  h, w = images.shape[1:3]
  focal = 0.5 * w / np.tan(0.5 * angle)
  K = np.array([[focal, 0, 0.5 * w], [0, focal, 0.5 * h], [0, 0, 1]], np.float32)
  render_poses = np.stack([pose_spherical(a, -30.0, 4.0)[:3, :4]
                           for a in np.linspace(-180, 180, 41)[:-1]]).astype(np.float32)
  return Scene(images=images, c2w=poses, K=K, near=NEAR, far=FAR, ndc=False,
               white_background=True, splits=splits, render_poses=render_poses,
               format="blender", image_paths=tuple(paths),
               alphas=images_lib.stack_same_size(all_alphas, paths))
