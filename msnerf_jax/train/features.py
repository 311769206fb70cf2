"""Training a VGG feature field on a NeRF run's frozen geometry, top to bottom: the encoder's
relu4_1 maps of the training views as targets (computed once, cached in the run), a batch of
relu4_1 cells each averaged over jittered rays inside its 8 x 8 block, composited with the
frozen NeRF's weights, lifted to 512 channels, MSE (or L1) to the targets, optionally plus
the frozen decoder's picture of patches of cells against the views' pixels (decodability);
Adam on the field alone."""

import dataclasses
import functools
import os
from typing import Any, Callable, Dict, Optional, Tuple

import jax
import jax.numpy as jnp
import numpy as np

from msnerf_jax.core import config as config_lib
from msnerf_jax.kinds import stylized_scenes
from msnerf_jax.core import distributed
from msnerf_jax.nerf import rays as rays_lib
from msnerf_jax.nerf import render as render_lib
from msnerf_jax.core import run_lock
from msnerf_jax.kinds import runs as runs_lib
from msnerf_jax.style import transfer as stylize_lib
from msnerf_jax.core.config import FeatureConfig
from msnerf_jax.core.errors import UserError
from msnerf_jax.style.features import CELL, painted_size
from msnerf_jax.models import decoder as decoder_lib
from msnerf_jax.models.feature_field import FeatureFieldFn, init_feature_params
from msnerf_jax.models.nerf import NerfField
from msnerf_jax.core.parallel import DataParallel, data_parallel
from msnerf_jax.train import loop as loop_lib
from msnerf_jax.train import multistyle as multistyle_lib
from msnerf_jax.train import nerf as nerf_lib
from msnerf_jax.train import state as state_lib
from msnerf_jax.train.feature_targets import (load_targets, prepare_targets,
                                              write_rendered_stats)

KIND = "features"
FROZEN = "nerf"  # params {"nerf": the NeRF run's params, "features": {"field", "lift"}}.
TRAINED = "features"


# ----------------------------------------------------------------------------- state


def split_frozen(params) -> Tuple[Dict, Dict]:
  """(trainable, frozen) = (params["features"], params["nerf"])."""
  return params[TRAINED], params[FROZEN]


def merge(trainable, frozen) -> Dict:
  return {FROZEN: frozen, TRAINED: trainable}


def frozen_mask(params):
  """True for every leaf of the NeRF (the optimizer's freeze mask)."""
  trainable, frozen = split_frozen(params)
  return merge(jax.tree_util.tree_map(lambda _: False, trainable),
               jax.tree_util.tree_map(lambda _: True, frozen))


def init_params(config: FeatureConfig, nerf_params) -> Dict:
  """{"nerf": a copy of the NeRF run's params, "features": a fresh field and lift}."""
  return merge(init_feature_params(config, config.scene_box, jax.random.PRNGKey(config.optim.seed)),
               jax.tree_util.tree_map(jnp.array, nerf_params))


def init_state(config: FeatureConfig, nerf_params) -> state_lib.TrainState:
  tx = state_lib.adam(state_lib.exponential_lr(config.optim), frozen=frozen_mask, b2=0.99,
                      eps=1e-15)
  return state_lib.create_state(init_params(config, nerf_params), tx)


# ----------------------------------------------------------------------------- the step


def cell_features(params, rays, config: FeatureConfig):
  """The lifted features of cells, each the mean over its rays_per_cell rays.

  Args: params {"nerf", "features"}; rays: ray_bundle [B * R], cell by cell.
  Returns: ([B, 512], complete [B] bool: every ray of the cell fitted the sampler's budget).
  """
  fn = FeatureFieldFn(config)
  out = render_lib.render_feature_rays(NerfField(config.nerf), fn, params, rays, config.nerf,
                                       config.top_k)
  r = config.rays_per_cell
  per_cell = lambda x: x.reshape(-1, r, *x.shape[1:])
  features = jnp.mean(per_cell(out["features"]), 1)
  acc = jnp.mean(per_cell(out["accumulation"]), 1)
  return fn.lift(params[TRAINED], features, acc), jnp.all(per_cell(out["complete"]), 1)


def decode_loss(params, batch, config: FeatureConfig, decoder_params, upsample: str):
  """Decodability: MSE between the frozen decoder's picture of each patch of rendered cells
  (the lifted features as they are, alpha = 0) and config.decode_target's picture of the
  patch, one cell's margin (the decoder's padding) left out.

  batch: "patch_rays" ray_bundle [P * m * m * R] (patch, then cell, major), and "pixels"
  [P, 8m, 8m, 3] of the enlarged views ("photo") or "patch_targets" [P, m, m, 512], their
  encoder's cells ("encoder"), as sample_batch makes them.
  """
  m = config.decode_cells
  decoder_params = jax.lax.stop_gradient(decoder_params)
  paint = lambda cells: decoder_lib.Decoder(upsample).apply(decoder_params, cells)
  feats, _ = cell_features(params, batch["patch_rays"], config)
  painted = paint(feats.reshape(-1, m, m, feats.shape[-1]))
  if config.decode_target == "photo":
    reference = batch["pixels"].astype(jnp.float32)
  else:
    reference = jax.lax.stop_gradient(paint(batch["patch_targets"].astype(jnp.float32)))
  inner = slice(CELL, CELL * (m - 1))
  return jnp.mean(jnp.square(painted[:, inner, inner] - reference[:, inner, inner]))


def loss_fn(trainable, frozen, batch, config: FeatureConfig, decoder_params=None,
            upsample: str = "nearest"):
  """MSE (or L1) between the cells' lifted features and their targets (over complete cells),
  plus config.decode_weight x decode_loss when that is on (decoder_params: the frozen
  decoder's, of `upsample`)."""
  params = merge(trainable, jax.lax.stop_gradient(frozen))
  pred, complete = cell_features(params, batch["rays"], config)
  diff = pred - batch["target"].astype(jnp.float32)
  masked_mean = lambda e: jnp.sum(jnp.where(complete, e, 0.0)) / jnp.maximum(jnp.sum(complete), 1)
  l1 = masked_mean(jnp.mean(jnp.abs(diff), -1))
  mse = masked_mean(jnp.mean(jnp.square(diff), -1))
  loss = l1 if config.loss == "l1" else mse
  stats = {"l1": l1, "mse": mse}
  if config.decode_weight > 0:
    stats["decode"] = decode_loss(params, batch, config, decoder_params, upsample)
    loss = loss + config.decode_weight * stats["decode"]
  return loss, {"loss": loss, **stats}


def train_step(state: state_lib.TrainState, batch, decoder_params=None, *,
               config: FeatureConfig, upsample: str = "nearest",
               axis_name: Optional[str] = None):
  """One Adam step on the feature field; the NeRF comes out bit-identical (its arrays are
  passed through, not updated by zero). decoder_params: the frozen decoder's, read when
  config.decode_weight > 0."""
  trainable, frozen = split_frozen(state.params)
  grads, stats = jax.grad(loss_fn, has_aux=True)(trainable, frozen, batch, config,
                                                 decoder_params, upsample)
  if axis_name is not None:
    grads = jax.lax.pmean(grads, axis_name)
    stats = jax.lax.pmean(stats, axis_name)
  state = state.apply_gradients(grads=merge(grads, jax.tree_util.tree_map(jnp.zeros_like,
                                                                          frozen)))
  return state.replace(params=merge(split_frozen(state.params)[0], frozen)), stats


def compile_train_step(config: FeatureConfig, parallel: DataParallel,
                       decoder: Optional[stylize_lib.Decoder] = None) -> Callable:
  """The placed (state, batch) -> (state, stats) step; `decoder` (the frozen one the
  decodability loss paints with) is needed when config.decode_weight > 0."""
  if config.decode_weight > 0:
    return parallel.compile(functools.partial(train_step, config=config,
                                              upsample=decoder.config.upsample),
                            (decoder.params,))
  return parallel.compile(functools.partial(train_step, config=config))


def _cell_rays(key, views, rows, cols, c2w, K, config: FeatureConfig, ndc: bool, shape,
               near: float, far: float, coeffs=None):
  """rays_per_cell rays in each cell (views, rows, cols) [B], uniform over its 8 x 8 block of
  the enlarged view: ray_bundle [B * R], cell-major."""
  r, s = config.rays_per_cell, config.stylize_scale
  u = jax.random.uniform(key, (views.shape[0], r, 2))
  to_pixels = lambda cell, frac: (CELL * (cell[:, None] + frac)) / s - 0.5  # [B, R]
  ray_idx = jnp.repeat(views, r)
  origins, directions = rays_lib.pixel_rays(
      K[ray_idx] if K.ndim == 3 else K, c2w[ray_idx], to_pixels(rows, u[..., 0]).reshape(-1),
      to_pixels(cols, u[..., 1]).reshape(-1), None if coeffs is None else coeffs[ray_idx])
  return rays_lib.ray_bundle(origins, directions, near, far, ndc, *shape)


@functools.partial(jax.jit, static_argnames=("config", "ndc", "shape"))
def sample_batch(key, targets, c2w, K, config: FeatureConfig, ndc: bool, shape, near: float,
                 far: float, coeffs=None, pixels=None):
  """A random batch of relu4_1 cells of the training views, rays_per_cell jittered rays in
  each (uniform over the cell's 8 x 8 block of the enlarged view); with config.decode_weight
  > 0 also decode_patches square patches of decode_cells x decode_cells cells, with their
  pixels or target cells (config.decode_target).

  Args:
    targets: [N, h, w, 512] float16; c2w [N, 3, 4]; K [3, 3] or [N, 3, 3]; coeffs [N, 5]
      or None; shape (H, W, focal) for NDC; pixels: [N, 8h, 8w, 3] the enlarged views
      (stylize.enlarged), read for the "photo" target.
  Returns:
    {"rays": ray_bundle [B * R] (cell-major), "target": [B, 512] float16[, "patch_rays":
    ray_bundle [P * m * m * R], and "pixels" [P, 8m, 8m, 3] or "patch_targets"
    [P, m, m, 512]]}.
  """
  n, h, w = targets.shape[:3]
  b = config.batch_cells
  k_img, k_row, k_col, k_jit = jax.random.split(key, 4)
  idx = jax.random.randint(k_img, (b,), 0, n)
  rows = jax.random.randint(k_row, (b,), 0, h)
  cols = jax.random.randint(k_col, (b,), 0, w)
  rays_of = lambda k, v, r, c: _cell_rays(k, v, r, c, c2w, K, config, ndc, shape, near, far,
                                          coeffs)
  batch = {"rays": rays_of(k_jit, idx, rows, cols), "target": targets[idx, rows, cols]}
  if config.decode_weight > 0:
    m, p = config.decode_cells, config.decode_patches
    k_img, k_row, k_col, k_jit = jax.random.split(jax.random.fold_in(key, 1), 4)
    views = jax.random.randint(k_img, (p,), 0, n)
    top = jax.random.randint(k_row, (p,), 0, h - m + 1)
    left = jax.random.randint(k_col, (p,), 0, w - m + 1)
    grid = lambda start, axis: jnp.broadcast_to(
        jnp.expand_dims(start[:, None] + jnp.arange(m), axis), (p, m, m)).reshape(-1)
    cells = (jnp.repeat(views, m * m), grid(top, 2), grid(left, 1))
    batch["patch_rays"] = rays_of(k_jit, *cells)
    if config.decode_target == "photo":
      batch["pixels"] = jax.vmap(lambda v, t, l: jax.lax.dynamic_slice(
          pixels[v], (CELL * t, CELL * l, 0), (CELL * m, CELL * m, 3)))(views, top, left)
    else:
      batch["patch_targets"] = targets[cells].reshape(p, m, m, targets.shape[-1])
  return batch


# ----------------------------------------------------------------------------- the loop


def check_config(config: FeatureConfig, parallel: DataParallel) -> None:
  """UserError naming the setting (its `msnerf features train` option) that cannot work:
  FeatureConfig.validate, then what depends on the devices."""
  config.validate()
  if config.decode_weight > 0 and config.decode_patches % parallel.size:
    config_lib.bad_setting(config, "decode_patches", f"must be a positive multiple of the "
                                                     f"{parallel.size} device(s)")
  nerf_lib.check_batch_splits(config.batch_cells, parallel)


def check_same_nerf(run_dir: str, nerf_run_dir: str) -> None:
  """UserError when run_dir is a feature run made on another NeRF run (its geometry and its
  targets' views belong to that one)."""
  if not os.path.exists(os.path.join(run_dir, runs_lib.RUN_FILE)):
    return
  made_on = runs_lib.read_run_file(run_dir, KIND).get("nerf_run")
  if made_on and os.path.abspath(made_on) != os.path.abspath(nerf_run_dir):
    raise UserError(f"{os.path.join(run_dir, runs_lib.RUN_FILE)}: a feature run made on the "
                    f"NeRF run {made_on}, not {os.path.abspath(nerf_run_dir)}; use another "
                    "--out")


@run_lock.released_after
def train(config: FeatureConfig, nerf_run_dir: str, decoder_dir: str, run_dir: str,
          n_devices: Optional[int] = None, progress: bool = True,
          callback: Optional[Callable[[int, Any], None]] = None, parallel: str = "shard_map"
          ) -> Dict[str, Any]:
  """Trains (or resumes) a feature field in `run_dir` on the NeRF run's frozen geometry.

  `config.nerf` becomes the NeRF run's config and `config.scene_box` its scene box; the
  decoder run (`msnerf adain train`) is checked against this build's encoder (the targets
  are that encoder's features) and recorded for rendering. Devices and processes as
  nerf.train's. Returns the loop's summary dict.
  """
  check_same_nerf(run_dir, nerf_run_dir)
  nerf_run, scene, data = multistyle_lib.load_nerf_run(nerf_run_dir)
  decoder = stylized_scenes.load_decoder(decoder_dir)  # refuses another encoder's, up front.
  box = config.scene_box or nerf_run.config.scene_box or nerf_lib.scene_box(scene)
  config = dataclasses.replace(config, nerf=nerf_run.config, scene_box=float(box))
  devices = data_parallel(n_devices, parallel)
  check_config(config, devices)
  cells = tuple(n // CELL for n in painted_size(scene.height, scene.width, config.stylize_scale))
  if config.decode_weight > 0 and config.decode_cells > min(cells):
    config_lib.bad_setting(config, "decode_cells", f"a patch wider than the views' "
                                                   f"{cells[0]} x {cells[1]} relu4_1 cells")
  record = {"config": config_lib.to_dict(config), "data": config_lib.to_dict(data),
            "nerf_run": os.path.abspath(nerf_run_dir), "decoder": os.path.abspath(decoder_dir)}
  distributed.check_same(record, "settings")

  def prepare():
    runs_lib.prepare_run_dir(run_dir, KIND, record, lock=True)
    prepare_targets(run_dir, scene, config, progress)
  distributed.primary_first(prepare)
  train_idx = scene.split("train")
  targets = jnp.asarray(load_targets(run_dir, len(train_idx), cells))
  pixels = None
  if config.decode_weight > 0 and config.decode_target == "photo":
    pixels = jnp.asarray(np.stack([stylize_lib.enlarged(v, config.stylize_scale)
                                   for v in scene.images[train_idx]]), jnp.float16)
  c2w = jnp.asarray(scene.c2w[train_idx])
  K, coeffs = jax.tree_util.tree_map(jnp.asarray, scene.cameras_of(train_idx))
  base_key = jax.random.PRNGKey(config.optim.seed)
  shape = (scene.height, scene.width, scene.focal)
  summary = loop_lib.fit(
      init_state(config, nerf_run.params), compile_train_step(config, devices, decoder),
      lambda step: sample_batch(jax.random.fold_in(base_key, step), targets, c2w, K, config,
                                scene.ndc, shape, scene.near, scene.far, coeffs, pixels),
      run_dir=run_dir, **loop_lib.bookkeeping(config.optim),
      parallel=devices, desc="features train",
      progress=progress, callback=callback,
      shown=("mse", "l1") + (("decode",) if config.decode_weight > 0 else ()))
  distributed.primary_first(write_rendered_stats, run_dir, scene, progress)
  return summary
