"""Training a vanilla NeRF, top to bottom: batch -> coarse/fine render -> MSE -> Adam."""

import dataclasses
import functools
from typing import Any, Callable, Dict, Optional

import jax
import jax.numpy as jnp
import numpy as np

from msnerf_jax.kinds import runs
from msnerf_jax.nerf.field_samples import apply_in_chunks
from msnerf_jax.nerf.samplers import sampler_of
from msnerf_jax.core import config as config_lib
from msnerf_jax.core import distributed
from msnerf_jax.eval import metrics
from msnerf_jax.nerf import occupancy
from msnerf_jax.nerf import rays as rays_lib
from msnerf_jax.nerf import regularizers
from msnerf_jax.nerf import render as render_lib
from msnerf_jax.core import run_lock
from msnerf_jax.core.config import DataConfig, NerfConfig
from msnerf_jax.data.scene import Scene
from msnerf_jax.core.errors import UserError
from msnerf_jax.models.nerf import NerfField, init_nerf_params
from msnerf_jax.core.parallel import DataParallel, data_parallel
from msnerf_jax.train import loop as loop_lib
from msnerf_jax.train import state as state_lib


# ----------------------------------------------------------------------------- batches


@functools.partial(jax.jit, static_argnames=("config", "precrop", "ndc", "shape"))
def sample_batch(key, images, c2w, K, config: NerfConfig, precrop: bool, ndc: bool,
                 shape, near: float, far: float, alphas=None, coeffs=None):
  """A random global batch of training rays with their target colours and randomness.

  Args:
    images: [N, H, W, 3] training images; c2w: [N, 3, 4]; K: [3, 3] shared or [N, 3, 3]
      per view; coeffs: [N, 5] lens distortion per view (msnerf_jax.nerf.cameras) or None.
    precrop: draw pixels only from the central precrop_frac of each image.
    shape: (H, W, focal) static for the NDC warp.
    alphas: [N, H, W] uint8 opacity of the images (composited over white): given, every
      ray gets a random background colour (see pixel_batch); None: the images as they are.
  Returns:
    {"rays": ray_bundle [B], "rgb": [B, 3], "random": draw_randomness [B, ...]}, plus
    "background" [B, 3] with alphas.
  """
  n, h, w = images.shape[:3]
  k_img, k_row, k_col, k_rand = jax.random.split(key, 4)
  b = config.batch_rays
  idx = jax.random.randint(k_img, (b,), 0, n)
  if precrop:
    dh, dw = int(h // 2 * config.precrop_frac), int(w // 2 * config.precrop_frac)
    rows = jax.random.randint(k_row, (b,), h // 2 - dh, h // 2 + dh)
    cols = jax.random.randint(k_col, (b,), w // 2 - dw, w // 2 + dw)
  else:
    rows = jax.random.randint(k_row, (b,), 0, h)
    cols = jax.random.randint(k_col, (b,), 0, w)
  return pixel_batch(k_rand, images, c2w, K, idx, rows, cols, config, ndc, shape, near, far,
                     alphas, coeffs)


def pixel_batch(key, images, c2w, K, idx, rows, cols, config: NerfConfig, ndc: bool, shape,
                near: float, far: float, alphas=None, coeffs=None):
  """Chosen training pixels as a batch: idx, rows, cols [B] (view, row, column of each).

  Returns {"rays": ray_bundle [B], "rgb": images[idx, rows, cols], "random":
  draw_randomness [B] from `key`}. With `alphas` [N, H, W] uint8 (the images' opacity, the
  images composited over white), also "background" [B, 3]: uniform random colours drawn
  from `key` (a stream of their own, so the other draws stay as without them), and "rgb" is
  the photo composited over them instead: c a + bg (1 - a) = image + (1 - a) (bg - 1).
  """
  origins, directions = rays_lib.pixel_rays(K[idx] if K.ndim == 3 else K, c2w[idx], rows, cols,
                                            None if coeffs is None else coeffs[idx])
  rays = rays_lib.ray_bundle(origins, directions, near, far, ndc, shape[0], shape[1], shape[2])
  batch = {"rays": rays, "rgb": images[idx, rows, cols],
           "random": render_lib.draw_randomness(key, idx.shape[0], config)}
  if alphas is not None:
    alpha = alphas[idx, rows, cols][:, None].astype(jnp.float32) / 255.0
    background = jax.random.uniform(jax.random.fold_in(key, 1), (idx.shape[0], 3))
    batch["rgb"] = batch["rgb"] + (1.0 - alpha) * (background - 1.0)
    batch["background"] = background
  return batch


# ----------------------------------------------------------------------------- the step


def masked_mse(rgb, target, mask=None):
  """Mean squared error of colours [..., R, 3]; with mask [R] bool, over the masked rays
  only."""
  if mask is None:
    return jnp.mean((rgb - target) ** 2)
  err = jnp.sum((rgb - target) ** 2, -1)  # [..., R]
  per_ray = err.size // mask.size
  return (jnp.sum(jnp.where(mask, err, 0.0))
          / (3.0 * per_ray * jnp.maximum(jnp.sum(mask), 1)))


def distortion_loss(out, rays):
  """Mean distortion loss (regularizers) of render_rays' outputs: summed over the levels
  (coarse and fine), or with the occupancy-grid sampler (packed outputs) of its samples over
  the rays whose samples fit the budget."""
  fine = out["fine"]
  if "sample_interval" in fine:
    per_ray = regularizers.distortion_packed(fine["weights"], fine["sample_interval"],
                                             fine["sample_ray"], rays["near"], rays["far"])
    complete = fine["complete"]
    return jnp.sum(jnp.where(complete, per_ray, 0.0)) / jnp.maximum(jnp.sum(complete), 1)
  return sum(jnp.mean(regularizers.distortion(level["weights"], level["z_vals"], rays["near"],
                                              rays["far"])) for level in out.values())


def loss_fn(params, batch, config: NerfConfig, white_background: bool):
  """MSE of the coarse and the fine renders against the target colours (NeRF eq. 6); with
  the occupancy-grid sampler, of its one level over the rays whose samples fit the budget.

  A batch with "background" [B, 3] is rendered over those colours (random backgrounds).
  With config.distortion_weight > 0, adds that weight times the mean distortion loss
  (distortion_loss).
  """
  out = render_lib.render_rays(NerfField(config), params, batch["rays"], config,
                               batch["random"], white_background, batch.get("background"))
  complete = out["fine"].get("complete")
  mse = {level: masked_mse(o["rgb"], batch["rgb"], complete) for level, o in out.items()}
  loss = sum(mse.values())
  stats = {**{f"mse_{level}": v for level, v in mse.items()},
           "psnr": metrics.mse_to_psnr(mse["fine"])}
  if complete is not None:
    stats["complete"] = jnp.mean(complete.astype(jnp.float32))
  if config.distortion_weight > 0:
    stats["distortion"] = distortion_loss(out, batch["rays"])
    loss = loss + config.distortion_weight * stats["distortion"]
  return loss, {"loss": loss, **stats}


REFRESH_CHUNK = 65536  # points per field call of a grid refresh (forward only).


def refresh_grid(params, step, config: NerfConfig):
  """params with params["occupancy"] refreshed from the fine field's density when `step`
  (traced) is a multiple of config.grid_every (every cell during config.grid_warmup steps,
  a random quarter after it); the randomness is a pure function of (seed, step), so every
  device and process computes the same grid."""
  field = NerfField(config)

  def density(points):
    _, sigma = apply_in_chunks(field, params["fine"], points[:, None],
                                          jnp.zeros_like(points)[:, None], REFRESH_CHUNK)
    return jax.nn.relu(sigma[:, 0])

  key = jax.random.fold_in(jax.random.fold_in(jax.random.PRNGKey(config.optim.seed), step), 7)
  grid = params["occupancy"]
  refresh = lambda all_cells: lambda: occupancy.update_grid(grid, density, key, config,
                                                            all_cells)
  new = jax.lax.cond(step % config.grid_every == 0,
                     lambda: jax.lax.cond(step < config.grid_warmup, refresh(True),
                                          refresh(False)),
                     lambda: grid)
  return {**params, "occupancy": new}


def train_step(state: state_lib.TrainState, batch, config: NerfConfig,
               white_background: bool, axis_name: Optional[str] = None):
  """One optimizer step on a batch; with an `axis_name`, gradients are averaged across it.
  With the occupancy-grid sampler, the grid is then refreshed (refresh_grid).

  The same function runs under jax.jit (axis_name=None), or per device under jax.shard_map
  or jax.pmap (axis_name="batch"): see msnerf_jax.core.parallel.
  """
  grads, stats = jax.grad(loss_fn, has_aux=True)(state.params, batch, config, white_background)
  if axis_name is not None:
    grads = jax.lax.pmean(grads, axis_name)
    stats = jax.lax.pmean(stats, axis_name)
  new = state.apply_gradients(grads=grads)
  if "occupancy" in new.params:
    new = new.replace(params=refresh_grid(new.params, state.step, config))
  return new, stats


@functools.lru_cache(maxsize=8)
def compile_train_step(config: NerfConfig, white_background: bool, parallel: DataParallel):
  """train_step compiled for `parallel`'s devices (DataParallel.compile); the state is
  donated. Cached per (config, background, parallel), so resuming in one process compiles
  once."""
  return parallel.compile(functools.partial(train_step, config=config,
                                            white_background=white_background))


def not_trained(params):
  """The optimizer's freeze mask of a NeRF: the occupancy grid (rewritten by the step, not
  by gradients) when there is one."""
  return {k: jax.tree_util.tree_map(lambda _: k == "occupancy", v) for k, v in params.items()}


def init_state(config: NerfConfig) -> state_lib.TrainState:
  params = init_nerf_params(config, jax.random.PRNGKey(config.optim.seed))
  schedule = state_lib.exponential_lr(config.optim)
  if sampler_of(config).occupancy:  # instant-NGP's Adam: beta2 0.99, eps 1e-15.
    return state_lib.create_state(params, state_lib.adam(schedule, not_trained, b2=0.99,
                                                         eps=1e-15))
  return state_lib.create_state(params, state_lib.adam(schedule))


# ----------------------------------------------------------------------------- the loop


def scene_box(scene: Scene) -> float:
  """Half side of a box centred at the origin that holds the scene: Blender scenes 1.5
  (instant-NGP's box of the synthetic objects), NDC scenes 1.5 (the NDC cube of the
  reference view, with room for the other views' frustums: fern's reach |x| = 1.35), other
  captures the farthest camera's distance from the origin (the cameras surround what they
  film)."""
  if scene.ndc or scene.format == "blender":
    return 1.5
  return float(np.max(np.linalg.norm(np.asarray(scene.c2w)[:, :3, 3], axis=-1)))


def resolve_config(config: NerfConfig, scene: Scene) -> NerfConfig:
  """The config with what depends on the scene filled in (scene_box 0 -> scene_box(scene)
  when the hash trunk or the grid sampler uses it), checked (NerfConfig.validate)."""
  if config.scene_box == 0 and (config.trunk == "hash" or sampler_of(config).occupancy):
    config = dataclasses.replace(config, scene_box=scene_box(scene))
  config.validate()
  return config


def check_batch_splits(batch_rays: int, parallel: DataParallel) -> None:
  """UserError unless the global batch splits evenly over the devices."""
  if batch_rays % parallel.size:
    raise UserError(f"batch of {batch_rays} rays does not split over {parallel.size} devices")


@run_lock.released_after
def train(scene: Scene, config: NerfConfig, data_config: DataConfig, run_dir: str,
          n_devices: Optional[int] = None, progress: bool = True,
          callback: Optional[Callable[[int, Any], None]] = None,
          style: Optional[Dict[str, str]] = None, parallel: str = "shard_map"
          ) -> Dict[str, Any]:
  """Trains (or resumes) a NeRF run in `run_dir`; returns a summary dict.

  `style` ({"stylized": dataset folder, "name": style}) records that the scene's images are
  one style's stylized views (data.stylized.style_views), so that loading the run
  (runs.scene_of) reloads those views: the single-style NeRF baseline.

  Checkpoints every config.optim.checkpoint_every steps and at the end; re-running with the same
  settings resumes from the latest complete checkpoint. A NaN/inf loss stops training with
  a UserError naming the step; the last good checkpoint stays the latest one.
  `callback(step, params)` runs after every checkpoint (benchmarks evaluate there); its
  time is not counted in the summary's training seconds.

  `n_devices` (default: all) and `parallel` ("shard_map" or "pmap") choose the devices:
  parallel.data_parallel. After msnerf_jax.core.distributed.initialize, every process calls
  this with the same arguments and the step spans all their devices; process 0 writes.
  """
  config = resolve_config(config, scene)
  devices = data_parallel(n_devices, parallel)
  check_batch_splits(config.batch_rays, devices)
  record = {"config": config_lib.to_dict(config), "data": config_lib.to_dict(data_config)}
  if style is not None:
    record["style"] = dict(style)
  if config.random_background and scene.alphas is None:
    raise UserError(f"{data_config.path}: random backgrounds need images with an alpha "
                    f"channel (a Blender RGBA scene); this {scene.format} scene has none: "
                    "train with --no-random-background (and --distortion-weight against "
                    "floaters)")
  distributed.check_same(record, "settings")
  distributed.primary_first(runs.prepare_run_dir, run_dir, "nerf", record, lock=True)
  train_idx = scene.split("train")
  images = jnp.asarray(scene.images[train_idx])
  alphas = jnp.asarray(scene.alphas[train_idx]) if config.random_background else None
  c2w = jnp.asarray(scene.c2w[train_idx])
  K, coeffs = jax.tree_util.tree_map(jnp.asarray, scene.cameras_of(train_idx))
  base_key = jax.random.PRNGKey(config.optim.seed)
  shape = (scene.height, scene.width, scene.focal)

  def batch_fn(step):  # per-step key: resuming replays the same batches.
    return sample_batch(jax.random.fold_in(base_key, step), images, c2w, K, config,
                        step < config.precrop_steps, scene.ndc, shape, scene.near, scene.far,
                        alphas, coeffs)

  return loop_lib.fit(init_state(config), compile_train_step(config, scene.white_background,
                                                             devices),
                      batch_fn, run_dir=run_dir, **loop_lib.bookkeeping(config.optim),
                      parallel=devices,
                      desc="nerf train", progress=progress, callback=callback)
