"""What painting reads, prepared once: the style pictures, the training views' sample lists
cached from the frozen NeRF (RUN/sample_cache.npz, stamped with the NeRF run it was made
from), the painted vertices, where each row's samples start (for crops), and the constants
every step reads."""

import os
from typing import Any, Dict, Optional, Sequence, Tuple

import jax
import jax.numpy as jnp
import numpy as np

from msnerf_jax.core.config import MIN_CROP, PaintConfig
from msnerf_jax.core.errors import UserError
from msnerf_jax.core.files import atomic_path
from msnerf_jax.core.progress import progress_bar
from msnerf_jax.data.images import cover_crop, file_problem, read_style_image
from msnerf_jax.models import vgg
from msnerf_jax.models.painted_field import paint_index
from msnerf_jax.nerf import sample_cache
from msnerf_jax.style import painting_loss
from msnerf_jax.style.transfer import apply_colour_map, colour_map
from msnerf_jax.train.paint_coverage import (camera_samples, nearest_seen, path_views,
                                             seen_of, seen_vertices, vertex_sums)

CACHE_FILE = "sample_cache.npz"


def style_name(path: str) -> str:
  return os.path.splitext(os.path.basename(path.rstrip("/")))[0]


MAX_STYLE_SIZE = 256  # the fitted style size's cap: the NNFM matrix grows with its square.


def style_size(config: PaintConfig, scene) -> int:
  """The side of the square the style images are cover-cropped to: config.style_size, or
  for 0 the scene's longer side (MIN_CROP to MAX_STYLE_SIZE), so that the style loss sees
  the painting's strokes at about the scale per-frame AdaIN paints them on a view (it
  cover-crops the style to the view). Measured on the cup capture (100x75, 300 steps):
  style distance 0.98-1.64x per-frame AdaIN's at 100 against 1.56-1.80x at 256."""
  return config.style_size or min(max(scene.height, scene.width, MIN_CROP), MAX_STYLE_SIZE)


def read_styles(paths: Sequence[str], size: int) -> np.ndarray:
  """The style images cover-cropped to size x size: [M, size, size, 3] float32; UserError
  for an empty list, two styles of one name, or a file that is not a still image of at
  least 16 x 16 pixels."""
  if not paths:
    raise UserError("--styles: give at least one style image")
  names = [style_name(p) for p in paths]
  for name, path in zip(names, paths):
    if names.count(name) > 1:
      raise UserError(f"{path}: two styles named {name!r}; rename one")
  return np.stack([cover_crop(read_style_image(p), size, size) for p in paths])


def build_cache(scene, nerf_run, config: PaintConfig, progress: bool) -> Dict[str, np.ndarray]:
  """The packed sample lists of the scene's training views (sample_cache.view_samples)."""
  cameras = progress_bar([int(i) for i in scene.split("train")], desc="caching samples",
                         disable=not progress, leave=False)
  return sample_cache.pack_views(list(camera_samples(scene, nerf_run, cameras, config.top_k,
                                                     config.cache_threshold)))


def read_cache(path: str, made_from: str) -> Optional[Dict[str, np.ndarray]]:
  """The sample lists cached at `path` (None when there are none yet); UserError for a file
  that is not a cache or one made from another NeRF run than `made_from` ("RUN@STEP")."""
  if not os.path.exists(path):
    return None
  try:
    with np.load(path, allow_pickle=False) as saved:
      source = str(saved["nerf_run"]) if "nerf_run" in saved.files else ""
      if source != made_from:
        raise UserError(f"{path}: made from the NeRF run {source or '(unknown)'}, not "
                        f"{made_from}; delete it to rebuild")
      cache = {k: saved[k] for k in saved.files if k != "nerf_run"}
  except (UserError, MemoryError):
    raise
  except Exception as e:  # pylint: disable=broad-except  # a broken .npy header: SyntaxError ...
    raise UserError(f"{path}: not a sample cache ({file_problem(e)}); delete it to "
                    "rebuild") from None
  _check_cache(cache, path)
  return cache


def _check_cache(cache: Dict[str, np.ndarray], path: str) -> None:
  """UserError naming the file unless `cache` holds the arrays pack_views makes: points
  [N, P, 3], weights [N, P], pixel [N, P] (whole numbers below n), accumulation [N, n]."""
  def bad(problem):
    raise UserError(f"{path}: not a sample cache ({problem}); delete it to rebuild")
  keys = set(sample_cache.CACHE_KEYS) | {"accumulation"}
  if set(cache) != keys:
    bad(f"holds {', '.join(sorted(cache)) or 'nothing'}, expected {', '.join(sorted(keys))}")
  if not all(isinstance(v, np.ndarray) for v in cache.values()):
    bad("a member is not a .npy array")
  weights, accumulation = cache["weights"], cache["accumulation"]
  if weights.ndim != 2 or not len(weights) or accumulation.ndim != 2:
    bad(f"weights {weights.shape}, accumulation {accumulation.shape}")
  n, p = weights.shape
  if (cache["points"].shape != (n, p, 3) or cache["pixel"].shape != (n, p)
      or len(accumulation) != n):
    bad(f"points {cache['points'].shape}, pixel {cache['pixel'].shape} and accumulation "
        f"{accumulation.shape} do not fit weights {weights.shape}")
  for key in ("points", "weights", "accumulation"):
    if cache[key].dtype.kind != "f" or not np.all(np.isfinite(cache[key])):
      bad(f"{key} must be finite floats")
  pixel = cache["pixel"]
  if pixel.dtype.kind not in "iu" or np.any(pixel < 0) or np.any(pixel >= accumulation.shape[1]):
    bad("pixel must be whole numbers below the number of pixels")


def cache_source(nerf_run) -> str:
  """What a cache records of the NeRF run it was made from: "ABSOLUTE_FOLDER@STEP"."""
  return f"{os.path.abspath(nerf_run.run_dir)}@{nerf_run.step}"


def load_or_build_cache(run_dir: str, scene, nerf_run, config: PaintConfig, progress: bool
                        ) -> Dict[str, np.ndarray]:
  """The run's cached sample lists (RUN/sample_cache.npz), built and written atomically on
  first use. UserError for a cache made from another NeRF run (or another step of it)."""
  path = os.path.join(run_dir, CACHE_FILE)
  made_from = cache_source(nerf_run)
  cache = read_cache(path, made_from)
  if cache is not None:
    return cache
  cache = build_cache(scene, nerf_run, config, progress)
  with atomic_path(path, sum(v.nbytes for v in cache.values())) as tmp:
    with open(tmp, "wb") as f:
      np.savez(f, nerf_run=np.array(made_from), **cache)
  return cache


def painting_views(cache, scene, nerf_run, config: PaintConfig
                   ) -> Tuple[Dict[str, np.ndarray], np.ndarray]:
  """(sample lists, photos [N + P, H, W, 3]) of the views a painting is optimised on: the N
  training views (the packed `cache` and the scene's photos), then config.path_views
  cameras along the scene's render path (paint_coverage.path_views: the photo-real NeRF's
  renders stand in for their photos), so the style loss paints what the path looks at
  where no photo does."""
  photos = np.asarray(scene.images[scene.split("train")], np.float32)
  lists, renders = path_views(scene, nerf_run, config.top_k, config.cache_threshold,
                              config.path_views)
  if not lists:
    return cache, photos
  extra = sample_cache.pack_views(lists)
  n, size = len(cache["weights"]), max(cache["weights"].shape[1], extra["weights"].shape[1])
  joined = {"accumulation": np.concatenate([cache["accumulation"], extra["accumulation"]])}
  for key in sample_cache.CACHE_KEYS:  # padded as pack_views pads (weight 0 at pixel 0)
    out = np.zeros((n + len(lists), size) + cache[key].shape[2:], cache[key].dtype)
    out[:n, :cache[key].shape[1]] = cache[key]
    out[n:, :extra[key].shape[1]] = extra[key]
    joined[key] = out
  return joined, np.concatenate([photos, renders])


def index_of(cache, config: PaintConfig):
  """(index, V) of the painted vertices: those around every sample of the painting's views
  (painting_views') that carries weight, grown by one vertex (painted_field.paint_index)."""
  points = (p[w > 0] for p, w in zip(cache["points"], cache["weights"]))
  return paint_index(points, config.resolution, config.scene_box)


def fill_map(cache, index: np.ndarray, count: int, bound: float) -> np.ndarray:
  """int32 [V + 1]: where each painted vertex takes its colour from after a step: itself
  when the training views see it, else the nearest vertex they see
  (paint_coverage.nearest_seen)."""
  return nearest_seen(index, seen_vertices(cache, index, count, bound))


def starting_colours(cache, photos: np.ndarray, maps: Dict[str, Any], index: np.ndarray,
                     count: int, bound: float) -> Tuple[np.ndarray, np.ndarray]:
  """(fill [V + 1] as fill_map gives it, logits [M, V + 1, 3]): where a painting starts,
  each painted vertex at the weighted mean of the photo colours the painting's views see
  at it (`photos` [N, H, W, 3], the cache's views), moved to each style by its colour map
  (`maps` as constants() holds them) -- the colour-transferred photos lifted into 3D in
  closed form, which the init fit then refines. Vertices no view sees start at their
  fill vertex's colour; the unpainted row stays grey (logit 0)."""
  total, sums = vertex_sums(cache, index, count, bound, photos.reshape(len(photos), -1, 3))
  seen = seen_of(total)
  fill = nearest_seen(index, seen)
  mean = (sums / np.maximum(total, 1e-12)[:, None])[fill]
  logits = np.zeros((len(maps["transform"]), count + 1, 3), np.float32)
  for m in range(len(logits)):
    moved = apply_colour_map(jnp.asarray(mean, jnp.float32), maps["transform"][m],
                             maps["mu_s"][m], maps["mu_t"][m])
    logits[m, :-1] = logit(np.asarray(moved)[:-1])
  return fill, logits


def logit(x: np.ndarray) -> np.ndarray:
  """The logits of colours x in [0, 1], clipped to [1e-3, 1 - 1e-3] first (float32)."""
  x = np.clip(x, 1e-3, 1.0 - 1e-3)
  return np.log(x / (1.0 - x)).astype(np.float32)


def style_maps(scene, cache, photos: np.ndarray, styles: np.ndarray, config: PaintConfig
               ) -> Dict[str, jnp.ndarray]:
  """Each style's colour map from the painting's photos [N, H, W, 3] (colour_map; the
  identity without config.colour_transfer), stacked: {"transform" [M, 3, 3], "mu_s", "mu_t"
  [M, 3]}. On white-background scenes the map moves the scene's colours, not the
  background's: the pixels count by the NeRF's opacity (the targets are put back over white
  by it too)."""
  opacity = (np.asarray(cache["accumulation"], np.float32).reshape(photos.shape[:3])
             if scene.white_background else None)
  maps = [colour_map(jnp.asarray(photos), jnp.asarray(s), source_weights=opacity)
          if config.colour_transfer else (jnp.eye(3), jnp.zeros(3), jnp.zeros(3))
          for s in styles]
  return dict(zip(("transform", "mu_s", "mu_t"), _stack([tuple(m) for m in maps])))


def _stack(trees):
  return jax.tree_util.tree_map(lambda *x: jnp.stack(x), *trees)


def constants(scene, cache, photos: np.ndarray, styles: np.ndarray, config: PaintConfig,
              fill: np.ndarray, maps: Dict[str, jnp.ndarray]) -> Dict[str, Any]:
  """What every step reads and no step changes (placed on the devices once), for the
  painting's views and the style images: "cache" (the packed sample lists of the N views,
  painting_views'), "photos" [N, H, W, 3] (theirs), "maps" (style_maps),
  "targets" (painting_loss.StyleTarget stacked [M, ...]), "encoder" (VGG params),
  "background" [3] and "fill" [V + 1] (fill_map); with config.crop also "pixel_start" and
  "band" (pixel_starts; the band is taken out by compile_train_step, a static size)."""
  encoder = vgg.load_vgg_params()
  targets = [painting_loss.style_target(encoder, jnp.asarray(s)) for s in styles]
  crops = {}
  if config.crop:
    pixel_start, band = pixel_starts(cache, scene.height, scene.width, config.crop)
    crops = {"pixel_start": jnp.asarray(pixel_start), "band": band}
  return dict(
      **crops,
      cache={k: jnp.asarray(v) for k, v in cache.items()}, photos=jnp.asarray(photos),
      maps=maps, targets=_stack(targets), encoder=encoder, fill=jnp.asarray(fill, jnp.int32),
      background=jnp.full((3,), 1.0 if scene.white_background else 0.0, jnp.float32))


def pixel_starts(cache, height: int, width: int, crop: int):
  """(pixel_start [N, H * W + 1] int32: where each pixel's samples start in each view's list,
  band: the most samples `crop` neighbouring pixels of one row hold in any view, rounded up
  to 64) of packed sample lists (sorted by pixel; the padding after the last sample of
  weight > 0)."""
  starts = []
  for pixel, weights in zip(cache["pixel"], cache["weights"]):
    count = int(np.max(np.nonzero(weights > 0)[0], initial=-1)) + 1
    starts.append(np.searchsorted(pixel[:count], np.arange(height * width + 1)))
  starts = np.asarray(starts, np.int32)
  first = starts[:, :-1].reshape(-1, height, width)  # each pixel's first sample
  after = starts[:, 1:].reshape(-1, height, width)  # and the one after its last
  band = int(np.max(after[:, :, crop - 1:] - first[:, :, :width - crop + 1]))
  return starts, max(64, -(-band // 64) * 64)
