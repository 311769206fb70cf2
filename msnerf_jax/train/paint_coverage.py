"""Where a painting's colours reach: the cameras along the scene's render path that it is
painted from beside the training views (path_views: the path may look where no photo
does), how much each painted vertex weighs in those views (the ones that weigh nothing get
no gradient from any view), and, for those, the seen vertex they take their colour from
(the nearest: a gather map the trainer applies after every step, so a painting has no grey
holes).

Density alone does not say where to paint: a NeRF of a capture that photographs one side of
an object fills the box with thin fog (on the cup capture 94% of a 128^3 grid stops 1% of
the light over a vertex spacing), while a render sees only the first surfaces along its
rays; those are what the views' sample lists hold."""

from typing import Dict, Iterable, Iterator, List, Optional, Tuple

import numpy as np
from scipy import spatial

from msnerf_jax.kinds import views as views_lib
from msnerf_jax.models.nerf import NerfField
from msnerf_jax.models.painted_field import corners
from msnerf_jax.nerf import sample_cache

SEEN_WEIGHT = 1e-3  # a vertex is seen when its summed weight in the training views is above.


def camera_samples(scene, nerf_run, cameras: Iterable, top_k: int, threshold: float
                   ) -> Iterator[Dict[str, np.ndarray]]:
  """The frozen NeRF's sample lists of each camera (a training view's index or a c2w) of the
  scene: sample_cache.view_samples, the samples of weight above `threshold`."""
  field = NerfField(nerf_run.config)
  for camera in cameras:
    yield sample_cache.view_samples(field, nerf_run.params, scene.camera_rays(camera),
                                    nerf_run.config, top_k, threshold)


def path_views(scene, nerf_run, top_k: int, threshold: float, views: int
               ) -> Tuple[List[Dict[str, np.ndarray]], np.ndarray]:
  """`views` cameras spread along the scene's render path as painting views: (their sample
  lists (camera_samples), their photo-real renders by the frozen NeRF [P, H, W, 3], which
  stand in for photos), or ([], [0, H, W, 3]) for none."""
  poses = scene.path_poses(views) if views else []
  samples = list(camera_samples(scene, nerf_run, poses, top_k, threshold))
  renders = [views_lib.render_view(scene, nerf_run.params, nerf_run.config, pose)["rgb"]
             for pose in poses]
  shape = (0, scene.height, scene.width, 3)
  return samples, (np.stack(renders).astype(np.float32) if renders else np.zeros(shape,
                                                                              np.float32))


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


def vertex_sums(cache: Dict[str, np.ndarray], index: np.ndarray, count: int, bound: float,
                pictures: Optional[np.ndarray] = None
                ) -> Tuple[np.ndarray, Optional[np.ndarray]]:
  """What all the cached views put on each painted vertex, in one pass: (weight [V + 1], the
  summed weight of their samples there (view_spread's), colours [V + 1, 3] or None: the
  weighted sum of the colours of those samples' pixels in `pictures` [N, n, 3], one picture
  a cached view)."""
  total = np.zeros(count + 1)
  sums = None if pictures is None else np.zeros((count + 1, 3))
  for view in range(len(cache["weights"])):
    rows, spread, pixel = view_spread(cache, view, index, bound)
    total += np.bincount(rows, spread, count + 1)
    if sums is not None:
      colour = np.asarray(pictures[view], np.float64)[pixel]
      for c in range(3):
        sums[:, c] += np.bincount(rows, spread * colour[:, c], count + 1)
  return total, sums


def seen_of(total: np.ndarray) -> np.ndarray:
  """bool [V + 1]: the vertices whose summed weight (vertex_sums') is above SEEN_WEIGHT
  (row V, unpainted, never)."""
  seen = total > SEEN_WEIGHT
  seen[-1] = False
  return seen


def seen_vertices(cache: Dict[str, np.ndarray], index: np.ndarray, count: int, bound: float
                  ) -> np.ndarray:
  """bool [V + 1]: the painted vertices whose summed weight in all the cached views is above
  SEEN_WEIGHT (row V, unpainted, never)."""
  return seen_of(vertex_sums(cache, index, count, bound)[0])


def nearest_seen(index: np.ndarray, seen: np.ndarray) -> np.ndarray:
  """int32 [V + 1]: for each painted vertex (rows of `index` [R, R, R]), itself when `seen`
  [V + 1], else the row of the nearest seen vertex (Euclidean, in grid steps: a k-d tree of
  the seen vertices, so memory grows with V, not R^3); row V (unpainted) maps to itself, and
  so does everything when no vertex is seen."""
  source = np.arange(len(seen), dtype=np.int32)
  if not seen[:-1].any():
    return source
  where = np.argwhere(index < len(seen) - 1)  # [V, 3] the painted vertices' grid positions
  rows = index[tuple(where.T)]
  looked = seen[rows]
  if looked.all():
    return source
  _, nearest = spatial.cKDTree(where[looked]).query(where[~looked])
  source[rows[~looked]] = rows[looked][nearest]
  return source
