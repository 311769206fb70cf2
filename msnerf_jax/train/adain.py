"""AdaIN decoder training: content + style loss through the frozen VGG, batches from a thread."""

import dataclasses
import functools
import math
import os
import time
from typing import Any, Callable, Dict, Optional, Sequence

import jax
import jax.numpy as jnp
import numpy as np
import optax

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
from msnerf_jax.core import distributed
from msnerf_jax.core.parallel import DataParallel, data_parallel
from msnerf_jax.train import loop as loop_lib
from msnerf_jax.train import state as state_lib
from msnerf_jax.train.adain_data import (PrefetchedBatches, collect_content, feature_batch,
                                         feature_source, load_for_crops, prepare_feature_maps)
from msnerf_jax.train.adain_losses import losses
from msnerf_jax.train.adain_samples import sample_grid, sample_painter

KIND = "adain"


@functools.lru_cache(maxsize=8)
def make_optimizer(config: config_lib.AdainConfig) -> optax.GradientTransformation:
  """Adam with the reference code's lr / (1 + decay * step). Cached per (frozen) config: a
  TrainState holds its optimizer as static data, so the same object lets a resumed or
  repeated run in one process reuse the compiled step."""
  schedule = lambda count: config.lr / (1.0 + config.lr_decay * count)
  return optax.adam(schedule)


def step_config(config: config_lib.AdainConfig) -> config_lib.AdainConfig:
  """`config` with only the fields the jitted step reads (losses, optimizer, upsampling) kept,
  so runs that differ in steps, sizes or bookkeeping share one compiled step."""
  return dataclasses.replace(config, steps=1, size=0, resize=0, batch=0, holdout_every=0, seed=0,
                             sample_every=1, checkpoint_every=1, keep_checkpoints=1, init_from="",
                             content_features="", feature_share=0.5)


def new_state(params, config: config_lib.AdainConfig) -> state_lib.TrainState:
  """A TrainState of decoder params with the run's Adam; its step an int64, as AdaIN
  checkpoints hold it."""
  state = state_lib.create_state(params, make_optimizer(step_config(config)))
  return state.replace(step=np.asarray(0, np.int64))


def train_step(state: state_lib.TrainState, batch, encoder_params, *,
               config: config_lib.AdainConfig, axis_name: Optional[str] = None):
  """One Adam step on the decoder: batch = (content, style, shifts, features) as `losses`
  takes them (this device's rows, `device_rows`), gradients and metrics averaged over the
  devices. Returns (state, metrics); the state's step is the caller's to count."""
  grads, metrics = jax.grad(losses, has_aux=True)(state.params, encoder_params, *batch[:2],
                                                  config, *batch[2:])
  if axis_name is not None:
    grads = jax.lax.pmean(grads, axis_name)
    metrics = jax.lax.pmean(metrics, axis_name)
  return state.apply_gradients(grads=grads), metrics


@functools.lru_cache(maxsize=8)
def _per_device_step(config: config_lib.AdainConfig):
  """train_step for a step_config, one object per config (so compiles are reused)."""
  return functools.partial(train_step, config=config)


def compile_train_step(config: config_lib.AdainConfig, parallel: DataParallel,
                       encoder_params) -> Callable:
  """`(state, batch) -> (state, metrics)`: train_step compiled for `parallel`'s devices, the
  frozen encoder placed once on each. Takes the state and batch as parallel.put_state and
  put_batch place them (the batch's rows ordered by `device_rows`)."""
  return parallel.compile(_per_device_step(step_config(config)), (encoder_params,))


def device_rows(batch, n_devices: int):
  """The batch (content [P], style [B], shifts [B], features [F] or None) with the style and
  shift rows reordered so that splitting every array into `n_devices` consecutive blocks
  gives each device its photos' and its feature crops' styles in the order `losses` reads
  them (its P / n photos' first). One device: the batch as it is."""
  content, style, shifts, features = batch
  if n_devices == 1:
    return batch
  p = 0 if content is None else content.shape[0] // n_devices
  f = 0 if features is None else features.shape[0] // n_devices
  photos = n_devices * p
  order = np.concatenate([np.r_[d * p:(d + 1) * p, photos + d * f:photos + (d + 1) * f]
                          for d in range(n_devices)])
  return content, style[order], None if shifts is None else shifts[order], features


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
    raise UserError("--content: needed for the photo share of each batch "
                    "(or --feature-share 1)")
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


class _Hooks:
  """The trainer's step and the loop's hook after it: the last good checkpoint, the last step
  that passed the checks and its metrics, the throughput clock (from the second step: the
  first compiles), the sample pictures (process 0)."""

  def __init__(self, config, run_dir, encoder_params, painted, sample_style, start,
               parallel: DataParallel):
    self.config, self.run_dir, self.parallel = config, run_dir, parallel
    self.painted, self.sample_style = painted, sample_style
    self.train_step = compile_train_step(config, parallel, encoder_params)
    self.last_good, self.done, self.metrics = start, start or 0, {}
    self.timed_from, self.timed_steps = None, 0

  def step(self, state, batch):
    state, m = self.train_step(state, batch)
    return state.replace(step=np.asarray(self.done + 1, np.int64)), m

  def on_step(self, step, state, m):  # before the loop's loss check and this step's checkpoint.
    config, run_dir = self.config, self.run_dir
    values = {k: float(v) for k, v in self.parallel.to_host(m).items()}
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
    sample = step % config.sample_every == 0 or step == config.steps
    checkpoint = step % config.checkpoint_every == 0 or step == config.steps
    params = self.parallel.to_host(state.params) if sample or checkpoint else None
    if sample and distributed.is_primary():
      content, out = self.painted(params)
      images_lib.write_image(os.path.join(run_dir, "samples", f"step_{step:07d}.png"),
                             sample_grid(content, self.sample_style, out))
    if checkpoint:  # the loop saves it next.
      if not _all_finite(params):
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


def check_devices(config: config_lib.AdainConfig, parallel: DataParallel) -> None:
  """UserError unless the batch's photo and feature crops split evenly over the devices."""
  n = parallel.size
  if config.batch % n:
    config_lib.bad_setting(config, "batch", f"must be a multiple of the {n} devices")
  if feature_batch(config) % n:
    config_lib.bad_setting(config, "feature_share", f"gives {feature_batch(config)} feature "
                                                    f"crops a batch, not a multiple of the "
                                                    f"{n} devices")


@run_lock.released_after
def train(config: config_lib.AdainConfig, content_dirs: Sequence[str], style_dir: str,
          run_dir: str, progress: bool = True, log=print, n_devices: Optional[int] = None,
          parallel: str = "shard_map") -> TrainResult:
  """Trains (or resumes) an AdaIN decoder in `run_dir`, on the shared loop (train.loop.fit),
  data parallel over `n_devices` (default all; processes and `parallel` as nerf.train's).

  Writes run.json, checkpoints/ (orbax, params + Adam state + step), samples/step_N.png
  (content | style | output) every `sample_every` steps, and holdout.txt (the held-out
  content files, for evaluation). A NaN/inf loss stops training with a UserError naming
  the step; the last good checkpoint is kept.
  """
  config.validate()
  devices = data_parallel(n_devices, parallel)
  check_devices(config, devices)
  n_features = feature_batch(config)
  feature_run = check_feature_content(config, content_dirs)
  saved = os.path.join(run_dir, checkpoint_lib.CHECKPOINT_DIR)
  init_params = initial_decoder(config, resuming=os.path.isdir(saved) and bool(os.listdir(saved)))
  encoder_params = vgg.load_vgg_params()
  content_pools, style_pools, record = _read_inputs(config, content_dirs, style_dir, log)
  distributed.check_same(record, "settings")
  distributed.primary_first(_prepare, run_dir, record)
  start = checkpoint_lib.latest_saved_step(run_dir) or None
  if start is not None:
    log(f"resuming {run_dir} from step {start}")
    if start >= config.steps:
      log(f"{run_dir}: already trained to step {start} (>= --steps {config.steps})")
      return TrainResult(run_dir, start, {}, 0.0, 0.0)
  feature_maps = feature_stats = None
  if n_features:
    log(f"feature maps of {config.content_features}: {n_features} of every {config.batch} crops")
    maps = distributed.primary_first(prepare_feature_maps, run_dir, config, feature_run, progress)
    feature_maps, feature_stats = maps or prepare_feature_maps(run_dir, config, feature_run)
  painted, sample_style = sample_painter(config, encoder_params, content_pools, style_pools,
                                         feature_maps, feature_stats)
  hooks = _Hooks(config, run_dir, encoder_params, painted, sample_style, start, devices)
  batches = PrefetchedBatches(content_pools, style_pools, config, feature_maps)
  try:
    summary = loop_lib.fit(new_state(init_params, config), hooks.step,
                           lambda step: device_rows(batches(step), devices.size),
                           run_dir=run_dir, **loop_lib.bookkeeping(config),
                           parallel=devices, desc="adain", progress=progress,
                           on_step=hooks.on_step, history=False,
                           shown=("content", "style") + (("shift",) if config.shift_weight > 0
                                                         else ()))
  finally:
    batches.close()
  return _finish(run_dir, hooks, summary["seconds"], log)


def _prepare(run_dir: str, record: Dict[str, Any]) -> None:
  """The run folder (run.json, checked against an existing one), holdout.txt, samples/."""
  runs_lib.prepare_run_dir(run_dir, KIND, record, lock=True)
  files.atomic_write_bytes(os.path.join(run_dir, "holdout.txt"),
                           "".join(p + "\n" for p in record["holdout"]).encode())
  os.makedirs(os.path.join(run_dir, "samples"), exist_ok=True)


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
