"""Camera-path files in nerfstudio's `camera_path.json` format (what its viewer exports and
`ns-render camera-path` reads):

  {"camera_type": "perspective", "render_width": W, "render_height": H, "fps": 24,
   "seconds": S, "camera_path": [{"camera_to_world": [16 numbers, a row-major 4x4],
                                  "fov": vertical field of view in degrees,
                                  "aspect": W / H}, ...]}

Poses are OpenGL camera-to-world matrices in the scene's normalised world (the frame the
run was trained in: `msnerf nerf camera-path` writes the scene's own path there, to edit
or script). Only perspective cameras are read.
"""

import json
import os
from typing import Any, Dict, List, Sequence, Tuple

import numpy as np

from msnerf_jax.nerf import cameras as cameras_lib
from msnerf_jax.data.images import json_number, read_json
from msnerf_jax.core.errors import UserError
from msnerf_jax.core.files import atomic_write_bytes


def read_camera_path(path: str) -> Tuple[List[cameras_lib.Camera], float]:
  """The cameras of a camera_path.json and its frame rate (fps, default 24).

  Raises:
    UserError naming the file for anything but a well-formed perspective path.
  """
  try:
    meta = read_json(path)
  except FileNotFoundError:
    raise UserError(f"{path}: no such file") from None
  except IsADirectoryError:
    raise UserError(f"{path}: is a folder, expected a camera_path.json") from None
  if not isinstance(meta, dict) or not isinstance(meta.get("camera_path"), list):
    raise UserError(f"{path}: expected a JSON object with a 'camera_path' list")
  if meta.get("camera_type", "perspective") != "perspective":
    raise UserError(f"{path}: camera_type {meta['camera_type']!r} is not supported "
                    "(perspective only)")
  if not meta["camera_path"]:
    raise UserError(f"{path}: 'camera_path' is empty")
  width, height = (_pixels(meta.get(key), path, key) for key in ("render_width", "render_height"))
  fps = json_number(meta.get("fps", 24), path, "fps", positive=True)
  cameras = []
  for i, frame in enumerate(meta["camera_path"]):
    where = f"{path}: camera_path[{i}]"
    if not isinstance(frame, dict) or "camera_to_world" not in frame or "fov" not in frame:
      raise UserError(f"{where} needs 'camera_to_world' and 'fov'")
    try:
      matrix = np.asarray(frame["camera_to_world"], np.float64)
    except (TypeError, ValueError, OverflowError):
      raise UserError(f"{where}: camera_to_world is not numeric") from None
    with np.errstate(over="ignore"):
      finite = np.all(np.isfinite(matrix.astype(np.float32)))  # (1e308: inf as float32)
    if matrix.size != 16 or not finite:
      raise UserError(f"{where}: camera_to_world must be 16 finite numbers (a 4x4 matrix)")
    c2w = matrix.reshape(4, 4)[:3, :4]
    if abs(np.linalg.det(c2w[:, :3])) < 1e-6:
      raise UserError(f"{where}: camera_to_world has a singular rotation")
    fov = json_number(frame["fov"], where, "fov", positive=True)
    if fov >= 180:
      raise UserError(f"{where}: fov {fov} must be below 180 degrees")
    focal = 0.5 * height / np.tan(np.radians(fov) / 2)
    K = cameras_lib.centre_origin_K(focal, focal, width / 2, height / 2)
    if not np.all(np.isfinite(K)) or K[0, 0] <= 0:
      raise UserError(f"{where}: fov {fov} gives no usable focal length at {width}x{height}")
    cameras.append(cameras_lib.Camera(c2w.astype(np.float32), K, height, width))
  return cameras, fps


def _pixels(value: Any, path: str, key: str) -> int:
  """A size in pixels of the file: a whole number >= 1 (UserError naming `key` otherwise)."""
  number = json_number(value, path, key, positive=True)
  if number != int(number) or number > 2 ** 20:
    raise UserError(f"{path}: {key} must be a whole number of pixels (1 to 2^20), got {value!r}")
  return int(number)


def camera_path_dict(poses: Sequence[np.ndarray], K: np.ndarray, height: int, width: int,
                     fps: float = 24.0) -> Dict[str, Any]:
  """A camera_path.json (dict) of cameras c2w [P, 3, 4] with intrinsics K [3, 3] (shared) or
  [P, 3, 3] of a height x width image (the vertical field of view is what the format keeps)."""
  Ks = np.broadcast_to(np.asarray(K), (len(poses), 3, 3))
  path = []
  for c2w, K in zip(poses, Ks):
    fov = float(np.degrees(2 * np.arctan(0.5 * height / float(K[1, 1]))))
    matrix = np.eye(4)
    matrix[:3, :4] = c2w
    path.append({"camera_to_world": [float(x) for x in matrix.ravel()], "fov": fov,
                 "aspect": width / height})
  return {"camera_type": "perspective", "render_width": int(width), "render_height": int(height),
          "fps": fps, "seconds": len(path) / fps, "camera_path": path}


def write_camera_path(path: str, poses: Sequence[np.ndarray], K: np.ndarray, height: int,
                      width: int, fps: float = 24.0) -> None:
  """Writes camera_path_dict(...) to `path` atomically."""
  if os.path.isdir(path):
    raise UserError(f"{path}: is a folder, expected a .json file name")
  atomic_write_bytes(path, json.dumps(camera_path_dict(poses, K, height, width, fps),
                                      indent=1).encode())
