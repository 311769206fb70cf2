"""AdaIN decoder training: content + style loss through the frozen VGG, batches from a thread."""

import dataclasses
import functools
import math
import os
import queue
import threading
import time
from typing import Any, Dict, List, Optional, Sequence, Tuple

import chex
import jax
import jax.numpy as jnp
import numpy as np
import optax

from msnerf_jax.style import adain as adain_lib
from msnerf_jax.kinds import features as feature_kind
from msnerf_jax.core import checkpoint as checkpoint_lib
from msnerf_jax.core import files
from msnerf_jax.kinds import runs as runs_lib
from msnerf_jax.core import config as config_lib
from msnerf_jax.core import run_lock
from msnerf_jax.kinds import views
from msnerf_jax.data import images as images_lib
from msnerf_jax.core.errors import UserError
from msnerf_jax.style.features import CELL, painted_size
from msnerf_jax.models import decoder as decoder_lib
from msnerf_jax.models import vgg
from msnerf_jax.core.parallel import data_parallel
from msnerf_jax.core.progress import progress_bar
from msnerf_jax.train import loop as loop_lib
from msnerf_jax.train import state as state_lib

KIND = "adain"
SHIFT_MARGIN = 8  # pixels at each border of a crop left out of the shift loss (border effects).
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


# ----------------------------------------------------------------------------- losses and step


def window(images: jnp.ndarray, corners: jnp.ndarray, side: int) -> jnp.ndarray:
  """Square windows: images [B, H, W, C], corners [B, 2] int (y, x) -> [B, side, side, C]."""
  take = lambda image, corner: jax.lax.dynamic_slice(
      image, (corner[0], corner[1], 0), (side, side, image.shape[-1]))
  return jax.vmap(take)(images, corners)


def resample_cells(features: jnp.ndarray, shifts: jnp.ndarray) -> jnp.ndarray:
  """A relu4_1 map moved by a sub-cell shift, bilinear between neighbouring cells: what a
  feature field's render gives when the camera moves the scene by (dy, dx) pixels.

  Args:
    features: [B, h, w, C]; shifts: [B, 2] int (dy, dx) pixels, each in [0, CELL].
  Returns:
    [B, h - 1, w - 1, C]: cell (i, j) is the map at (i + dy / CELL, j + dx / CELL).
  """
  a = (shifts[:, 0].astype(features.dtype) / CELL)[:, None, None, None]
  b = (shifts[:, 1].astype(features.dtype) / CELL)[:, None, None, None]
  rows = (1 - a) * features[:, :-1] + a * features[:, 1:]
  return (1 - b) * rows[:, :, :-1] + b * rows[:, :, 1:]


def shift_loss(decoder_params: Any, encoder_params: Any, content: jnp.ndarray,
               output: jnp.ndarray, style_mean: jnp.ndarray, style_std: jnp.ndarray,
               shifts: jnp.ndarray, upsample: str, source: str = "photo",
               target: Optional[jnp.ndarray] = None) -> jnp.ndarray:
  """Shift consistency of the stylization: decoding a moved crop moves the strokes with it.

  The window of side S - CELL at (dy, dx) of each content crop is stylized on its own (its
  relu4_1 cells sit dy, dx pixels off the crop's) and compared with the same window of the
  crop's stylization `output`, SHIFT_MARGIN pixels from the window's borders left out. With
  source "photo" the window's map is the encoder's of the moved pixels; with "features" it is
  the crop's AdaIN map `target` resampled by the shift (`resample_cells`).

  Args:
    content, output: [B, S, S, 3] (content read with "photo" only); style_mean, style_std:
      [B, 512] (relu4_1 statistics).
    shifts: [B, 2] int (dy, dx), each in [1, CELL).
    source: "photo" or "features" (config.SHIFT_SOURCES).
    target: [B, S / CELL, S / CELL, 512], the crop's AdaIN map; read with "features".
  Returns:
    [] mean squared pixel difference.
  """
  side = output.shape[1] - CELL
  if source == "features":
    chex.assert_shape(target, (output.shape[0], output.shape[1] // CELL,
                               output.shape[2] // CELL, None))
    moved_target = jax.lax.stop_gradient(resample_cells(target, shifts))
  else:
    moved = adain_lib.encode(encoder_params, window(content, shifts, side))["relu4_1"]
    moved_target = jax.lax.stop_gradient(adain_lib.adain_from_stats(moved, style_mean, style_std))
  moved_out = decoder_lib.Decoder(upsample).apply(decoder_params, moved_target)
  inner = slice(SHIFT_MARGIN, side - SHIFT_MARGIN)
  same = window(output, shifts, side)
  return jnp.mean(jnp.square(moved_out[:, inner, inner] - same[:, inner, inner]))


def adain_targets(encoder_params: Any, content: Optional[jnp.ndarray],
                  features: Optional[jnp.ndarray], style_mean: jnp.ndarray,
                  style_std: jnp.ndarray) -> jnp.ndarray:
  """The relu4_1 maps the decoder paints: AdaIN of the photo crops' encodings (their own
  statistics, the paper's), then the normalised feature crops given the style's statistics
  (`n * std + mean`, as a feature run's view is stylized), concatenated along the batch.

  Args:
    content: [P, S, S, 3] or None; features: [F, S / 8, S / 8, 512] or None (P + F = B).
    style_mean, style_std: [B, 512], the first P for the photos.
  Returns:
    [B, S / 8, S / 8, 512].
  """
  parts, p = [], 0
  if content is not None:
    p = content.shape[0]
    feats = adain_lib.encode(encoder_params, content)["relu4_1"]
    parts.append(adain_lib.adain_from_stats(feats, style_mean[:p], style_std[:p]))
  if features is not None:
    parts.append(features * style_std[p:, None, None] + style_mean[p:, None, None])
  return jnp.concatenate(parts) if len(parts) > 1 else parts[0]


def losses(decoder_params: Any, encoder_params: Any, content: Optional[jnp.ndarray],
           style: jnp.ndarray, config: config_lib.AdainConfig,
           shifts: Optional[jnp.ndarray] = None, features: Optional[jnp.ndarray] = None
           ) -> Tuple[jnp.ndarray, Dict[str, jnp.ndarray]]:
  """AdaIN training loss (Huang & Belongie eq. 11-13), plus the optional shift consistency.

  Args:
    content: [P, S, S, 3] photo crops in [0, 1], or None; style: [B, S, S, 3] in [0, 1].
    shifts: [B, 2] int sub-cell shifts (`random_shifts`); read when config.shift_weight > 0.
    features: [F, S / 8, S / 8, 512] feature crops normalised by their scene's statistics
      (`render_content_features`), or None; P + F = B.
  Returns:
    (total [], {"loss", "content", "style"[, "shift"]}): content = MSE(relu4_1(g(t)), t) with
    t = AdaIN(f(c), f(s)) (`adain_targets`); style = sum over relu1_1..relu4_1 of MSE of
    means + MSE of stds; shift = `shift_loss`, weighted by config.shift_weight.
  """
  n_photos = 0 if content is None else content.shape[0]
  n_features = 0 if features is None else features.shape[0]
  chex.assert_equal(n_photos + n_features, style.shape[0])
  if content is not None:
    chex.assert_equal_shape([content, style[:n_photos]])
  if features is not None:
    chex.assert_shape(features, (n_features, style.shape[1] // CELL, style.shape[2] // CELL, None))
  encoder_params = jax.lax.stop_gradient(encoder_params)  # frozen: XLA drops its backward.
  target_stats = adain_lib.style_stats(encoder_params, style)
  target = adain_targets(encoder_params, content, features, *target_stats["relu4_1"])
  target = jax.lax.stop_gradient(target)
  output = decoder_lib.Decoder(config.upsample).apply(decoder_params, target)
  out_feats = adain_lib.encode(encoder_params, output)
  content_loss = jnp.mean(jnp.square(out_feats["relu4_1"] - target))
  out_stats = {name: adain_lib.channel_stats(out_feats[name]) for name in vgg.STYLE_LAYERS}
  style_loss = adain_lib.style_loss(out_stats, jax.lax.stop_gradient(target_stats))
  total = config.content_weight * content_loss + config.style_weight * style_loss
  metrics = {"content": content_loss, "style": style_loss}
  if config.shift_weight > 0:
    chex.assert_shape(shifts, (style.shape[0], 2))
    mean, std = jax.lax.stop_gradient(target_stats["relu4_1"])
    metrics["shift"] = shift_loss(decoder_params, encoder_params, content, output, mean, std,
                                  shifts, config.upsample, config.shift_source, target)
    total = total + config.shift_weight * metrics["shift"]
  return total, {"loss": total, **metrics}


def make_optimizer(config: config_lib.AdainConfig) -> optax.GradientTransformation:
  """Adam with the reference code's lr / (1 + decay * step)."""
  schedule = lambda count: config.lr / (1.0 + config.lr_decay * count)
  return optax.adam(schedule)


def step_config(config: config_lib.AdainConfig) -> config_lib.AdainConfig:
  """`config` with only the fields the jitted step reads (losses, optimizer, upsampling) kept,
  so runs that differ in steps, sizes or bookkeeping share one compiled step."""
  return dataclasses.replace(config, steps=1, size=0, resize=0, batch=0, holdout_every=0, seed=0,
                             sample_every=1, checkpoint_every=1, keep_checkpoints=1, init_from="",
                             content_features="", feature_share=0.5)


@functools.lru_cache(maxsize=8)
def make_train_step(config: config_lib.AdainConfig):
  """jitted (params, opt_state, encoder_params, content, style[, shifts, features]) ->
  (params, opt_state, metrics).

  Cached per (frozen) config, so a resumed or repeated run in one process compiles once.
  """
  optimizer = make_optimizer(config)

  def step(params, opt_state, encoder_params, content, style, shifts=None, features=None):
    grads, metrics = jax.grad(losses, has_aux=True)(params, encoder_params, content, style, config,
                                                    shifts, features)
    updates, opt_state = optimizer.update(grads, opt_state, params)
    return optax.apply_updates(params, updates), opt_state, metrics

  return jax.jit(step, donate_argnums=(0, 1))


@functools.lru_cache(maxsize=4)
def make_stylize_fn(upsample: str):
  """jitted (decoder_params, encoder_params, content [B,H,W,3], style [B,H',W',3]) -> [B,H,W,3]."""

  def fn(decoder_params, encoder_params, content, style):
    feats = adain_lib.encode(encoder_params, content)["relu4_1"]
    style_feats = adain_lib.encode(encoder_params, style)["relu4_1"]
    out = decoder_lib.Decoder(upsample).apply(decoder_params, adain_lib.adain(feats, style_feats))
    return jnp.clip(out, 0.0, 1.0)

  return jax.jit(fn)


@functools.lru_cache(maxsize=4)
def make_feature_stylize_fn(upsample: str):
  """jitted (decoder_params, encoder_params, normalised features [B,h,w,512], stats [2, 512],
  style [B,H,W,3]) -> (the features decoded unstylized, stylized), each [B, 8h, 8w, 3]."""

  def fn(decoder_params, encoder_params, features, stats, style):
    mean, std = adain_lib.channel_stats(adain_lib.encode(encoder_params, style)["relu4_1"])
    decode = lambda t: jnp.clip(decoder_lib.Decoder(upsample).apply(decoder_params, t), 0.0, 1.0)
    own = [jnp.broadcast_to(x, mean.shape) for x in stats]  # AdaIN towards the scene: identity.
    return (decode(adain_targets(encoder_params, None, features, *own)),
            decode(adain_targets(encoder_params, None, features, mean, std)))

  return jax.jit(fn)


def sample_grid(content: np.ndarray, style: np.ndarray, output: np.ndarray) -> np.ndarray:
  """Rows of (content | style | output) with 4-pixel white gaps: [B*S + gaps, 3*S + gaps, 3]."""
  rows = []
  gap = 4
  for c, s, o in zip(content, style, output):
    sep = np.ones((c.shape[0], gap, 3), np.float32)
    rows.append(np.concatenate([c, sep, s, sep, o], axis=1))
    rows.append(np.ones((gap, rows[-1].shape[1], 3), np.float32))
  return np.concatenate(rows[:-1], axis=0)


def _all_finite(tree) -> bool:
  # numpy on the host: jnp would compile one reduction per leaf shape (~10 s on one core).
  return all(bool(np.isfinite(np.asarray(x)).all()) for x in jax.tree_util.tree_leaves(tree))


# ----------------------------------------------------------------------------- training loop


@dataclasses.dataclass(frozen=True)
class TrainResult:
  run_dir: str
  step: int
  metrics: Dict[str, float]
  seconds: float
  images_per_second: float


def collect_content(content_dirs: Sequence[str], holdout_every: int) -> Tuple[List[List[str]], List[str]]:
  """Per-folder training paths and the held-out paths of the content folders."""
  groups, held = [], []
  for folder in content_dirs:
    train, out = split_holdout(images_lib.list_images(folder), holdout_every)
    groups.append(train)
    held += out
  return groups, held


def initial_decoder(config: config_lib.AdainConfig, resuming: bool = False) -> Any:
  """The decoder params a new run starts from: a random init, or with `init_from` the latest
  checkpoint of that AdaIN run (same encoder; a UserError naming it otherwise). Its upsampling
  may differ: nearest and bilinear decoders have the same parameters, so a nearest decoder can
  be fine-tuned into a bilinear one. A resumed run restores its own checkpoint, so the random
  init only gives the structure."""
  if not config.init_from or resuming:
    return decoder_lib.init_decoder(jax.random.PRNGKey(config.seed), config.upsample)
  source = runs_lib.load_run(config.init_from, KIND)
  run_file = os.path.join(config.init_from, runs_lib.RUN_FILE)
  if source.config.encoder != config.encoder:
    raise UserError(f"{run_file}: decoder made with encoder {source.config.encoder!r}, "
                    f"this run uses {config.encoder!r}")
  return jax.tree_util.tree_map(jnp.asarray, source.params)


def check_feature_content(config: config_lib.AdainConfig, content_dirs: Sequence[str]):
  """UserErrors for feature-map content settings that cannot work, before anything is written:
  a share outside (0, 1], a folder that is not a loadable feature run (or whose views are
  fewer cells than a crop), no photo folders for the photos' share, the shift loss's photo
  source (feature crops have no pixels to move).

  Returns: the feature run's (run, scene) (feature_source), or None without feature content."""
  if not config.content_features:
    if not content_dirs:
      raise UserError("--content: give at least one content folder (or --content-features)")
    return None
  if feature_batch(config) < config.batch and not content_dirs:
    raise UserError(f"--content: needed for the photo share of each batch "
                    f"(or --feature-share 1)")
  if config.shift_weight > 0 and config.shift_source != "features":
    raise UserError(f"--shift-source {config.shift_source}: feature crops have no pixels to "
                    f"move; use --shift-source features with --content-features")
  run, scene = source = feature_source(config)
  cells = min(painted_size(scene.height, scene.width, run.config.stylize_scale)) // CELL
  if cells < config.size // CELL:
    raise UserError(f"{os.path.join(config.content_features, runs_lib.RUN_FILE)}: its views are "
                    f"{cells} relu4_1 cells on their shorter side, --size {config.size} needs "
                    f"{config.size // CELL}")
  return source


@run_lock.released_after
def train(config: config_lib.AdainConfig, content_dirs: Sequence[str], style_dir: str,
          run_dir: str, progress: bool = True, log=print) -> TrainResult:
  """Trains (or resumes) an AdaIN decoder in `run_dir`, on the shared loop (train.loop.fit).

  Writes run.json, checkpoints/ (orbax, params + Adam state + step), samples/step_N.png
  (content | style | output) every `sample_every` steps, and holdout.txt (the held-out
  content files, for evaluation). A NaN/inf loss stops training with a UserError naming
  the step; the last good checkpoint is kept.
  """
  config.validate()
  n_features = feature_batch(config)
  feature_run = check_feature_content(config, content_dirs)
  saved = os.path.join(run_dir, checkpoint_lib.CHECKPOINT_DIR)
  init_params = initial_decoder(config, resuming=os.path.isdir(saved) and bool(os.listdir(saved)))
  # Validate every input before touching the run folder.
  groups, held = collect_content(content_dirs, config.holdout_every)
  style_paths = images_lib.list_images(style_dir)
  encoder_params = vgg.load_vgg_params()
  record = {"config": config_lib.to_dict(config),
            "content": [os.path.abspath(d) for d in content_dirs],
            "styles": os.path.abspath(style_dir),
            "holdout": [os.path.abspath(p) for p in held]}
  log(f"reading {sum(map(len, groups))} content images ({len(held)} held out) "
      f"and {len(style_paths)} style images")
  content_pools = [[load_for_crops(p, config.resize, config.size) for p in g] for g in groups]
  style_pools = [[load_for_crops(p, config.resize, config.size) for p in style_paths]]

  resumed = runs_lib.prepare_run_dir(run_dir, KIND, record, lock=True)
  files.atomic_write_bytes(os.path.join(run_dir, "holdout.txt"),
                                "".join(p + "\n" for p in record["holdout"]).encode())
  checkpoints = checkpoint_lib.Checkpoints(run_dir, keep=config.keep_checkpoints)
  start = checkpoints.latest_step() if resumed else None
  checkpoints.close()
  if start is not None:
    log(f"resuming {run_dir} from step {start}")
    if start >= config.steps:
      log(f"{run_dir}: already trained to step {start} (>= --steps {config.steps})")
      return TrainResult(run_dir, start, {}, 0.0, 0.0)
  feature_maps = feature_stats = None
  if n_features:
    log(f"feature maps of {config.content_features}: {n_features} of every {config.batch} crops")
    feature_maps, feature_stats = prepare_feature_maps(run_dir, config, feature_run, progress)

  sample_rng = np.random.default_rng([config.seed, 10**9])
  n_samples = min(4, config.batch)
  if n_features == config.batch:  # no photos: the unstylized decode is the content column.
    stylize_features = make_feature_stylize_fn(config.upsample)
    sample_features = random_feature_crops(sample_rng, feature_maps, n_samples, config.size // CELL)
    sample_style = random_crops(sample_rng, style_pools, n_samples, config.size)
    def painted(params):
      return tuple(map(np.asarray, stylize_features(params, encoder_params, sample_features,
                                                    feature_stats, sample_style)))
  else:
    stylize = make_stylize_fn(config.upsample)
    sample_content = random_crops(sample_rng, content_pools, n_samples, config.size)
    sample_style = random_crops(sample_rng, style_pools, n_samples, config.size)
    def painted(params):
      return sample_content, np.asarray(stylize(params, encoder_params, sample_content,
                                                sample_style))
  os.makedirs(os.path.join(run_dir, "samples"), exist_ok=True)
  train_step = make_train_step(step_config(config))
  # Shared with the loop's hooks: the last good checkpoint, the latest state, the last step
  # that passed the checks and its metrics, the throughput clock (not the compiling step).
  last_good, latest, done, metrics = start, None, start or 0, {}
  timed_from, timed_steps = None, 0

  def step_fn(state, batch):
    nonlocal latest
    params, opt_state, m = train_step(state.params, state.opt_state, encoder_params, *batch)
    latest = state.replace(step=np.asarray(state.step + 1, np.int64), params=params,
                           opt_state=opt_state)
    return latest, m

  def check_finite(params, step):
    if not _all_finite(params):
      raise UserError(f"{run_dir}: parameters became NaN/inf by step {step}; stopped, "
                      f"last good checkpoint: step {last_good}")

  def on_step(step, state, m):  # before the loop's loss check and this step's checkpoint.
    nonlocal last_good, done, metrics, timed_from, timed_steps
    values = {k: float(v) for k, v in m.items()}
    if not all(math.isfinite(v) for v in values.values()):
      where = os.path.abspath(os.path.join(run_dir, checkpoint_lib.CHECKPOINT_DIR))
      raise UserError(f"step {step}: loss is {values['loss']} (NaN/inf); stopped; last good "
                      f"checkpoint: {'step ' + str(last_good) if last_good is not None else 'none'} "
                      f"in {where} (lower --lr?)")
    done, metrics = step, values
    if timed_from is None:
      timed_from = time.time()
    else:
      timed_steps += 1
    if step % config.sample_every == 0 or step == config.steps:
      content, out = painted(state.params)
      images_lib.write_image(os.path.join(run_dir, "samples", f"step_{step:07d}.png"),
                             sample_grid(content, sample_style, out))
    if step % config.checkpoint_every == 0 or step == config.steps:  # the loop saves it next.
      check_finite(state.params, step)
      last_good = step

  state = state_lib.create_state(init_params, make_optimizer(config))
  state = state.replace(step=np.asarray(0, np.int64))  # the step as AdaIN checkpoints hold it.
  batches = PrefetchedBatches(content_pools, style_pools, config, feature_maps)
  try:
    summary = loop_lib.fit(state, step_fn, batches, run_dir=run_dir, steps=config.steps,
                           checkpoint_every=config.checkpoint_every,
                           keep_checkpoints=config.keep_checkpoints,
                           parallel=data_parallel(1), desc="adain", progress=progress, on_step=on_step,
                           shown=("content", "style") + (("shift",) if config.shift_weight > 0 else ()),
                           history=False)
  finally:
    batches.close()
  seconds = summary["seconds"]
  rate = timed_steps * config.batch / (time.time() - timed_from) if timed_steps else 0.0
  summary = {"step": done, "metrics": metrics, "seconds": round(seconds, 1),
             "images_per_second": round(rate, 3)}
  _write_summary(run_dir, summary)
  log(f"trained {run_dir} to step {done} in {seconds:.0f} s ({rate:.2f} images/s); "
      f"loss {metrics.get('loss', float('nan')):.4f} (content {metrics.get('content', float('nan')):.4f}, "
      f"style {metrics.get('style', float('nan')):.4f}); checkpoints in {run_dir}/checkpoints, "
      f"samples in {run_dir}/samples")
  return TrainResult(run_dir, done, metrics, seconds, rate)


def _write_summary(run_dir: str, summary: Dict[str, Any]) -> None:
  record = runs_lib.read_run_file(run_dir)
  record["summary"] = summary
  files.write_json(os.path.join(run_dir, runs_lib.RUN_FILE), record)
