"""The AdaIN trainer's data: content and style crops from images, feature-map crops from a
feature run's renders, and the batches a thread prepares while the step runs."""

import os
import queue
import threading
from typing import List, Optional, Sequence, Tuple

import numpy as np

from msnerf_jax.kinds import features as feature_kind
from msnerf_jax.core import files
from msnerf_jax.kinds import runs as runs_lib
from msnerf_jax.core import config as config_lib
from msnerf_jax.kinds import views
from msnerf_jax.data import images as images_lib
from msnerf_jax.core.errors import UserError
from msnerf_jax.style.features import CELL
from msnerf_jax.models import vgg
from msnerf_jax.core.progress import progress_bar


FEATURE_MAPS = "content_features.npy"  # [N, h, w, 512] float16: a feature run's normalised maps.
FEATURE_STATS = "content_features_stats.npy"  # [2, 512]: the (mean, std) they were normalised by.


# ----------------------------------------------------------------------------- data


def split_holdout(paths: Sequence[str], every: int) -> Tuple[List[str], List[str]]:
  """(train, held out) of one folder's sorted paths: with every > 0, indices i % every == every - 1
  are held out (never trained on)."""
  if every <= 0:
    return list(paths), []
  train = [p for i, p in enumerate(paths) if i % every != every - 1]
  held = [p for i, p in enumerate(paths) if i % every == every - 1]
  if not train:
    train, held = held, []
  return train, held


def load_for_crops(path: str, resize: int, size: int) -> np.ndarray:
  """Reads an image as uint8 [h, w, 3] with shorter side `resize` (at least `size`)."""
  image = images_lib.read_image(path, max_side=4 * max(resize, size))
  h, w = image.shape[:2]
  if min(h, w) < 16:
    raise UserError(f"{path}: image is {w}x{h}, need at least 16x16")
  scale = max(resize, size) / min(h, w)
  nh, nw = max(size, round(h * scale)), max(size, round(w * scale))
  return images_lib.to_uint8(images_lib.resize(image, nh, nw))


def random_crops(rng: np.random.Generator, pools: Sequence[Sequence[np.ndarray]], batch: int,
                 size: int) -> np.ndarray:
  """A batch of random size x size crops with random horizontal flips.

  Each item picks a pool (folder) uniformly, then an image of it uniformly, so a folder of
  100 near-identical views does not drown one of 7 photos.
  Returns: [batch, size, size, 3] float32 in [0, 1].
  """
  out = np.empty((batch, size, size, 3), np.float32)
  for b in range(batch):
    pool = pools[rng.integers(len(pools))]
    image = pool[rng.integers(len(pool))]
    h, w = image.shape[:2]
    y, x = rng.integers(h - size + 1), rng.integers(w - size + 1)
    crop = image[y:y + size, x:x + size]
    if rng.random() < 0.5:
      crop = crop[:, ::-1]
    out[b] = crop.astype(np.float32) / 255.0
  return out


def random_shifts(rng: np.random.Generator, batch: int) -> np.ndarray:
  """Sub-cell shifts for the shift-consistency loss: [batch, 2] int32 (dy, dx) in [1, CELL)."""
  return rng.integers(1, CELL, size=(batch, 2)).astype(np.int32)


def random_feature_crops(rng: np.random.Generator, maps: np.ndarray, batch: int,
                         cells: int) -> np.ndarray:
  """A batch of random cells x cells crops of feature maps [N, h, w, C] (one map uniformly
  per item, no flips: a flipped view's VGG features are not its features flipped).
  Returns: [batch, cells, cells, C] float32."""
  out = np.empty((batch, cells, cells, maps.shape[-1]), np.float32)
  for b in range(batch):
    fmap = maps[rng.integers(len(maps))]
    y, x = rng.integers(fmap.shape[0] - cells + 1), rng.integers(fmap.shape[1] - cells + 1)
    out[b] = fmap[y:y + cells, x:x + cells]
  return out


def feature_batch(config: config_lib.AdainConfig) -> int:
  """Crops of each batch taken from the feature maps (0 without config.content_features)."""
  if not config.content_features:
    return 0
  return min(config.batch, max(1, round(config.batch * config.feature_share)))


def feature_source(config: config_lib.AdainConfig):
  """(run, scene) of config.content_features: the feature run (UserError unless it is one)
  and its scene as it was trained."""
  run = runs_lib.load_run(config.content_features, "features")
  return run, runs_lib.scene_of(run)[0]


def render_content_features(source, progress: bool = False) -> Tuple[np.ndarray, np.ndarray]:
  """A feature run's relu4_1 maps of its scene's training views (views.render_feature_map,
  the background feature filling each cell), normalised by the run's content statistics
  (feature_kind.content_stats, what rendering normalises by). source: feature_source's (run, scene).

  AdaIN towards a style's (mean, std) is then `n * std + mean`, exactly what
  feature_style.stylize_features gives the decoder when a view of the run is painted.

  Returns: (maps [N, h, w, 512] float16, statistics [2, 512] float32: mean, std)."""
  run, scene = source
  mean, std = feature_kind.content_stats(run)
  maps = [(views.render_feature_map(scene, run.params, run.config, int(i))["features"] - mean) / std
          for i in progress_bar(scene.split("train"), desc="feature maps", disable=not progress,
                                leave=False)]
  return np.stack(maps).astype(np.float16), np.stack([mean, std]).astype(np.float32)


def prepare_feature_maps(run_dir: str, config: config_lib.AdainConfig, source=None,
                         progress: bool = False) -> Tuple[np.ndarray, np.ndarray]:
  """The run's cache of render_content_features (written once, atomically, the statistics
  last; a resumed run reads both back), checked against the crop size. source: the feature
  run's (run, scene) if already loaded (default: feature_source(config))."""
  path, stats_path = os.path.join(run_dir, FEATURE_MAPS), os.path.join(run_dir, FEATURE_STATS)
  channels = vgg.LAYER_CHANNELS["relu4_1"]
  if os.path.exists(stats_path):
    maps = images_lib.read_npy(path, (None, None, None, channels)).astype(np.float16)
    stats = images_lib.read_npy(stats_path, (2, channels))
  else:
    maps, stats = render_content_features(source or feature_source(config), progress)
    files.write_npy(path, maps)
    files.write_npy(stats_path, stats)
  cells = config.size // CELL
  if min(maps.shape[1:3]) < cells:
    raise UserError(f"{path}: feature maps of shape {maps.shape}, --size {config.size} needs "
                    f"at least {cells} x {cells} cells")
  return maps, stats


class BatchLoader:
  """Prepares (content, style, shifts, features) batches for steps [start, end) in a
  background thread: content [B - F, S, S, 3] photo crops (None when F = B), features
  [F, S / 8, S / 8, 512] crops of the feature maps (None without them), F = feature_batch.

  The batch of step s is drawn from np.random.default_rng([seed, s]), so a resumed run sees
  the same batches. Errors in the thread are re-raised by `next()`.
  """

  def __init__(self, content_pools, style_pools, config: config_lib.AdainConfig, start: int,
               end: int, prefetch: int = 3, feature_maps: Optional[np.ndarray] = None):
    self._queue: "queue.Queue" = queue.Queue(maxsize=prefetch)
    self._stop = threading.Event()
    self._args = (content_pools, style_pools, config, start, end, feature_maps)
    self._thread = threading.Thread(target=self._run, daemon=True)
    self._thread.start()

  def _run(self):
    content_pools, style_pools, config, start, end, feature_maps = self._args
    n_features = feature_batch(config)
    n_photos = config.batch - n_features
    try:
      for step in range(start, end):
        rng = np.random.default_rng([config.seed, step])
        item = (random_crops(rng, content_pools, n_photos, config.size) if n_photos else None,
                random_crops(rng, style_pools, config.batch, config.size),
                random_shifts(rng, config.batch),
                random_feature_crops(rng, feature_maps, n_features, config.size // CELL)
                if n_features else None)
        while not self._stop.is_set():
          try:
            self._queue.put(item, timeout=0.1)
            break
          except queue.Full:
            continue
        if self._stop.is_set():
          return
    except BaseException as e:  # pylint: disable=broad-except
      self._queue.put(e)

  def next(self) -> Tuple[Optional[np.ndarray], np.ndarray, np.ndarray, Optional[np.ndarray]]:
    item = self._queue.get()
    if isinstance(item, BaseException):
      raise item
    return item

  def close(self):
    self._stop.set()
    self._thread.join(timeout=5)


class PrefetchedBatches:
  """The loop's batch function: step -> (content, style, shifts, features) of that step, from
  a BatchLoader started at the first step asked for (where the run resumes) and running to
  config.steps."""

  def __init__(self, content_pools, style_pools, config: config_lib.AdainConfig,
               feature_maps: Optional[np.ndarray] = None):
    self._args = (content_pools, style_pools, config, feature_maps)
    self._loader = None

  def __call__(self, step: int):
    if self._loader is None:
      content_pools, style_pools, config, feature_maps = self._args
      self._loader = BatchLoader(content_pools, style_pools, config, step, config.steps,
                                 feature_maps=feature_maps)
    return self._loader.next()

  def close(self):
    if self._loader is not None:
      self._loader.close()


def collect_content(content_dirs: Sequence[str], holdout_every: int) -> Tuple[List[List[str]], List[str]]:
  """Per-folder training paths and the held-out paths of the content folders."""
  groups, held = [], []
  for folder in content_dirs:
    train, out = split_holdout(images_lib.list_images(folder), holdout_every)
    groups.append(train)
    held += out
  return groups, held


