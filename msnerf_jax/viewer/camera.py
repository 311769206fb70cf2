"""The browser's camera and the library's: viser reports a pose T_world_camera in OpenCV axes
(x right, y down, +z forward), a vertical field of view in radians and the viewport's size;
the library's cameras are OpenGL c2w (x right, y up, -z forward) with intrinsics K.

Frames are rendered at a pixel budget, not at the viewport's size: the full level has as many
pixels as the scene's training images (a 100x100 lego run renders 10,000 rays per frame,
whatever the window), shaped to the viewport's aspect ratio.
"""

import math
from typing import Any, Dict, Tuple

import numpy as np
import viser.transforms as tf

from msnerf_jax.nerf import cameras as cameras_lib
from msnerf_jax.data.camera_path import camera_path_dict
from msnerf_jax.data.scene import Scene

# OpenCV camera axes = OpenGL's with y and z flipped.
_FLIP_YZ = np.diag([1.0, -1.0, -1.0])
# The look-at distance of forward-facing scenes (LLFF recentring puts the content 1-4 units
# in front of the cameras).
FORWARD_FACING_FOCUS = 3.0


def frame_size(aspect: float, pixels: int) -> Tuple[int, int]:
  """(height, width) of about `pixels` pixels with width / height = aspect (both >= 1)."""
  aspect = float(aspect) if math.isfinite(aspect) and aspect > 0 else 1.0
  aspect = min(max(aspect, 0.1), 10.0)
  height = max(1, round(math.sqrt(pixels / aspect)))
  return height, max(1, round(height * aspect))


def to_camera(wxyz, position, fov: float, height: int, width: int) -> cameras_lib.Camera:
  """The library camera of a viser pose (OpenCV wxyz [4], position [3]) and vertical field of
  view `fov` (radians), rendered at height x width with square pixels."""
  R = tf.SO3(np.asarray(wxyz, np.float64)).as_matrix() @ _FLIP_YZ
  c2w = np.concatenate([R, np.asarray(position, np.float64)[:, None]], 1).astype(np.float32)
  focal = 0.5 * height / math.tan(0.5 * float(fov))
  K = cameras_lib.centre_origin_K(focal, focal, width / 2, height / 2)
  return cameras_lib.Camera(c2w, K, int(height), int(width))


def to_viser_pose(c2w: np.ndarray) -> Tuple[np.ndarray, np.ndarray]:
  """(wxyz [4], position [3]) in viser's OpenCV convention of an OpenGL c2w [3, 4]."""
  c2w = np.asarray(c2w, np.float64)
  return tf.SO3.from_matrix(c2w[:3, :3] @ _FLIP_YZ).wxyz, c2w[:3, 3].copy()


def vertical_fov(K: np.ndarray, height: int) -> float:
  """The vertical field of view (radians) of intrinsics K [3, 3] for images `height` tall."""
  return 2.0 * math.atan(0.5 * height / float(K[1, 1]))


def scene_up(scene: Scene) -> np.ndarray:
  """The world's up [3]: the training cameras' mean up vector, normalised."""
  up = scene.c2w[:, :3, 1].astype(np.float64).sum(0)
  return up / max(np.linalg.norm(up), 1e-12)


def look_at_point(scene: Scene, c2w: np.ndarray) -> np.ndarray:
  """What a camera c2w [3, 4] orbits around: the point of its optical axis closest to the
  world origin (object scenes are centred there), or FORWARD_FACING_FOCUS in front of it
  (forward-facing scenes, whose origin is among the cameras)."""
  position = c2w[:3, 3].astype(np.float64)
  forward = -c2w[:3, 2].astype(np.float64)
  forward /= max(np.linalg.norm(forward), 1e-12)
  depth = FORWARD_FACING_FOCUS if scene.ndc else max(float(-position @ forward), 0.1)
  return position + depth * forward


def nearest_view(scene: Scene, position, wxyz) -> int:
  """The training view closest to a viser camera: smallest distance plus scene-scaled angle
  between the view directions."""
  views = scene.splits.get("train", np.arange(len(scene.c2w)))
  c2w = scene.c2w[views].astype(np.float64)
  forward = tf.SO3(np.asarray(wxyz, np.float64)).as_matrix()[:, 2]
  distance = np.linalg.norm(c2w[:, :3, 3] - np.asarray(position, np.float64), axis=1)
  angle = np.arccos(np.clip(np.einsum("ni,i->n", -c2w[:, :3, 2], forward)
                            / np.linalg.norm(c2w[:, :3, 2], axis=1), -1.0, 1.0))
  scale = np.median(np.linalg.norm(c2w[:, :3, 3] - c2w[:, :3, 3].mean(0), axis=1)) + 1e-6
  return int(views[np.argmin(distance + scale * angle)])


def keyframes_dict(cameras) -> Dict[str, Any]:
  """camera_path.json of cameras (cameras.Camera, each with its own field of view), sized as
  the last one."""
  last = cameras[-1]
  # The format keeps a vertical field of view: focal lengths in the last camera's pixels.
  Ks = np.stack([c.K * (last.height / c.height) for c in cameras])
  return camera_path_dict([c.c2w for c in cameras], Ks, last.height, last.width)
