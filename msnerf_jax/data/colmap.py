"""COLMAP sparse models (`cameras`, `images`, `points3D`; binary `.bin` or text `.txt`).

A small reader of COLMAP's documented model format
(https://colmap.github.io/format.html) instead of pycolmap: the format is three flat record
files, and pycolmap is a large compiled dependency (it bundles COLMAP itself) for reading
them. The reader checks every record: truncated files, unknown camera models, images
without a camera and points that name missing images are errors naming the file.

Cameras are converted to the library's camera model (msnerf_jax.nerf.cameras): K in the pixel
grid with pixel centres at integers (COLMAP's principal point minus 0.5) and OpenCV
distortion coefficients (k1, k2, p1, p2, k3).
"""

import dataclasses
import os
import struct
from typing import Dict, List, Optional, Tuple

import numpy as np

from msnerf_jax.core.errors import UserError

# id -> (name, number of parameters), as COLMAP numbers its camera models.
CAMERA_MODELS = {
    0: ("SIMPLE_PINHOLE", 3), 1: ("PINHOLE", 4), 2: ("SIMPLE_RADIAL", 4), 3: ("RADIAL", 5),
    4: ("OPENCV", 8), 5: ("OPENCV_FISHEYE", 8), 6: ("FULL_OPENCV", 12), 7: ("FOV", 5),
    8: ("SIMPLE_RADIAL_FISHEYE", 4), 9: ("RADIAL_FISHEYE", 5), 10: ("THIN_PRISM_FISHEYE", 12),
    # COLMAP 3.12+ / 4.x (read, so that their cameras get the "not supported" message).
    11: ("RAD_TAN_THIN_PRISM_FISHEYE", 16), 12: ("SIMPLE_DIVISION", 4), 13: ("DIVISION", 5),
    14: ("SIMPLE_FISHEYE", 3), 15: ("FISHEYE", 4), 16: ("EUCM", 6), 17: ("EQUIRECTANGULAR", 2),
}
MODEL_IDS = {name: (i, n) for i, (name, n) in CAMERA_MODELS.items()}
SUPPORTED = ("SIMPLE_PINHOLE", "PINHOLE", "SIMPLE_RADIAL", "RADIAL", "OPENCV", "FULL_OPENCV")


@dataclasses.dataclass(frozen=True)
class Camera:
  model: str
  width: int
  height: int
  params: Tuple[float, ...]


@dataclasses.dataclass(frozen=True)
class Image:
  """A registered image: world-to-camera rotation qvec (w, x, y, z) and translation tvec
  (COLMAP/OpenCV camera axes: x right, y down, z forward)."""
  id: int
  qvec: Tuple[float, float, float, float]
  tvec: Tuple[float, float, float]
  camera_id: int
  name: str


@dataclasses.dataclass(frozen=True)
class Model:
  """cameras: id -> Camera; images: registered images in file order; points: [P, 3] xyz;
  tracks: per point, the ids of the images that see it (None when no points3D file)."""
  path: str
  cameras: Dict[int, Camera]
  images: List[Image]
  points: Optional[np.ndarray]
  tracks: Optional[List[np.ndarray]]


def find_model(path: str) -> Optional[str]:
  """The folder of the COLMAP model of a capture: `path` itself, sparse/0 or sparse (the
  first that holds cameras.bin or cameras.txt), or None."""
  for folder in (path, os.path.join(path, "sparse", "0"), os.path.join(path, "sparse")):
    if any(os.path.isfile(os.path.join(folder, f"cameras.{ext}")) for ext in ("bin", "txt")):
      return folder
  return None


# ----------------------------------------------------------------------------- binary


class _Reader:
  """Little-endian struct reads over a file's bytes; UserError naming the file at its end."""

  def __init__(self, path: str):
    self.path = path
    with open(path, "rb") as f:
      self.data = f.read()
    self.offset = 0

  def read(self, fmt: str):
    size = struct.calcsize("<" + fmt)
    if self.offset + size > len(self.data):
      raise UserError(f"{self.path}: truncated (ends at byte {len(self.data)} inside a record)")
    values = struct.unpack_from("<" + fmt, self.data, self.offset)
    self.offset += size
    return values

  def array(self, dtype, count: int) -> np.ndarray:
    size = np.dtype(dtype).itemsize * count
    if self.offset + size > len(self.data):
      raise UserError(f"{self.path}: truncated (ends at byte {len(self.data)} inside a record)")
    out = np.frombuffer(self.data, dtype, count, self.offset)
    self.offset += size
    return out

  def string(self) -> str:
    end = self.data.find(b"\0", self.offset)
    if end < 0:
      raise UserError(f"{self.path}: truncated (an image name has no end)")
    value = self.data[self.offset:end].decode("utf-8", "replace")
    self.offset = end + 1
    return value

  def done(self) -> None:
    if self.offset != len(self.data):
      raise UserError(f"{self.path}: {len(self.data) - self.offset} bytes after the last record")


def _model_params(path: str, model_id: int) -> Tuple[str, int]:
  if model_id not in CAMERA_MODELS:
    raise UserError(f"{path}: unknown camera model id {model_id} (COLMAP's are "
                    f"0-{max(CAMERA_MODELS)})")
  return CAMERA_MODELS[model_id]


def read_cameras_bin(path: str) -> Dict[int, Camera]:
  r = _Reader(path)
  cameras = {}
  for _ in range(r.read("Q")[0]):
    camera_id, model_id, width, height = r.read("iiQQ")
    name, n = _model_params(path, model_id)
    cameras[camera_id] = Camera(name, int(width), int(height), r.read("d" * n))
  r.done()
  return cameras


def read_images_bin(path: str) -> Tuple[List[Image], List[np.ndarray]]:
  """Images in file order and, per image, the point3D ids of its keypoints (-1: none)."""
  r = _Reader(path)
  images, point_ids = [], []
  for _ in range(r.read("Q")[0]):
    values = r.read("I7dI")
    name = r.string()
    n = r.read("Q")[0]
    points2d = r.array(np.dtype([("x", "<f8"), ("y", "<f8"), ("id", "<i8")]), n)
    images.append(Image(int(values[0]), tuple(values[1:5]), tuple(values[5:8]), int(values[8]),
                        name))
    point_ids.append(points2d["id"])
  r.done()
  return images, point_ids


def read_points_bin(path: str) -> Tuple[np.ndarray, List[np.ndarray]]:
  r = _Reader(path)
  count = r.read("Q")[0]
  xyz, tracks = [], []
  for _ in range(count):
    values = r.read("Q3d3BdQ")
    xyz.append(values[1:4])
    track = r.array(np.dtype([("image", "<i4"), ("point2d", "<i4")]), values[8])
    tracks.append(track["image"].astype(np.int64))
  r.done()
  return np.asarray(xyz, np.float64).reshape(-1, 3), tracks


# ----------------------------------------------------------------------------- text


def _text_lines(path: str) -> List[Tuple[int, List[str]]]:
  """(line number, fields) of the non-comment lines; keeps empty lines of images.txt, whose
  second line per image may be empty (the last image's too: COLMAP ends such a file with
  an empty line)."""
  try:
    with open(path, encoding="utf-8") as f:
      lines = f.read().splitlines()
  except UnicodeDecodeError:
    raise UserError(f"{path}: not a text file") from None
  return [(n + 1, line.split()) for n, line in enumerate(lines) if not line.startswith("#")]


def _numbers(path: str, line: int, fields: List[str], kind=float) -> List:
  try:
    values = [kind(x) for x in fields]
  except ValueError:
    raise UserError(f"{path}: line {line}: expected numbers, got {' '.join(fields)!r}") from None
  if kind is int and not all(-2 ** 63 <= v < 2 ** 63 for v in values):
    raise UserError(f"{path}: line {line}: a number out of range in {' '.join(fields)!r}")
  return values


def read_cameras_txt(path: str) -> Dict[int, Camera]:
  cameras = {}
  for line, fields in _text_lines(path):
    if not fields:
      continue
    if len(fields) < 4:
      raise UserError(f"{path}: line {line}: expected CAMERA_ID MODEL WIDTH HEIGHT PARAMS...")
    model = fields[1]
    if model not in MODEL_IDS:
      raise UserError(f"{path}: line {line}: unknown camera model {model!r}")
    n = MODEL_IDS[model][1]
    if len(fields) != 4 + n:
      raise UserError(f"{path}: line {line}: {model} has {n} parameters, got {len(fields) - 4}")
    camera_id, width, height = _numbers(path, line, [fields[0], fields[2], fields[3]], int)
    cameras[camera_id] = Camera(model, width, height, tuple(_numbers(path, line, fields[4:])))
  return cameras


def read_images_txt(path: str) -> Tuple[List[Image], List[np.ndarray]]:
  lines = _text_lines(path)
  images, point_ids = [], []
  k = 0
  while k < len(lines):
    line, fields = lines[k]
    if not fields:
      k += 1
      continue
    if len(fields) < 10:
      raise UserError(f"{path}: line {line}: expected IMAGE_ID QW QX QY QZ TX TY TZ CAMERA_ID "
                      "NAME")
    values = _numbers(path, line, fields[1:8])
    image_id, camera_id = _numbers(path, line, [fields[0], fields[8]], int)
    images.append(Image(image_id, tuple(values[:4]), tuple(values[4:7]), camera_id,
                        " ".join(fields[9:])))
    points = lines[k + 1][1] if k + 1 < len(lines) else None
    if points is None:
      raise UserError(f"{path}: truncated (image {image_id} has no keypoint line)")
    if len(points) % 3:
      raise UserError(f"{path}: line {lines[k + 1][0]}: keypoints come as X Y POINT3D_ID")
    point_ids.append(np.asarray(_numbers(path, lines[k + 1][0], points[2::3], int), np.int64))
    k += 2
  return images, point_ids


def read_points_txt(path: str) -> Tuple[np.ndarray, List[np.ndarray]]:
  xyz, tracks = [], []
  for line, fields in _text_lines(path):
    if not fields:
      continue
    if len(fields) < 8 or (len(fields) - 8) % 2:
      raise UserError(f"{path}: line {line}: expected POINT3D_ID X Y Z R G B ERROR TRACK...")
    xyz.append(_numbers(path, line, fields[1:4]))
    tracks.append(np.asarray(_numbers(path, line, fields[8::2], int), np.int64))
  return np.asarray(xyz, np.float64).reshape(-1, 3), tracks


# ----------------------------------------------------------------------------- the model


def read_model(folder: str) -> Model:
  """The COLMAP model in `folder` (binary preferred over text when both are there)."""
  ext = "bin" if os.path.isfile(os.path.join(folder, "cameras.bin")) else "txt"
  paths = {name: os.path.join(folder, f"{name}.{ext}") for name in ("cameras", "images",
                                                                      "points3D")}
  for name in ("cameras", "images"):
    if not os.path.isfile(paths[name]):
      raise UserError(f"{paths[name]}: missing (a COLMAP model needs cameras and images)")
  binary = ext == "bin"
  cameras = (read_cameras_bin if binary else read_cameras_txt)(paths["cameras"])
  images, _ = (read_images_bin if binary else read_images_txt)(paths["images"])
  if not images:
    raise UserError(f"{paths['images']}: no registered images")
  for image in images:
    if image.camera_id not in cameras:
      raise UserError(f"{paths['images']}: image {image.name} names camera {image.camera_id}, "
                      f"which {paths['cameras']} does not have")
  points = tracks = None
  if os.path.isfile(paths["points3D"]):
    points, tracks = (read_points_bin if binary else read_points_txt)(paths["points3D"])
    ids = {image.id for image in images}
    for track in tracks:
      missing = set(track.tolist()) - ids
      if missing:
        raise UserError(f"{paths['points3D']}: a point is seen by image {min(missing)}, which "
                        f"{paths['images']} does not have")
  return Model(folder, cameras, images, points, tracks)


def camera_intrinsics(camera: Camera, source: str) -> Tuple[float, float, float, float,
                                                            np.ndarray]:
  """(fx, fy, cx, cy, distortion [5]) of a COLMAP camera, in COLMAP's pixel convention."""
  p = camera.params
  if not np.all(np.isfinite(p)):
    raise UserError(f"{source}: camera parameters {p} must be finite")
  coeffs = np.zeros(5)
  if camera.model == "SIMPLE_PINHOLE":
    fx = fy = p[0]
    cx, cy = p[1], p[2]
  elif camera.model == "PINHOLE":
    fx, fy, cx, cy = p
  elif camera.model in ("SIMPLE_RADIAL", "RADIAL"):
    fx = fy = p[0]
    cx, cy = p[1], p[2]
    coeffs[0] = p[3]
    if camera.model == "RADIAL":
      coeffs[1] = p[4]
  elif camera.model in ("OPENCV", "FULL_OPENCV"):
    fx, fy, cx, cy = p[:4]
    coeffs[:4] = p[4:8]
    if camera.model == "FULL_OPENCV":
      coeffs[4] = p[8]
      if any(p[9:12]):
        raise UserError(f"{source}: FULL_OPENCV camera with rational coefficients k4-k6 is "
                        "not supported (supported: k1, k2, p1, p2, k3)")
  else:
    raise UserError(f"{source}: camera model {camera.model} is not supported (supported: "
                    f"{', '.join(SUPPORTED)}); undistort the images with `colmap "
                    "image_undistorter` first")
  if not all(np.isfinite([fx, fy, cx, cy])) or fx <= 0 or fy <= 0:
    raise UserError(f"{source}: camera with focal length {fx}, {fy}: must be positive")
  return fx, fy, cx, cy, coeffs


def qvec_to_rotation(qvec) -> np.ndarray:
  """Rotation matrix [3, 3] of a unit quaternion (w, x, y, z)."""
  w, x, y, z = np.asarray(qvec, np.float64) / np.linalg.norm(qvec)
  return np.array([
      [1 - 2 * y * y - 2 * z * z, 2 * x * y - 2 * w * z, 2 * x * z + 2 * w * y],
      [2 * x * y + 2 * w * z, 1 - 2 * x * x - 2 * z * z, 2 * y * z - 2 * w * x],
      [2 * x * z - 2 * w * y, 2 * y * z + 2 * w * x, 1 - 2 * x * x - 2 * y * y]])


def opengl_c2w(image: Image) -> np.ndarray:
  """Camera-to-world [3, 4] (OpenGL axes: x right, y up, z back) of a COLMAP image."""
  R = qvec_to_rotation(image.qvec)
  t = np.asarray(image.tvec, np.float64)
  c2w = np.concatenate([R.T, (-R.T @ t)[:, None]], 1)
  return c2w * np.array([1.0, -1.0, -1.0, 1.0])  # OpenCV camera axes -> OpenGL


def depth_bounds(model: Model, c2w: np.ndarray, order: List[int]) -> Optional[np.ndarray]:
  """Per image [N, 2] near and far depths of the sparse points it sees, as LLFF's
  imgs2poses computes them (0.1 and 99.9 percentiles of the points' camera depths), for the
  images model.images[order]; None without points.

  Raises:
    UserError when an image sees no point.
  """
  if model.points is None or not len(model.points):
    return None
  index = {image.id: n for n, image in enumerate(model.images)}
  visible = [[] for _ in model.images]
  for k, track in enumerate(model.tracks):
    for image_id in set(track.tolist()):
      visible[index[image_id]].append(k)
  bounds = []
  for n, pose in zip(order, c2w):
    if not visible[n]:
      raise UserError(f"{model.path}: image {model.images[n].name} sees no sparse point, so "
                      "its depth range is unknown")
    depth = (model.points[visible[n]] - pose[:, 3]) @ -pose[:, 2]  # along the view axis
    bounds.append([np.percentile(depth, 0.1), np.percentile(depth, 99.9)])
  return np.asarray(bounds)
