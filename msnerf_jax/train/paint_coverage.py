"""Where a painting's colours reach: the grid vertices that a render along the scene's
camera path sees (they are painted even where no training view looks: the path may go
there), how much each painted vertex weighs in the training views (the ones that weigh
nothing get no gradient from any view), and, for those, the seen vertex they take their
colour from (the nearest: a gather map the trainer applies after every step, so a painting
has no grey holes where the path looks).

Density alone does not say where to paint: a NeRF of a capture that photographs one side of
an object fills the box with thin fog (on the cup capture 94% of a 128^3 grid stops 1% of
the light over a vertex spacing), while a render sees only the first surfaces along its
rays; those are what the path's sample lists hold."""

from typing import Dict, Iterable, Iterator, Tuple

import numpy as np
from scipy import ndimage

from msnerf_jax.models.nerf import NerfField
from msnerf_jax.models.painted_field import corners
from msnerf_jax.nerf import sample_cache

PATH_VIEWS = 24  # cameras along the render path whose samples are painted.
SEEN_WEIGHT = 1e-3  # a vertex is seen when its summed weight in the training views is above.


def camera_samples(scene, nerf_run, cameras: Iterable, top_k: int, threshold: float
                   ) -> Iterator[Dict[str, np.ndarray]]:
  """The frozen NeRF's sample lists of each camera (a training view's index or a c2w) of the
  scene: sample_cache.view_samples, the samples of weight above `threshold`."""
  field = NerfField(nerf_run.config)
  for camera in cameras:
    yield sample_cache.view_samples(field, nerf_run.params, scene.camera_rays(camera),
                                    nerf_run.config, top_k, threshold)


def path_points(scene, nerf_run, top_k: int, threshold: float, views: int = PATH_VIEWS
                ) -> Iterator[np.ndarray]:
  """The points [P, 3] of each of `views` cameras spread along the scene's render path that
  carry weight above `threshold` in its render by the frozen NeRF (camera_samples, as the
  training views' cache keeps them)."""
  for samples in camera_samples(scene, nerf_run, scene.path_poses(views), top_k, threshold):
    yield samples["points"]


def view_spread(cache: Dict[str, np.ndarray], view: int, index: np.ndarray, bound: float
                ) -> Tuple[np.ndarray, np.ndarray, np.ndarray]:
  """How one cached view's samples spread over the painted vertices: (rows [S * 8] the
  vertices' rows, spread [S * 8] each sample's weight x trilinear weight, pixel [S * 8] the
  sample's pixel) for its S samples of weight > 0."""
  weights, points = cache["weights"][view], cache["points"][view]
  keep = weights > 0
  flat, tri = corners(points[keep].astype(np.float32), index.shape[0], bound, np)
  rows = index.reshape(-1)[flat].reshape(-1)
  spread = (weights[keep][:, None] * tri).reshape(-1)
  return rows, spread, np.repeat(cache["pixel"][view][keep], 8)


def seen_vertices(cache: Dict[str, np.ndarray], index: np.ndarray, count: int, bound: float
                  ) -> np.ndarray:
  """bool [V + 1]: the painted vertices whose summed weight in all the cached views is above
  SEEN_WEIGHT (row V, unpainted, never)."""
  total = np.zeros(count + 1)
  for view in range(len(cache["weights"])):
    rows, spread, _ = view_spread(cache, view, index, bound)
    total += np.bincount(rows, spread, count + 1)
  seen = total > SEEN_WEIGHT
  seen[-1] = False
  return seen


def nearest_seen(index: np.ndarray, seen: np.ndarray) -> np.ndarray:
  """int32 [V + 1]: for each painted vertex (rows of `index` [R, R, R]), itself when `seen`
  [V + 1], else the row of the nearest seen vertex (Euclidean, in grid steps); row V
  (unpainted) maps to itself, and so does everything when no vertex is seen."""
  source = np.arange(len(seen), dtype=np.int32)
  if not seen.any():
    return source
  rows = index.reshape(-1)
  grid_seen = (rows < len(seen) - 1) & seen[rows]
  nearest = ndimage.distance_transform_edt(~grid_seen.reshape(index.shape),
                                           return_distances=False, return_indices=True)
  nearest_rows = index[tuple(nearest)].reshape(-1)
  unseen = (rows < len(seen) - 1) & ~seen[rows]
  source[rows[unseen]] = nearest_rows[unseen]
  return source
