"""Users' own captures (nerfstudio / instant-ngp transforms.json, COLMAP models) as Scenes.

Every capture goes through the same steps:
  1. the reader gives each image's camera-to-world pose (OpenGL axes), intrinsics in
     COLMAP's pixel convention, lens distortion, and (COLMAP) the sparse points;
  2. the images are loaded at `--downscale` (from images_{factor}/ folders next to the full
     ones when present, otherwise box-downscaled on load) and the intrinsics scaled with
     them; rays are undistorted per view (msnerf_jax.nerf.cameras), the photos used as taken;
  3. the layout is decided and the scene normalised (`normalise`):
       forward-facing (every camera looks within 40 degrees of the mean view direction):
         LLFF's recentring and bounds scaling, NDC rays, the spiral path (depth bounds from
         the sparse points, as LLFF's imgs2poses computes them, or from the point the
         cameras look at);
       object (cameras around something): centred on the point closest to every optical
         axis, rotated so the cameras' mean up is +z, scaled so the median camera distance
         is 4; near/far from the camera distances (2 and 6 at distance 4, as Blender scenes
         have); as render path an orbit at the cameras' mean elevation, or, when the
         cameras' azimuths leave a gap wider than 60 degrees, the arc they cover and back.
     The layout is printed and recorded in run.json (DataConfig.layout);
  4. views are sorted by image name; the file's split (nerfstudio's `train_filenames`,
     `val_filenames`, `test_filenames`) is used, or every `llff_holdout`-th view is held out
     for val/test.
"""

import dataclasses
import os
from typing import Any, Dict, List, Optional, Tuple

import numpy as np

from msnerf_jax.nerf import cameras as cameras_lib
from msnerf_jax.core.config import DataConfig
from msnerf_jax.data import colmap, llff
from msnerf_jax.data import images as images_lib
from msnerf_jax.data import transforms as transforms_lib
from msnerf_jax.data.scene import Scene, check_poses
from msnerf_jax.core.errors import UserError
from msnerf_jax.core.progress import progress_bar

LAYOUTS = ("forward-facing", "object")
FORWARD_FACING_DEGREES = 40.0
OBJECT_DISTANCE = 4.0  # median camera distance of object captures (Blender's radius)
MAX_AUTO_SIDE = 400  # --downscale 0: the smallest power of two bringing the longer side here
PATH_FRAMES = 40
ORBIT_GAP_DEGREES = 60.0  # a wider gap between cameras' azimuths: the path covers the arc


@dataclasses.dataclass(frozen=True)
class Capture:
  """What a reader gives, per view n (sorted by image name): paths [N] (full-size images);
  c2w [N, 3, 4] float64 OpenGL camera-to-world; cameras [N] {"fx", "fy", "cx", "cy", "w",
  "h", "coeffs"} in COLMAP's pixel convention at full size; bounds [N, 2] near/far depths
  or None; splits: the file's own split (nerfstudio's train/val/test_filenames) or None;
  source: the file named in messages."""
  source: str
  paths: List[str]
  c2w: np.ndarray
  cameras: List[Dict[str, Any]]
  bounds: Optional[np.ndarray] = None
  splits: Optional[Dict[str, np.ndarray]] = None


# ----------------------------------------------------------------------------- readers


def read_transforms_capture(path: str) -> Capture:
  data = transforms_lib.read_transforms(path)
  cameras = [transforms_lib.frame_camera(data["meta"], f["frame"], f["where"],
                                         _image_size(f["path"])
                                         if not {"w", "h"} <= set(data["meta"]) | set(f["frame"])
                                         else None)
             for f in data["frames"]]
  paths = [f["path"] for f in data["frames"]]
  return Capture(data["source"], paths, np.stack([f["c2w"] for f in data["frames"]]), cameras,
                 splits=transforms_lib.named_splits(data["meta"], path, paths, data["source"]))


def read_colmap_capture(path: str) -> Capture:
  folder = colmap.find_model(path)
  if folder is None:
    raise UserError(f"{path}: no COLMAP model (sparse/0/cameras.bin or .txt)")
  model = colmap.read_model(folder)
  image_dir = os.path.join(path, "images")
  order = sorted(range(len(model.images)), key=lambda n: model.images[n].name)
  registered = {image.name for image in model.images}
  if os.path.isdir(image_dir):
    for name in sorted(os.listdir(image_dir)):
      if name.lower().endswith(images_lib.IMAGE_EXTENSIONS) and name not in registered:
        raise UserError(f"{os.path.join(image_dir, name)}: not registered in the COLMAP model "
                        f"{folder} (COLMAP found no pose for it): remove it from images/ or "
                        "re-run COLMAP's mapper")
  paths, cameras = [], []
  for n in order:
    image = model.images[n]
    file = os.path.join(image_dir, image.name)
    if not os.path.isfile(file):
      raise UserError(f"{file}: missing (named by {folder})")
    camera = model.cameras[image.camera_id]
    fx, fy, cx, cy, coeffs = colmap.camera_intrinsics(
        camera, f"{folder}: camera {image.camera_id}")
    paths.append(file)
    cameras.append({"fx": fx, "fy": fy, "cx": cx, "cy": cy, "w": float(camera.width),
                    "h": float(camera.height), "coeffs": coeffs})
  c2w = np.stack([colmap.opengl_c2w(model.images[n]) for n in order])
  return Capture(folder, paths, c2w, cameras, colmap.depth_bounds(model, c2w, order))


def _image_size(path: str) -> Tuple[int, int]:
  from PIL import Image  # pylint: disable=g-import-not-at-top
  try:
    with Image.open(path) as image:
      return image.size
  except Exception as e:  # pylint: disable=broad-except
    raise UserError(f"{path}: not a readable image ({e})") from None


# ----------------------------------------------------------------------------- images


def auto_downscale(width: float, height: float) -> int:
  factor = 1
  while max(width, height) / factor > MAX_AUTO_SIDE:
    factor *= 2
  return factor


def _downscaled_file(path: str, factor: int) -> Optional[str]:
  """folder_{factor}/name next to folder/name (nerfstudio's and LLFF's images_4 ...)."""
  folder, name = os.path.split(path)
  candidate = os.path.join(f"{folder}_{factor}", name)
  return candidate if factor > 1 and os.path.isfile(candidate) else None


def load_images(capture: Capture, factor: int) -> Tuple[np.ndarray, np.ndarray, List[str]]:
  """The views at 1/factor: images [N, H, W, 3], K [N, 3, 3] (library pixel grid) and the
  files read."""
  images, Ks, files = [], [], []
  for path, camera in zip(progress_bar(capture.paths, desc="loading images", leave=False,
                                       disable=None), capture.cameras):
    small = _downscaled_file(path, factor)
    image = images_lib.read_image(small or path, reduce=1 if small else factor)
    h, w = image.shape[:2]
    if small:  # a resized copy: scale by its actual size
      sx, sy = w / camera["w"], h / camera["h"]
    else:  # box averaging maps pixel corners by exactly 1/factor
      sx = sy = 1.0 / factor
      full = _image_size(path)
      if abs(full[0] - camera["w"]) > 0.5 or abs(full[1] - camera["h"]) > 0.5:
        raise UserError(f"{path}: image is {full[0]}x{full[1]}, but its camera in "
                        f"{capture.source} is {camera['w']:g}x{camera['h']:g}")
    images.append(image)
    K = cameras_lib.centre_origin_K(camera["fx"], camera["fy"], camera["cx"], camera["cy"],
                                    sx, sy)
    if not np.all(np.isfinite(K)) or K[0, 0] <= 0 or K[1, 1] <= 0:
      raise UserError(f"{capture.source}: the camera of {path} has intrinsics out of range "
                      f"(fx {camera['fx']:g}, fy {camera['fy']:g}, cx {camera['cx']:g}, "
                      f"cy {camera['cy']:g})")
    Ks.append(K)
    files.append(small or path)
  return images_lib.stack_same_size(images, files), np.stack(Ks), files


# ----------------------------------------------------------------------------- layout


def view_spread_degrees(c2w: np.ndarray) -> float:
  """The largest angle between a camera's view direction and the mean view direction."""
  forward = -c2w[:, :3, 2]
  forward = forward / np.linalg.norm(forward, axis=1, keepdims=True)
  mean = forward.sum(0)
  mean = mean / max(np.linalg.norm(mean), 1e-12)
  return float(np.degrees(np.arccos(np.clip(forward @ mean, -1.0, 1.0)).max()))


def focus_point(c2w: np.ndarray) -> np.ndarray:
  """The point [3] closest (least squares) to every camera's optical axis."""
  A, b = np.zeros((3, 3)), np.zeros(3)
  for pose in c2w:
    d = -pose[:3, 2] / np.linalg.norm(pose[:3, 2])
    P = np.eye(3) - np.outer(d, d)
    A += P
    b += P @ pose[:3, 3]
  return np.linalg.lstsq(A, b, rcond=None)[0]


def rotation_to_z(up: np.ndarray) -> np.ndarray:
  """Rotation [3, 3] taking the unit vector `up` to +z (Rodrigues)."""
  z = np.array([0.0, 0.0, 1.0])
  v, c = np.cross(up, z), float(up @ z)
  if np.linalg.norm(v) < 1e-9:
    return np.eye(3) if c > 0 else np.diag([1.0, -1.0, -1.0])
  vx = np.array([[0, -v[2], v[1]], [v[2], 0, -v[0]], [-v[1], v[0], 0]])
  return np.eye(3) + vx + vx @ vx / (1.0 + c)


def normalise(c2w: np.ndarray, bounds: Optional[np.ndarray], layout: str,
              source: str = "the capture"):
  """(poses [N, 3, 4], near, far, ndc, render path [P, 3, 4], description) of a capture in
  the given layout ("forward-facing" or "object"); see the module docstring. UserError
  naming `source` when its cameras cannot be normalised (all at one place, or so far apart
  that the numbers overflow)."""
  with np.errstate(all="ignore"):
    out = _normalise(c2w, bounds, layout, source)
  poses, near, far, _, path, _ = out
  if not (np.all(np.isfinite(poses.astype(np.float32))) and np.all(np.isfinite(
      path.astype(np.float32))) and 0 < near < far < np.finfo(np.float32).max):
    raise UserError(f"{source}: the cameras cannot be normalised as {layout} (no distinct "
                    "positions, or positions and depths out of range)")
  return out


def _normalise(c2w, bounds, layout, source):
  if layout == "forward-facing":
    if bounds is None:  # no sparse points: the depths of the point the cameras look at
      depth = np.abs(np.einsum("ni,ni->n", focus_point(c2w) - c2w[:, :3, 3], -c2w[:, :3, 2]))
      bounds = np.stack([0.5 * depth, 4.0 * depth], 1)
    poses, bounds, path = llff.forward_facing(c2w, bounds, source=source)
    near, far = float(bounds.min() * 0.9), float(bounds.max())
    return poses, near, far, True, path, "forward-facing: LLFF recentring, NDC rays"
  centre = focus_point(c2w)
  R = rotation_to_z(_unit(c2w[:, :3, 1].sum(0)))
  poses = np.concatenate([R @ c2w[:, :3, :3], (R @ (c2w[:, :3, 3] - centre).T).T[..., None]], 2)
  distance = np.linalg.norm(poses[:, :3, 3], axis=1)
  scale = OBJECT_DISTANCE / np.median(distance)
  poses[:, :3, 3] *= scale
  distance = distance * scale
  near, far = float(distance.min() / 2), float(distance.max() * 1.5)
  elevation = np.arcsin(np.clip(poses[:, 2, 3] / distance, -1, 1)).mean()
  start, arc = covered_arc(np.arctan2(poses[:, 1, 3], poses[:, 0, 3]))
  if arc >= 2 * np.pi:  # the cameras surround it: a full orbit
    azimuths = start + np.linspace(0, 2 * np.pi, PATH_FRAMES + 1)[:-1]
  else:  # a partial arc: along what the cameras saw, and back
    half = np.linspace(0, arc, PATH_FRAMES // 2 + 1)
    azimuths = start + np.concatenate([half, half[-2:0:-1]])
  path = np.stack([orbit_camera(a, elevation, OBJECT_DISTANCE) for a in azimuths])
  return (poses, near, far, False, path,
          f"object: centred on the cameras' focus, bounds {near:.2f}-{far:.2f}, "
          + ("orbit" if arc >= 2 * np.pi else f"{np.degrees(arc):.0f}-degree arc")
          + f" at {np.degrees(elevation):.0f} degrees elevation")


def covered_arc(azimuths: np.ndarray) -> Tuple[float, float]:
  """(start, length) in radians of the arc of azimuths [N] the cameras cover: the circle
  minus its largest gap; length 2 pi when no gap is wider than ORBIT_GAP_DEGREES."""
  a = np.sort(np.mod(azimuths, 2 * np.pi))
  gaps = np.diff(np.concatenate([a, [a[0] + 2 * np.pi]]))
  k = int(np.argmax(gaps))
  if gaps[k] <= np.radians(ORBIT_GAP_DEGREES):
    return float(a[0]), 2 * np.pi
  start = a[(k + 1) % len(a)]
  return float(start), float(2 * np.pi - gaps[k])


def orbit_camera(azimuth: float, elevation: float, radius: float) -> np.ndarray:
  """OpenGL camera-to-world [3, 4] on a sphere around the origin (z up), looking at it."""
  back = np.array([np.cos(elevation) * np.cos(azimuth), np.cos(elevation) * np.sin(azimuth),
                   np.sin(elevation)])
  return llff.view_matrix(back, np.array([0.0, 0.0, 1.0]), radius * back)


def _unit(v: np.ndarray) -> np.ndarray:
  return v / max(np.linalg.norm(v), 1e-12)


# ----------------------------------------------------------------------------- the scene


def load_capture(config: DataConfig, fmt: str) -> Tuple[Scene, DataConfig]:
  """A capture folder as a Scene; returns (scene, resolved config: format, downscale, layout)."""
  if config.layout not in ("auto",) + LAYOUTS:
    raise UserError(f"--layout {config.layout}: must be auto, {' or '.join(LAYOUTS)}")
  if config.downscale < 0:
    raise UserError(f"--downscale {config.downscale}: must be >= 1 (or 0 for automatic)")
  capture = (read_transforms_capture if fmt == "transforms" else read_colmap_capture)(config.path)
  names = [os.path.relpath(p, config.path) for p in capture.paths]
  check_poses(capture.c2w, capture.source, names, orthonormal=True)
  factor = config.downscale or auto_downscale(capture.cameras[0]["w"], capture.cameras[0]["h"])
  images, Ks, files = load_images(capture, factor)
  layout = config.layout
  if layout == "auto":
    layout = ("forward-facing" if view_spread_degrees(capture.c2w) < FORWARD_FACING_DEGREES
              else "object")
  poses, near, far, ndc, path, description = normalise(capture.c2w, capture.bounds, layout,
                                                       capture.source)
  with np.errstate(over="ignore"):
    coeffs = np.stack([c["coeffs"] for c in capture.cameras]).astype(np.float32)
  if not np.all(np.isfinite(coeffs)):
    raise UserError(f"{capture.source}: lens distortion coefficients out of range")
  scene = Scene(images=images, c2w=poses.astype(np.float32), K=Ks[0], near=near, far=far,
                ndc=ndc, white_background=False,
                splits=capture.splits or llff.holdout_splits(len(images), config.llff_holdout),
                render_poses=path.astype(np.float32), format=fmt, image_paths=tuple(files),
                Ks=None if np.all(Ks == Ks[0]) else Ks,
                distortion=None if cameras_lib.is_pinhole(coeffs) else coeffs,
                layout=description)
  return scene, dataclasses.replace(config, format=fmt, downscale=factor, layout=layout)
