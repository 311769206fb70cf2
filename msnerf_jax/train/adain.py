"""AdaIN decoder training: content + style loss through the frozen VGG, batches from a thread."""

import dataclasses
import functools
import math
import os
import time
from typing import Any, Dict, Sequence

import jax
import jax.numpy as jnp
import numpy as np
import optax

from msnerf_jax.style import adain as adain_lib
from msnerf_jax.core import checkpoint as checkpoint_lib
from msnerf_jax.core import files
from msnerf_jax.kinds import runs as runs_lib
from msnerf_jax.core import config as config_lib
from msnerf_jax.core import run_lock
from msnerf_jax.data import images as images_lib
from msnerf_jax.core.errors import UserError
from msnerf_jax.style.features import CELL, painted_size
from msnerf_jax.models import decoder as decoder_lib
from msnerf_jax.models import vgg
from msnerf_jax.core.parallel import data_parallel
from msnerf_jax.train import loop as loop_lib
from msnerf_jax.train import state as state_lib
from msnerf_jax.train.adain_data import (PrefetchedBatches, collect_content, feature_batch,
                                         feature_source, load_for_crops, prepare_feature_maps,
                                         random_crops, random_feature_crops)
from msnerf_jax.train.adain_losses import adain_targets, losses

KIND = "adain"


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
    return decoder_lib.paint(decoder_params, adain_lib.adain(feats, style_feats), upsample)

  return jax.jit(fn)


@functools.lru_cache(maxsize=4)
def make_feature_stylize_fn(upsample: str):
  """jitted (decoder_params, encoder_params, normalised features [B,h,w,512], stats [2, 512],
  style [B,H,W,3]) -> (the features decoded unstylized, stylized), each [B, 8h, 8w, 3]."""

  def fn(decoder_params, encoder_params, features, stats, style):
    mean, std = adain_lib.channel_stats(adain_lib.encode(encoder_params, style)["relu4_1"])
    decode = lambda t: decoder_lib.paint(decoder_params, t, upsample)
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


def sample_painter(config: config_lib.AdainConfig, encoder_params, content_pools, style_pools,
                   feature_maps, feature_stats):
  """(painted(params) -> (content column, outputs), the style crops) of the fixed sample
  crops (up to 4) the trainer paints every sample_every steps. Without photos in a batch the
  content column is the unstylized decode of the feature crops."""
  sample_rng = np.random.default_rng([config.seed, 10**9])
  n_samples = min(4, config.batch)
  if feature_batch(config) == config.batch:
    stylize_features = make_feature_stylize_fn(config.upsample)
    sample_features = random_feature_crops(sample_rng, feature_maps, n_samples, config.size // CELL)
    sample_style = random_crops(sample_rng, style_pools, n_samples, config.size)

    def painted(params):
      return tuple(map(np.asarray, stylize_features(params, encoder_params, sample_features,
                                                    feature_stats, sample_style)))
    return painted, sample_style
  stylize = make_stylize_fn(config.upsample)
  sample_content = random_crops(sample_rng, content_pools, n_samples, config.size)
  sample_style = random_crops(sample_rng, style_pools, n_samples, config.size)

  def painted(params):
    return sample_content, np.asarray(stylize(params, encoder_params, sample_content,
                                              sample_style))
  return painted, sample_style


class _Hooks:
  """The trainer's step and the loop's hook after it: the last good checkpoint, the last step
  that passed the checks and its metrics, the throughput clock (from the second step: the
  first compiles), the sample pictures."""

  def __init__(self, config, run_dir, encoder_params, painted, sample_style, start):
    self.config, self.run_dir, self.encoder_params = config, run_dir, encoder_params
    self.painted, self.sample_style = painted, sample_style
    self.train_step = make_train_step(step_config(config))
    self.last_good, self.done, self.metrics = start, start or 0, {}
    self.timed_from, self.timed_steps = None, 0

  def step(self, state, batch):
    params, opt_state, m = self.train_step(state.params, state.opt_state, self.encoder_params,
                                           *batch)
    return state.replace(step=np.asarray(state.step + 1, np.int64), params=params,
                         opt_state=opt_state), m

  def on_step(self, step, state, m):  # before the loop's loss check and this step's checkpoint.
    config, run_dir = self.config, self.run_dir
    values = {k: float(v) for k, v in m.items()}
    if not all(math.isfinite(v) for v in values.values()):
      where = os.path.abspath(os.path.join(run_dir, checkpoint_lib.CHECKPOINT_DIR))
      last = "step " + str(self.last_good) if self.last_good is not None else "none"
      raise UserError(f"step {step}: loss is {values['loss']} (NaN/inf); stopped; last good "
                      f"checkpoint: {last} in {where} (lower --lr?)")
    self.done, self.metrics = step, values
    if self.timed_from is None:
      self.timed_from = time.time()
    else:
      self.timed_steps += 1
    if step % config.sample_every == 0 or step == config.steps:
      content, out = self.painted(state.params)
      images_lib.write_image(os.path.join(run_dir, "samples", f"step_{step:07d}.png"),
                             sample_grid(content, self.sample_style, out))
    if step % config.checkpoint_every == 0 or step == config.steps:  # the loop saves it next.
      if not _all_finite(state.params):
        raise UserError(f"{run_dir}: parameters became NaN/inf by step {step}; stopped, "
                        f"last good checkpoint: step {self.last_good}")
      self.last_good = step

  def rate(self) -> float:
    """Images per second after the first step."""
    if not self.timed_steps:
      return 0.0
    return self.timed_steps * self.config.batch / (time.time() - self.timed_from)


def _read_inputs(config, content_dirs, style_dir, log):
  """(content pools, style pools, run.json record) from the folders, every input checked
  before the run folder is touched."""
  groups, held = collect_content(content_dirs, config.holdout_every)
  style_paths = images_lib.list_images(style_dir)
  record = {"config": config_lib.to_dict(config),
            "content": [os.path.abspath(d) for d in content_dirs],
            "styles": os.path.abspath(style_dir),
            "holdout": [os.path.abspath(p) for p in held]}
  log(f"reading {sum(map(len, groups))} content images ({len(held)} held out) "
      f"and {len(style_paths)} style images")
  content_pools = [[load_for_crops(p, config.resize, config.size) for p in g] for g in groups]
  style_pools = [[load_for_crops(p, config.resize, config.size) for p in style_paths]]
  return content_pools, style_pools, record


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
  encoder_params = vgg.load_vgg_params()
  content_pools, style_pools, record = _read_inputs(config, content_dirs, style_dir, log)
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
  painted, sample_style = sample_painter(config, encoder_params, content_pools, style_pools,
                                         feature_maps, feature_stats)
  os.makedirs(os.path.join(run_dir, "samples"), exist_ok=True)
  hooks = _Hooks(config, run_dir, encoder_params, painted, sample_style, start)
  state = state_lib.create_state(init_params, make_optimizer(config))
  state = state.replace(step=np.asarray(0, np.int64))  # the step as AdaIN checkpoints hold it.
  batches = PrefetchedBatches(content_pools, style_pools, config, feature_maps)
  try:
    summary = loop_lib.fit(state, hooks.step, batches, run_dir=run_dir, steps=config.steps,
                           checkpoint_every=config.checkpoint_every,
                           keep_checkpoints=config.keep_checkpoints,
                           parallel=data_parallel(1), desc="adain", progress=progress,
                           on_step=hooks.on_step, history=False,
                           shown=("content", "style") + (("shift",) if config.shift_weight > 0
                                                         else ()))
  finally:
    batches.close()
  return _finish(run_dir, hooks, summary["seconds"], log)


def _finish(run_dir: str, hooks: _Hooks, seconds: float, log) -> TrainResult:
  """Saves the summary in run.json, logs it, returns the result."""
  done, metrics, rate = hooks.done, hooks.metrics, hooks.rate()
  runs_lib.write_summary(run_dir, {"step": done, "metrics": metrics, "seconds": round(seconds, 1),
                           "images_per_second": round(rate, 3)})
  nan = float("nan")
  log(f"trained {run_dir} to step {done} in {seconds:.0f} s ({rate:.2f} images/s); "
      f"loss {metrics.get('loss', nan):.4f} (content {metrics.get('content', nan):.4f}, "
      f"style {metrics.get('style', nan):.4f}); checkpoints in {run_dir}/checkpoints, "
      f"samples in {run_dir}/samples")
  return TrainResult(run_dir, done, metrics, seconds, rate)
