"""nerfstudio / instant-ngp `transforms.json`: one file for every frame of a capture.

Both flavours store camera-to-world matrices in OpenGL axes and intrinsics in COLMAP's
pixel convention (pixel centres at +0.5): `fl_x`, `fl_y`, `cx`, `cy`, `w`, `h` and OpenCV
distortion `k1`, `k2`, `k3`, `p1`, `p2`, given once for all frames or per frame (a frame's
keys override the file's). instant-ngp files may give only `camera_angle_x` (and
`camera_angle_y`). `camera_model` is PINHOLE or OPENCV; without it, as in nerfstudio, the
coefficients present are used (OPENCV). Fisheye models are refused.
"""

import os
from typing import Any, Dict, List, Optional

import numpy as np

from msnerf_jax.data.images import IMAGE_EXTENSIONS, json_number, read_json
from msnerf_jax.core.errors import UserError

FILE = "transforms.json"
CAMERA_MODELS = ("PINHOLE", "OPENCV")
INTRINSIC_KEYS = ("fl_x", "fl_y", "cx", "cy", "w", "h", "camera_angle_x", "camera_angle_y",
                  "k1", "k2", "k3", "k4", "p1", "p2", "camera_model", "is_fisheye")


def _focal_from_angle(merged: Dict[str, Any], key: str, side: float, source: str) -> float:
  """The focal length (pixels) of a field of view `key` (radians) across `side` pixels."""
  angle = json_number(merged[key], source, key)
  if not 0 < angle < np.pi:
    raise UserError(f"{source}: {key} {angle!r} must be in (0, pi) radians")
  return 0.5 * side / np.tan(0.5 * angle)


def frame_camera(meta: Dict[str, Any], frame: Dict[str, Any], source: str,
                 size: Optional[tuple] = None) -> Dict[str, Any]:
  """The camera of one frame: {"fx", "fy", "cx", "cy", "w", "h", "coeffs" [5]} (COLMAP pixel
  convention), the frame's keys over the file's. `size` (w, h) of the image is used when
  the file gives none."""
  merged = {k: meta[k] for k in INTRINSIC_KEYS if k in meta}
  merged.update({k: frame[k] for k in INTRINSIC_KEYS if k in frame})
  if "w" in merged and "h" in merged:
    w, h = json_number(merged["w"], source, "w"), json_number(merged["h"], source, "h")
  elif size is not None:
    w, h = float(size[0]), float(size[1])
  else:
    raise UserError(f"{source}: no image size (w and h)")
  if w <= 0 or h <= 0:
    raise UserError(f"{source}: image size {w:g}x{h:g} must be positive")
  if "fl_x" in merged:
    fx = json_number(merged["fl_x"], source, "fl_x")
  elif "camera_angle_x" in merged:
    fx = _focal_from_angle(merged, "camera_angle_x", w, source)
  else:
    raise UserError(f"{source}: no focal length (fl_x or camera_angle_x)")
  if "fl_y" in merged:
    fy = json_number(merged["fl_y"], source, "fl_y")
  elif "camera_angle_y" in merged and "fl_x" not in merged:
    fy = _focal_from_angle(merged, "camera_angle_y", h, source)
  else:
    fy = fx
  if fx <= 0 or fy <= 0:
    raise UserError(f"{source}: focal length {fx:g}, {fy:g} must be positive")
  cx = json_number(merged.get("cx", w / 2), source, "cx")
  cy = json_number(merged.get("cy", h / 2), source, "cy")
  model = merged.get("camera_model", "OPENCV")
  if model not in CAMERA_MODELS or merged.get("is_fisheye", False):
    raise UserError(f"{source}: camera model {model if model not in CAMERA_MODELS else 'fisheye'}"
                    f" is not supported (supported: {', '.join(CAMERA_MODELS)})")
  coeffs = np.zeros(5)
  if model == "OPENCV":
    for n, key in enumerate(("k1", "k2", "p1", "p2", "k3")):
      coeffs[n] = json_number(merged.get(key, 0.0), source, key)
    if json_number(merged.get("k4", 0.0), source, "k4") != 0:
      raise UserError(f"{source}: k4 {merged['k4']} (a fisheye or rational lens) is not "
                      "supported (supported: k1, k2, k3, p1, p2)")
  return {"fx": fx, "fy": fy, "cx": cx, "cy": cy, "w": w, "h": h, "coeffs": coeffs}


def image_file(folder: str, file_path: Any, source: str) -> str:
  """The image a frame's file_path names (relative to the file's folder; `./` or not; an
  extension added when it has none, as Blender's files omit it)."""
  if not isinstance(file_path, str) or not file_path:
    raise UserError(f"{source}: file_path must be a non-empty string")
  path = os.path.normpath(os.path.join(folder, file_path))
  if os.path.isfile(path):
    return path
  if not os.path.splitext(path)[1]:
    for ext in IMAGE_EXTENSIONS:
      if os.path.isfile(path + ext):
        return path + ext
  raise UserError(f"{path}: missing (named by {source})")


def read_transforms(folder: str) -> Dict[str, Any]:
  """The frames of folder/transforms.json: {"source", "meta", "frames": [{"path", "c2w" [3, 4]
  float64, "frame" (its dict)}]} sorted by image path."""
  source = os.path.join(folder, FILE)
  try:
    meta = read_json(source)
  except FileNotFoundError:
    raise UserError(f"{source}: missing") from None
  if not isinstance(meta, dict):
    raise UserError(f"{source}: expected a JSON object")
  frames = meta.get("frames")
  if not isinstance(frames, list) or not frames:
    raise UserError(f"{source}: 'frames' must be a non-empty list")
  out: List[Dict[str, Any]] = []
  for i, frame in enumerate(frames):
    where = f"{source}: frame {i}"
    if not isinstance(frame, dict) or "file_path" not in frame or "transform_matrix" not in frame:
      raise UserError(f"{where} needs 'file_path' and 'transform_matrix'")
    try:
      pose = np.asarray(frame["transform_matrix"], dtype=np.float64)
    except (TypeError, ValueError, OverflowError):  # (10**400)
      raise UserError(f"{where}: transform_matrix is not a numeric matrix") from None
    if pose.shape not in ((4, 4), (3, 4)):
      raise UserError(f"{where}: transform_matrix has shape {pose.shape}, expected 4x4")
    out.append({"path": image_file(folder, frame["file_path"], where), "c2w": pose[:3, :4],
                "frame": frame, "where": where})
  out.sort(key=lambda f: f["path"])
  return {"source": source, "meta": meta, "frames": out}


def named_splits(meta: Dict[str, Any], folder: str, paths: List[str], source: str
                 ) -> Optional[Dict[str, np.ndarray]]:
  """Splits [indices into `paths`] from nerfstudio's `train_filenames`, `val_filenames`,
  `test_filenames` (paths relative to `folder`); None when the file has none. A missing val
  split is the test split and vice versa."""
  keys = [k for k in ("train", "val", "test") if f"{k}_filenames" in meta]
  if not keys:
    return None
  index = {os.path.normpath(p): n for n, p in enumerate(paths)}
  splits = {}
  for key in keys:
    names = meta[f"{key}_filenames"]
    if not isinstance(names, list) or not all(isinstance(n, str) for n in names):
      raise UserError(f"{source}: {key}_filenames must be a list of file paths")
    ids = []
    for name in names:
      path = os.path.normpath(os.path.join(folder, name))
      if path not in index:
        raise UserError(f"{source}: {key}_filenames names {name}, which no frame has")
      ids.append(index[path])
    splits[key] = np.asarray(sorted(ids), np.int64)
  if "train" not in splits or not len(splits["train"]):
    raise UserError(f"{source}: has {', '.join(k + '_filenames' for k in keys)} but no "
                    "train_filenames")
  splits.setdefault("val", splits.get("test", np.array([], np.int64)))
  splits.setdefault("test", splits["val"])
  return splits
