"""Training a multi-style NeRF on a stylized dataset, top to bottom: a trained NeRF's frozen trunk,
new style heads, a batch of pixels supervised in every style at once, MSE (plus, optionally, a
style loss on rendered patches), Adam on the heads."""

import dataclasses
import functools
import os
from typing import Any, Callable, Dict, Optional, Tuple

import jax
import jax.numpy as jnp
import numpy as np

from msnerf_jax.style import adain as adain_lib
from msnerf_jax.nerf.samplers import sampler_of
from msnerf_jax.kinds import multistyle as multistyle_kind
from msnerf_jax.kinds import runs as runs_lib
from msnerf_jax.core import config as config_lib
from msnerf_jax.core import distributed
from msnerf_jax.eval import metrics
from msnerf_jax.nerf import render as render_lib
from msnerf_jax.core import run_lock
from msnerf_jax.core.config import MultistyleConfig
from msnerf_jax.data.scene import Scene
from msnerf_jax.data.stylized import StylizedData, check_views
from msnerf_jax.core.errors import UserError
from msnerf_jax.models import vgg
from msnerf_jax.models.multistyle import MultistyleField, init_multistyle_params
from msnerf_jax.core.parallel import DataParallel, data_parallel
from msnerf_jax.train import loop as loop_lib
from msnerf_jax.train import nerf as nerf_lib
from msnerf_jax.train import state as state_lib

KIND = "multistyle"
FROZEN = "trunk"
GRID = "occupancy"


# ----------------------------------------------------------------------------- frozen trunk


def split_frozen(params) -> Tuple[Dict, Dict]:
  """(trainable, frozen): params {"coarse", "fine"} split into the heads and the `trunk`s;
  an occupancy grid (params["occupancy"], the grid sampler's) is frozen whole."""
  nets = {net: p for net, p in params.items() if net != GRID}
  trainable = {net: {k: v for k, v in p.items() if k != FROZEN} for net, p in nets.items()}
  frozen = {net: {FROZEN: p[FROZEN]} for net, p in nets.items()}
  if GRID in params:
    frozen[GRID] = params[GRID]
  return trainable, frozen


def merge(trainable, frozen) -> Dict:
  merged = {net: {**trainable[net], **frozen[net]} for net in trainable}
  if GRID in frozen:
    merged[GRID] = frozen[GRID]
  return merged


def frozen_mask(params):
  """True for every leaf under a `trunk` subtree (the optimizer's freeze mask)."""
  trainable, frozen = split_frozen(params)
  return merge(jax.tree_util.tree_map(lambda _: False, trainable),
               jax.tree_util.tree_map(lambda _: True, frozen))


def init_state(config: MultistyleConfig, nerf_params) -> state_lib.TrainState:
  """Heads freshly initialised, trunks copied from the NeRF run; Adam only on the heads."""
  params = init_multistyle_params(config, jax.random.PRNGKey(config.optim.seed), nerf_params)
  tx = state_lib.adam(state_lib.exponential_lr(config.optim), frozen=frozen_mask)
  return state_lib.create_state(params, tx)


# ----------------------------------------------------------------------------- the step


def patch_style_loss(field: MultistyleField, params, patches, styles, encoder,
                     config: MultistyleConfig, white_background: bool) -> jnp.ndarray:
  """AdaIN statistics loss between whole rendered patches and the targets' same patches.

  Each patch is rendered (fine network) in every style and encoded by the frozen VGG; the
  loss is adain.style_loss (channel means and stds over relu1_1 ... relu4_1) against the
  stylized views' pixels of that patch, averaged over patches and styles. The per-view
  stylizations disagree on where each stroke lies, so a per-pixel MSE pulls the renders
  towards their faded average; statistics over a patch ask for the strokes' contrast and
  colours without asking where they lie.

  Args:
    patches: {"rays": ray_bundle [P, S*S], "rgb": [P, S, S, M, 3] uint8, "random"}.
    styles: [M, style_dim]; encoder: `vgg.load_vgg_params()`.
  Returns: [] the loss.
  """
  n, s = patches["rgb"].shape[:2]
  m = styles.shape[0]
  flat = jax.tree_util.tree_map(lambda x: x.reshape(n * s * s, *x.shape[2:]),
                                {"rays": patches["rays"], "random": patches["random"]})
  out = render_lib.render_rays_styles(field, params, flat["rays"], styles, config.nerf,
                                      flat["random"], white_background)
  rendered = out["fine"]["rgb"].reshape(m * n, s, s, 3)
  target = jnp.moveaxis(patches["rgb"], 3, 0).reshape(m * n, s, s, 3).astype(jnp.float32) / 255.0
  encoder = jax.lax.stop_gradient(encoder)  # frozen: XLA drops its weight gradients.
  want = jax.lax.stop_gradient(adain_lib.style_stats(encoder, target))
  return adain_lib.style_loss(adain_lib.style_stats(encoder, rendered), want)


def loss_fn(trainable, frozen, batch, styles, encoder, config: MultistyleConfig,
            white_background: bool):
  """MSE of the coarse and fine renders (the grid sampler: its one level, over the rays
  whose samples fit) in every style against the stylized targets, plus
  config.style_weight x patch_style_loss when that weight is > 0.

  batch["rgb"]: [B, M, 3] uint8, pixel b of the training view in each of the M styles.
  The frozen trunks enter through stop_gradient, so no gradient is computed for them.
  """
  params = merge(trainable, jax.lax.stop_gradient(frozen))
  field = MultistyleField(config)
  out = render_lib.render_rays_styles(field, params, batch["rays"], styles, config.nerf,
                                      batch["random"], white_background)
  target = jnp.swapaxes(batch["rgb"], 0, 1).astype(jnp.float32) / 255.0  # [M, B, 3]
  complete = out["fine"].get("complete")
  mse = {level: nerf_lib.masked_mse(o["rgb"], target, complete) for level, o in out.items()}
  loss = sum(mse.values())
  stats = {**{f"mse_{level}": v for level, v in mse.items()},
           "psnr": metrics.mse_to_psnr(mse["fine"])}
  if config.style_weight > 0:
    stats["style"] = patch_style_loss(field, params, batch["patches"], styles, encoder, config,
                                      white_background)
    loss = loss + config.style_weight * stats["style"]
  return loss, {"loss": loss, **stats}


def train_step(state: state_lib.TrainState, batch, styles, encoder=None, *,
               config: MultistyleConfig, white_background: bool,
               axis_name: Optional[str] = None):
  """One Adam step on the style heads; the trunks come out bit-identical.

  Gradients are taken with respect to the trainable subtrees only; the optimizer's freeze
  mask gives the trunks no update and no state; and the trunks of the new params are the
  old arrays themselves (not old + 0), so they never change by a bit.
  """
  trainable, frozen = split_frozen(state.params)
  grads, stats = jax.grad(loss_fn, has_aux=True)(trainable, frozen, batch, styles, encoder,
                                                 config, white_background)
  if axis_name is not None:
    grads = jax.lax.pmean(grads, axis_name)
    stats = jax.lax.pmean(stats, axis_name)
  grads = merge(grads, jax.tree_util.tree_map(jnp.zeros_like, frozen))
  state = state.apply_gradients(grads=grads)
  return state.replace(params=merge(split_frozen(state.params)[0], frozen)), stats


def compile_train_step(config: MultistyleConfig, styles: np.ndarray, white_background: bool,
                       parallel: DataParallel, encoder=None) -> Callable:
  """train_step compiled for `parallel`'s devices, with the style vectors [M, 1024] (and,
  with a style loss, the VGG encoder's params) placed once on every device."""
  if config.style_weight > 0 and encoder is None:
    raise ValueError("a style loss needs the encoder's params (vgg.load_vgg_params())")
  constants = (jnp.asarray(styles, jnp.float32),) + ((encoder,) if config.style_weight > 0 else ())
  return parallel.compile(functools.partial(
      train_step, config=config, white_background=white_background), constants)


def sample_batch(key, images, c2w, K, config: MultistyleConfig, scene: Scene, coeffs=None):
  """A random batch of pixels of the training views, with their colour in every style.

  images: [N, H, W, M, 3] uint8; K, coeffs: as nerf's sample_batch. Returns {"rays" [B],
  "rgb" [B, M, 3] uint8, "random"}, plus "patches" (sample_patches) when
  config.style_weight > 0.
  """
  sampling = dataclasses.replace(config.nerf, batch_rays=config.batch_rays)
  batch = nerf_lib.sample_batch(key, images, c2w, K, sampling, False, scene.ndc,
                                (scene.height, scene.width, scene.focal), scene.near, scene.far,
                                coeffs=coeffs)
  if config.style_weight > 0:
    batch["patches"] = sample_patches(jax.random.fold_in(key, 1), images, c2w, K, config, scene,
                                      coeffs)
  return batch


def sample_patches(key, images, c2w, K, config: MultistyleConfig, scene: Scene, coeffs=None):
  """config.style_patches random S x S patches (S = config.style_patch) of random training
  views, whole, with their pixels in every style.

  images: [N, H, W, M, 3] uint8. Returns {"rays": ray_bundle [P, S*S] (row-major),
  "rgb": [P, S, S, M, 3] uint8, "random": draw_randomness [P, S*S, ...]}.
  """
  n_views, h, w = images.shape[:3]
  count, s = config.style_patches, config.style_patch
  k_img, k_row, k_col, k_rand = jax.random.split(key, 4)
  views = jax.random.randint(k_img, (count, 1, 1), 0, n_views)
  rows = jax.random.randint(k_row, (count, 1, 1), 0, h - s + 1) + jnp.arange(s)[:, None]
  cols = jax.random.randint(k_col, (count, 1, 1), 0, w - s + 1) + jnp.arange(s)
  views, rows, cols = jnp.broadcast_arrays(views, rows, cols)  # [P, S, S] each
  batch = nerf_lib.pixel_batch(k_rand, images, c2w, K, views.reshape(-1), rows.reshape(-1),
                               cols.reshape(-1), config.nerf, scene.ndc,
                               (scene.height, scene.width, scene.focal), scene.near, scene.far,
                               coeffs=coeffs)
  patches = jax.tree_util.tree_map(lambda x: x.reshape(count, s * s, *x.shape[1:]), batch)
  patches["rgb"] = batch["rgb"].reshape(count, s, s, *batch["rgb"].shape[1:])
  return patches


def check_style_loss(config: MultistyleConfig, scene: Scene, n_devices: int) -> None:
  """UserError unless the patch style loss settings fit the views and the devices."""
  if config.style_weight == 0:  # (its sign is MultistyleConfig.validate's)
    return
  if not 16 <= config.style_patch <= min(scene.height, scene.width):
    raise UserError(f"style patch {config.style_patch}: must be between 16 (VGG's relu4_1 "
                    f"needs 2x2) and the views' {min(scene.height, scene.width)} pixels")
  if config.style_patches < 1 or config.style_patches % n_devices:
    raise UserError(f"{config.style_patches} style patches per step do not split over "
                    f"{n_devices} devices")


# ----------------------------------------------------------------------------- inputs


def load_nerf_run(nerf_run_dir: str) -> Tuple[runs_lib.Run, Scene, config_lib.DataConfig]:
  """A trained NeRF run and its scene (load_run already checks the params against the
  run's architecture)."""
  run = runs_lib.load_run(nerf_run_dir, "nerf")
  return (run, *runs_lib.scene_of(run))


def check_compatible(stylized: StylizedData, scene: Scene, nerf_run_dir: str) -> None:
  """UserError unless the stylized dataset has the NeRF run's views: sizes and poses."""
  n, h, w = stylized.images.shape[1:4]
  check_views(stylized.path, n, h, w, stylized.c2w, scene, f"the NeRF run {nerf_run_dir}")


# ----------------------------------------------------------------------------- the loop


@run_lock.released_after
def train(config: MultistyleConfig, nerf_run_dir: str, stylized: StylizedData, run_dir: str,
          n_devices: Optional[int] = None, progress: bool = True,
          callback: Optional[Callable[[int, Any], None]] = None, parallel: str = "shard_map"
          ) -> Dict[str, Any]:
  """Trains (or resumes) a multi-style NeRF in `run_dir` from a NeRF run and a stylized dataset.

  `config.nerf` is replaced by the NeRF run's config. Devices and processes as nerf.train's
  (`n_devices`, `parallel`). Returns the loop's summary dict.
  """
  nerf_run, scene, data = load_nerf_run(nerf_run_dir)
  config = dataclasses.replace(config, nerf=nerf_run.config).validate()
  if config.density_aware and sampler_of(config.nerf).occupancy:
    raise UserError(f"{nerf_run_dir}: a density-aware model needs a NeRF run with the "
                    "hierarchical sampler (this one samples from its occupancy grid, which "
                    "cannot follow a density per style)")
  check_compatible(stylized, scene, nerf_run_dir)
  devices = data_parallel(n_devices, parallel)
  nerf_lib.check_batch_splits(config.batch_rays, devices)
  check_style_loss(config, scene, devices.size)
  record = {"config": config_lib.to_dict(config), "data": config_lib.to_dict(data),
            "nerf_run": os.path.abspath(nerf_run_dir), "stylized": os.path.abspath(stylized.path),
            "styles": list(stylized.names)}
  distributed.check_same(record, "settings")

  def prepare():
    runs_lib.prepare_run_dir(run_dir, KIND, record, lock=True)
    multistyle_kind.save_style_vectors(run_dir, stylized.vectors)
  distributed.primary_first(prepare)
  train_idx = stylized.splits["train"]
  # [N, H, W, M, 3] uint8: one gather gives a pixel in every style.
  images = jnp.asarray(np.moveaxis(stylized.images[:, train_idx], 0, 3))
  c2w = jnp.asarray(scene.c2w[train_idx])
  K, coeffs = jax.tree_util.tree_map(jnp.asarray, scene.cameras_of(train_idx))
  base_key = jax.random.PRNGKey(config.optim.seed)
  encoder = vgg.load_vgg_params() if config.style_weight > 0 else None
  step_fn = compile_train_step(config, stylized.vectors, scene.white_background, devices,
                               encoder)
  return loop_lib.fit(
      init_state(config, nerf_run.params), step_fn,
      lambda step: sample_batch(jax.random.fold_in(base_key, step), images, c2w, K, config, scene,
                                coeffs),
      run_dir=run_dir, **loop_lib.bookkeeping(config.optim),
      parallel=devices, desc="multistyle train",
      progress=progress, callback=callback)
