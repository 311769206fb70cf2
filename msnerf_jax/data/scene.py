"""The Scene: posed images, intrinsics, bounds, splits and a render path; format auto-detection."""

import dataclasses
import os
from typing import Any, Dict, List, Optional, Tuple

import jax.numpy as jnp
import numpy as np

from msnerf_jax.nerf import cameras as cameras_lib
from msnerf_jax.nerf import rays as rays_lib
from msnerf_jax.core.config import DataConfig
from msnerf_jax.core.errors import UserError


@dataclasses.dataclass(frozen=True, eq=False)
class Scene:
  """A loaded scene. Arrays are numpy on the host.

  images: [N, H, W, 3] float32 in [0, 1]; c2w: [N, 3, 4] camera-to-world (OpenGL axes);
  K: [3, 3] the render camera's intrinsics (the first view's; render paths use it);
  splits: name -> indices into images; render_poses: [P, 3, 4] a camera path;
  alphas: [N, H, W] uint8 opacity of RGBA images (Blender), None when the photos have none;
  Ks: [N, 3, 3] per-view intrinsics when views differ (None: every view has K);
  distortion: [N, 5] per-view lens distortion (msnerf_jax.nerf.cameras; None: pinholes);
  layout: how the scene was normalised (captures), printed by the CLI.
  """
  images: np.ndarray
  c2w: np.ndarray
  K: np.ndarray
  near: float
  far: float
  ndc: bool
  white_background: bool
  splits: Dict[str, np.ndarray]
  render_poses: np.ndarray
  format: str
  image_paths: Tuple[str, ...]
  alphas: Optional[np.ndarray] = None
  Ks: Optional[np.ndarray] = None
  distortion: Optional[np.ndarray] = None
  layout: str = ""

  @property
  def height(self) -> int:
    return int(self.images.shape[1])

  @property
  def width(self) -> int:
    return int(self.images.shape[2])

  @property
  def focal(self) -> float:
    return float(self.K[0, 0])

  def split(self, name: str) -> np.ndarray:
    if name not in self.splits or len(self.splits[name]) == 0:
      raise UserError(f"scene has no {name!r} split (has: {', '.join(sorted(self.splits))})")
    return self.splits[name]

  def path_poses(self, frames: int = 0) -> np.ndarray:
    """The render path resampled to `frames` evenly spaced cameras [frames, 3, 4] (0 = all)."""
    return self.render_poses[spaced_indices(len(self.render_poses), frames)]

  @property
  def intrinsics(self) -> np.ndarray:
    """Per-view intrinsics [N, 3, 3]."""
    if self.Ks is not None:
      return self.Ks
    return np.broadcast_to(self.K, (len(self.images), 3, 3))

  def view_camera(self, view: int) -> Tuple[np.ndarray, Optional[np.ndarray]]:
    """(K [3, 3], distortion [5] or None) of dataset view `view`."""
    coeffs = None if self.distortion is None else self.distortion[view]
    return self.intrinsics[view], coeffs

  def cameras_of(self, views: np.ndarray) -> Tuple[np.ndarray, Optional[np.ndarray]]:
    """(K, distortion) of views [n] as training batches take them: K [3, 3] when every view
    shares it, else [n, 3, 3]; distortion [n, 5] or None (pinholes)."""
    K = self.K if self.Ks is None else self.Ks[views]
    return K, None if self.distortion is None else self.distortion[views]

  def camera_parts(self, camera) -> Tuple[np.ndarray, np.ndarray, Optional[np.ndarray], int, int]:
    """(K [3, 3], c2w [3, 4], distortion [5] or None, height, width) of one camera.

    camera: an int, dataset view `camera` with its own pose, intrinsics and distortion; a
    c2w [3, 4] (a render path's camera), seen with the render camera K; or a
    cameras.Camera (a camera path file's, any size and intrinsics).
    """
    if isinstance(camera, cameras_lib.Camera):
      return camera.K, camera.c2w, camera.coeffs, camera.height, camera.width
    if isinstance(camera, (int, np.integer)):
      K, coeffs = self.view_camera(int(camera))
      return K, self.c2w[camera], coeffs, self.height, self.width
    return self.K, np.asarray(camera), None, self.height, self.width

  def camera_rays(self, camera) -> Dict[str, jnp.ndarray]:
    """ray_bundle for every pixel of one camera (see camera_parts): [H, W, ...]."""
    K, c2w, coeffs, height, width = self.camera_parts(camera)
    return self.bundle(*rays_lib.get_rays(height, width, K, c2w, coeffs))

  def rays_at(self, camera, rows, cols) -> Dict[str, jnp.ndarray]:
    """ray_bundle of one camera (see camera_parts) through the (sub)pixel positions rows,
    cols [...] (pixel centres at integers): [..., ...]."""
    K, c2w, coeffs, _, _ = self.camera_parts(camera)
    rows = jnp.asarray(rows, jnp.float32)
    c2w = jnp.broadcast_to(jnp.asarray(c2w, jnp.float32)[:3, :4], (*rows.shape, 3, 4))
    coeffs = None if coeffs is None else jnp.broadcast_to(jnp.asarray(coeffs), (*rows.shape, 5))
    return self.bundle(*rays_lib.pixel_rays(jnp.asarray(K, jnp.float32), c2w, rows,
                                            jnp.asarray(cols, jnp.float32), coeffs))

  def bundle(self, origins, directions) -> Dict[str, jnp.ndarray]:
    """ray_bundle with this scene's bounds and NDC setting."""
    return rays_lib.ray_bundle(origins, directions, self.near, self.far, self.ndc,
                               self.height, self.width, self.focal)


def spaced_indices(count: int, frames: int) -> np.ndarray:
  """`frames` evenly spaced indices into `count` items, first and last included (0 = all)."""
  if frames <= 0:
    return np.arange(count)
  return np.linspace(0, count - 1, frames).round().astype(int)


# DataConfig keys that run.json files and stylized manifests of earlier versions may hold,
# with the only value they could have had (anything else never loaded a scene).
LEGACY_DATA_KEYS = {"llff_spherify": False}


def drop_legacy_data_keys(values: Dict[str, Any], source: str) -> Dict[str, Any]:
  """Removes LEGACY_DATA_KEYS from a saved DataConfig dict (in place; also returned).

  Raises:
    UserError naming `source` when a legacy key holds a value no version could load.
  """
  for key, value in LEGACY_DATA_KEYS.items():
    if key in values:
      if values[key] != value:
        raise UserError(f"{source}: {key} {values[key]!r} is not supported")
      del values[key]
  return values


def detect_format(path: str) -> str:
  """"blender" if transforms_*.json exist, "transforms" if transforms.json does (nerfstudio,
  instant-ngp), "llff" if poses_bounds.npy does, "colmap" if a sparse/0 model does."""
  if not os.path.exists(path):
    raise UserError(f"{path}: no such scene folder")
  if not os.path.isdir(path):
    raise UserError(f"{path}: not a folder")
  names = os.listdir(path)
  if any(n.startswith("transforms_") and n.endswith(".json") for n in names):
    return "blender"
  if "transforms.json" in names:
    return "transforms"
  if "poses_bounds.npy" in names:
    return "llff"
  from msnerf_jax.data import colmap  # pylint: disable=g-import-not-at-top
  if colmap.find_model(path) is not None:
    return "colmap"
  raise UserError(f"{path}: not a scene folder (no transforms_*.json, transforms.json, "
                  "poses_bounds.npy or COLMAP sparse/0 model)")


def load_scene(config: DataConfig) -> Tuple[Scene, DataConfig]:
  """Loads the scene a DataConfig names.

  Returns:
    (scene, resolved config): the config has the detected format and the actual downscale.
  """
  # pylint: disable=g-import-not-at-top
  from msnerf_jax.data import blender, captures, llff
  fmt = detect_format(config.path) if config.format == "auto" else config.format
  if fmt in ("transforms", "colmap"):
    return captures.load_capture(config, fmt)
  if config.layout != "auto":
    raise UserError(f"--layout {config.layout}: only for captures (transforms.json, COLMAP); "
                    f"{fmt} scenes have their paper's layout")
  if fmt == "blender":
    downscale = config.downscale or 1
    scene = blender.load_blender(config.path, downscale)
  elif fmt == "llff":
    downscale = config.downscale or 8
    scene = llff.load_llff(config.path, downscale, config.llff_holdout)
  else:
    raise UserError(f"--format {fmt}: unknown scene format (blender, llff, transforms or "
                    "colmap)")
  return scene, dataclasses.replace(config, format=fmt, downscale=downscale)


def check_poses(poses: np.ndarray, source: str, names: List[str],
                orthonormal: bool = False) -> None:
  """Rejects non-finite or singular camera rotations, naming the first bad view; with
  `orthonormal`, also rotations that are not orthonormal to 1e-3 (captures' poses are
  rigid; Blender's and LLFF's reference files are trusted as the reference code does)."""
  for pose, name in zip(poses, names):
    if not np.all(np.isfinite(pose)):
      raise UserError(f"{source}: camera of {name} has NaN or inf entries")
    if abs(np.linalg.det(pose[:3, :3])) < 1e-6:
      raise UserError(f"{source}: camera of {name} has a singular rotation matrix")
    if orthonormal:
      error = np.abs(pose[:3, :3].T @ pose[:3, :3] - np.eye(3)).max()
      if error > 1e-3:
        raise UserError(f"{source}: camera of {name} has a rotation that is not orthonormal "
                        f"(|R^T R - I| = {error:.3g})")
