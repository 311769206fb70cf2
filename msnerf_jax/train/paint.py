"""Painting colour fields on a NeRF run's frozen geometry, top to bottom: the views' sample
lists cached once (nerf.sample_cache; the training views, then cameras along the scene's
render path, whose photo-real NeRF renders stand in for photos), each step a batch of
(view, style) pairs rendered from the cache (a gather and a segment sum: no trunk
evaluation), fitted first to the photos colour-transferred to the style (MSE), then with a
style loss on the whole rendered views (style.painting_loss: NNFM or AdaIN statistics,
content, total variation); Adam on the colour grids alone. No per-view pixel target is used
after the first init_steps, so views cannot disagree: one 3D texture serves them all. The
grid is fitted to what the views see (train/paint_grid.py), the colours start at the
photos lifted into 3D, and after every step the vertices no view sees take the colour of
the nearest one that is seen (train/paint_coverage.py)."""

import dataclasses
import functools
import os
import zlib
from typing import Any, Callable, Dict, List, Optional, Sequence, Tuple

import jax
import jax.numpy as jnp
import numpy as np

from msnerf_jax.core import config as config_lib
from msnerf_jax.core import distributed, run_lock
from msnerf_jax.core.checkpoint import Checkpoints
from msnerf_jax.core.config import PaintConfig
from msnerf_jax.core.errors import UserError
from msnerf_jax.core.files import write_json
from msnerf_jax.core.parallel import DataParallel, data_parallel
from msnerf_jax.kinds import runs as runs_lib
from msnerf_jax.kinds.painted import NAME as KIND, save_style_images
from msnerf_jax.models.painted_field import init_painted_params, trilinear
from msnerf_jax.nerf import sample_cache
from msnerf_jax.style import painting_loss
from msnerf_jax.style.transfer import apply_colour_map
from msnerf_jax.train import loop as loop_lib
from msnerf_jax.train import paint_grid
from msnerf_jax.train.paint_data import (CACHE_FILE, cache_source, constants, index_of,
                                         load_or_build_cache, painting_views, read_cache,
                                         read_styles, starting_colours, style_maps,
                                         style_name, style_size)
from msnerf_jax.train import multistyle as multistyle_lib
from msnerf_jax.train import nerf as nerf_lib
from msnerf_jax.train import state as state_lib

FROZEN, TRAINED = "nerf", "paint"  # params {"nerf": the NeRF run's, "paint": {"colours", "index"}}.


# ----------------------------------------------------------------------------- state


def frozen_mask(params):
  """True for every leaf of the NeRF and for the paint index (the optimizer's freeze mask:
  only the colours train)."""
  return {FROZEN: jax.tree_util.tree_map(lambda _: True, params[FROZEN]),
          TRAINED: {"colours": False, "index": True}}


def init_state(config: PaintConfig, nerf_params, n_styles: int, index: np.ndarray,
               count: int, colours: Optional[np.ndarray] = None) -> state_lib.TrainState:
  """Colours for `n_styles` styles at the `count` painted vertices of `index`
  (painted_field.paint_index): the logits `colours` [M, V + 1, 3] (e.g.
  paint_data.starting_colours'), or grey; beside a copy of the NeRF's params; Adam on the
  colours only (the NeRF and the index get no optimizer state)."""
  paint = init_painted_params(n_styles, index, count)
  if colours is not None:
    paint["colours"] = jnp.asarray(colours, jnp.float32).reshape(paint["colours"].shape)
  params = {FROZEN: jax.tree_util.tree_map(jnp.array, nerf_params), TRAINED: paint}
  tx = state_lib.adam(state_lib.exponential_lr(config.optim), frozen=frozen_mask)
  return state_lib.create_state(params, tx)


# ----------------------------------------------------------------------------- the step


def style_colour(paint_params, style, bound: float):
  """points [P, 3] -> colours [P, 3] of one style (an index into paint_params["colours"])."""
  table = paint_params["colours"][style][None]
  return lambda points: jax.nn.sigmoid(trilinear(table, paint_params["index"], points,
                                                 bound))[0]


def render_pairs(paint_params, cache, views: jnp.ndarray, styles: jnp.ndarray, bound: float,
                 background: jnp.ndarray) -> jnp.ndarray:
  """Training views `views` [B] rendered from their cached samples, each in its style
  `styles` [B] (paint_params {"colours" [M, V + 1, 3], "index"}): [B, n, 3] (n pixels of a
  view)."""
  def one(view, style):
    lists = {k: cache[k][view] for k in ("points", "weights", "pixel", "accumulation")}
    return sample_cache.cached_render(style_colour(paint_params, style, bound), lists,
                                      background)
  return jax.vmap(one)(views, styles)


def photo_targets(consts, views: jnp.ndarray, styles: jnp.ndarray, white_background: bool
                  ) -> jnp.ndarray:
  """The photos of `views` with their colours moved to `styles`' ([B, H, W, 3]); on
  white-background scenes put back over white by the cached opacity."""
  maps = consts["maps"]
  moved = jax.vmap(apply_colour_map)(consts["photos"][views], maps["transform"][styles],
                                     maps["mu_s"][styles], maps["mu_t"][styles])
  if not white_background:
    return moved
  acc = consts["cache"]["accumulation"][views].reshape(moved.shape[:3])[..., None]
  return moved * acc + (1.0 - acc)


def render_crops(paint_params, consts, batch, crop: int, band: int, bound: float
                 ) -> jnp.ndarray:
  """The crops [B, crop, crop, 3] of batch's pairs ("view", "style", "top", "left"), each
  rendered from the samples of its own pixels alone: the cached lists are sorted by pixel,
  so each of a crop's rows is one run of at most `band` samples, starting where its first
  pixel's do (consts["pixel_start"] [N, H * W + 1])."""
  cache, width = consts["cache"], consts["photos"].shape[2]
  size = cache["weights"].shape[1]
  rows = jnp.arange(crop)

  def one(view, style, top, left):
    first = (top + rows) * width + left  # [crop] the rows' first pixels
    at = consts["pixel_start"][view, first][:, None] + jnp.arange(band)  # [crop, band]
    inside = at < size
    at = jnp.minimum(at, size - 1)
    column = cache["pixel"][view][at] - first[:, None]
    inside &= (column >= 0) & (column < crop)
    pixels = (rows[:, None] * crop + column).reshape(-1)
    lists = {"points": cache["points"][view][at].reshape(-1, 3),
             "weights": jnp.where(inside, cache["weights"][view][at], 0.0).reshape(-1),
             "pixel": jnp.where(inside.reshape(-1), pixels, 0),
             "accumulation": cache["accumulation"][view][
                 (first[:, None] + rows).reshape(-1)]}
    image = sample_cache.cached_render(style_colour(paint_params, style, bound), lists,
                                       consts["background"])
    return image.reshape(crop, crop, 3)
  return jax.vmap(one)(batch["view"], batch["style"], batch["top"], batch["left"])


def loss_fn(colours, index, batch, consts, config: PaintConfig, white_background: bool,
            init: bool, band: int = 0):
  """The loss of a batch of (view, style) pairs and its terms (means over the pairs): with
  `init` (the first init_steps) the MSE to photo_targets, else style_weight x (NNFM or
  AdaIN) + content_weight x content + tv_weight x total variation
  (painting_loss.painting_losses). With config.crop, each pair is its crop (render_crops,
  `band` samples). The loss is the sum over the pairs divided by views_per_style: each
  style's colours get the gradient of the mean over their own pairs alone, whatever the
  other styles and the devices are."""
  views, styles = batch["view"], batch["style"]
  shape = consts["photos"].shape[1:]
  paint_params = {"colours": colours, "index": index}
  photos = jax.lax.stop_gradient(photo_targets(consts, views, styles, white_background))
  if config.crop:
    renders = render_crops(paint_params, consts, batch, config.crop, band, config.scene_box)
    crop = lambda x, top, left: jax.lax.dynamic_slice(x, (top, left, 0),
                                                      (config.crop, config.crop, 3))
    photos = jax.vmap(crop)(photos, batch["top"], batch["left"])
  else:
    renders = render_pairs(paint_params, consts["cache"], views, styles, config.scene_box,
                           consts["background"]).reshape(-1, *shape)
  terms = {"mse": jnp.mean(jnp.square(renders - photos), (1, 2, 3))}
  if init:  # (the style terms as zeros: both programs give the same statistics)
    per_pair = terms["mse"]
    terms.update({k: jnp.zeros_like(per_pair) for k in ("nnfm", "adain", "content", "tv")})
  else:
    targets = jax.tree_util.tree_map(lambda x: x[styles], consts["targets"])
    terms.update(painting_loss.painting_losses(consts["encoder"], renders, photos, targets))
    per_pair = (config.style_weight * terms[config.style_loss]
                + config.content_weight * terms["content"] + config.tv_weight * terms["tv"])
  loss = jnp.sum(per_pair) / config.views_per_style
  return loss, {"loss": jnp.mean(per_pair), **{k: jnp.mean(v) for k, v in terms.items()}}


def train_step(state: state_lib.TrainState, batch, consts, *, config: PaintConfig,
               white_background: bool, init: bool, band: int = 0,
               axis_name: Optional[str] = None):
  """One Adam step on the colours, then every vertex the training views do not see takes
  the colour of the nearest one they see (consts["fill"]); the NeRF and the index come out
  bit-identical (passed through). The devices' gradients are summed (each holds other
  pairs: loss_fn's sum), so a step does not depend on how the pairs are split."""
  params = state.params
  paint = params[TRAINED]
  grads, stats = jax.grad(loss_fn, has_aux=True)(paint["colours"], paint["index"], batch,
                                                 consts, config, white_background, init, band)
  if axis_name is not None:
    grads = jax.lax.psum(grads, axis_name)
    stats = jax.lax.pmean(stats, axis_name)
  zeros = jax.tree_util.tree_map(jnp.zeros_like, params[FROZEN])
  state = state.apply_gradients(grads={FROZEN: zeros, TRAINED: {
      "colours": grads, "index": jnp.zeros_like(paint["index"])}})
  trained = {"colours": state.params[TRAINED]["colours"][:, consts["fill"]],
             "index": paint["index"]}
  return state.replace(params={FROZEN: params[FROZEN], TRAINED: trained}), stats


def compile_train_step(config: PaintConfig, consts, parallel: DataParallel,
                       white_background: bool) -> Callable:
  """The placed (state, batch) -> (state, stats) step: two compiled programs, the init fit
  and the style loss, chosen on the host by the batch's "init" flag (a lax.cond between them
  measured 2x slower on the CPU)."""
  band = consts.pop("band", 0)
  steps = {init: parallel.compile(functools.partial(
      train_step, config=config, white_background=white_background, init=init, band=band),
                                  (consts,)) for init in (True, False)}
  def step(state, batch):
    init = bool(np.asarray(jax.device_get(batch["init"])).reshape(-1)[0])
    return steps[init](state, batch)
  return step


def batch_of(step: int, config: PaintConfig, n_views: int, names: Sequence[str],
             size: Tuple[int, int] = (0, 0)) -> Dict[str, Any]:
  """The (view, style) pairs of a step, style-major: every style views_per_style times,
  each with random training views (and, with config.crop, a random crop of the views'
  `size` (H, W)) drawn from a key of the step and the style's name (a pure function of
  them, so a resumed run replays it, and a style's pairs do not depend on the other styles
  of the run); "init" marks the init fit's steps."""
  key = jax.random.fold_in(jax.random.PRNGKey(config.optim.seed), step)
  v, n_styles = config.views_per_style, len(names)
  keys = [jax.random.fold_in(key, zlib.crc32(name.encode()) & 0x7FFFFFFF) for name in names]
  views = [np.asarray(jax.random.randint(k, (v,), 0, n_views)) for k in keys]
  batch = {"view": np.concatenate(views).astype(np.int32),
           "style": np.repeat(np.arange(n_styles, dtype=np.int32), v),
           "init": np.full((n_styles * v,), step < config.init_steps)}
  if config.crop:
    high = np.asarray([size[0] - config.crop + 1, size[1] - config.crop + 1])
    corner = np.concatenate([np.asarray(jax.random.randint(
        jax.random.fold_in(k, 1), (v, 2), 0, high)) for k in keys]).astype(np.int32)
    batch["top"], batch["left"] = corner[:, 0], corner[:, 1]
  return batch


# ----------------------------------------------------------------------------- checks


def check_config(config: PaintConfig, n_styles: int, parallel: DataParallel, scene) -> None:
  """UserError naming what cannot work: PaintConfig.validate, then what depends on the
  styles, the devices and the views' size."""
  config.validate()
  if config.crop > min(scene.height, scene.width):
    config_lib.bad_setting(config, "crop", f"larger than the {scene.width}x{scene.height} "
                                           "views")
  if (n_styles * config.views_per_style) % parallel.size:
    raise UserError(f"{n_styles} styles x {config.views_per_style} views per style do not "
                    f"split over {parallel.size} devices")


# ----------------------------------------------------------------------------- the loop


def saved_grid(run_dir: str, config: PaintConfig) -> PaintConfig:
  """`config` with its fitted settings (scene_box, resolution, style_size 0) taken from the
  painted run already in `run_dir`, if any: a resumed run keeps the grid it was fitted to
  and its style size, and its run.json (which holds the fitted values) still matches the
  options it was started with."""
  try:
    saved = runs_lib.read_run_file(run_dir)
  except (UserError, OSError):
    return config  # no run there yet (prepare_run_dir reports what else is wrong)
  if saved.get("kind") != KIND or not isinstance(saved.get("config"), dict):
    return config
  return dataclasses.replace(
      config, scene_box=config.scene_box or float(saved["config"].get("scene_box", 0.0)),
      resolution=config.resolution or int(saved["config"].get("resolution", 0)),
      style_size=config.style_size or int(saved["config"].get("style_size", 0)))


def grid_and_vertices(run_dir: str, cache, config: PaintConfig, width: int, limit: float
                      ) -> Tuple[PaintConfig, np.ndarray, int]:
  """(config with its grid resolved (paint_grid.fit over the painting's views' `cache`),
  index, V): a resumed run's painted vertices are its checkpoint's (whichever version chose
  them), a new run's paint_data.index_of."""
  checkpoints = Checkpoints(run_dir)
  try:
    saved = (checkpoints.restore()["params"][TRAINED]
             if checkpoints.latest_step() is not None else None)
  finally:
    checkpoints.close()
  config = paint_grid.fit(config, cache, width, limit)
  if saved is not None:
    return config, np.asarray(saved["index"]), int(saved["colours"].shape[1]) - 1
  return (config, *index_of(cache, config))


def record_grid(run_dir: str, config: PaintConfig) -> None:
  """run.json's config with the fitted grid (the primary process writes it)."""
  if not distributed.is_primary():
    return
  record = runs_lib.read_run_file(run_dir)
  if record["config"] != config_lib.to_dict(config):
    record["config"] = config_lib.to_dict(config)
    write_json(os.path.join(run_dir, runs_lib.RUN_FILE), record)


@run_lock.released_after
def train(config: PaintConfig, nerf_run_dir: str, style_paths: Sequence[str], run_dir: str,
          n_devices: Optional[int] = None, progress: bool = True,
          callback: Optional[Callable[[int, Any], None]] = None, parallel: str = "shard_map"
          ) -> Dict[str, Any]:
  """Paints (or resumes painting) the styles `style_paths` on a NeRF run's frozen geometry
  in `run_dir`. `config.nerf` becomes the NeRF run's config; a scene_box or resolution of 0
  is fitted to what the painting's views see (paint_grid.fit), a style_size of 0 to the
  views (`style_size`); run.json holds the values.
  Devices and processes as nerf.train's. Returns the loop's summary dict."""
  names = [style_name(p) for p in style_paths]
  nerf_run, scene, data = multistyle_lib.load_nerf_run(nerf_run_dir)
  limit = nerf_run.config.scene_box or nerf_lib.scene_box(scene)
  config = saved_grid(run_dir, dataclasses.replace(config, nerf=nerf_run.config))
  config = dataclasses.replace(config, style_size=style_size(config, scene))
  styles = read_styles(style_paths, config.style_size)
  devices = data_parallel(n_devices, parallel)
  check_config(config, len(names), devices, scene)
  record = {"config": config_lib.to_dict(config), "data": config_lib.to_dict(data),
            "nerf_run": os.path.abspath(nerf_run_dir), "styles": names,
            "style_files": [os.path.abspath(p) for p in style_paths]}
  distributed.check_same(record, "settings")
  read_cache(os.path.join(run_dir, CACHE_FILE), cache_source(nerf_run))  # before any write
  holder: List[Dict[str, np.ndarray]] = []

  def prepare():
    runs_lib.prepare_run_dir(run_dir, KIND, record, lock=True)
    save_style_images(run_dir, styles)
    holder.append(load_or_build_cache(run_dir, scene, nerf_run, config, progress))
  distributed.primary_first(prepare)
  cache = holder.pop() if holder else load_or_build_cache(run_dir, scene, nerf_run, config,
                                                          False)
  cache, photos = painting_views(cache, scene, nerf_run, config)
  config, index, count = grid_and_vertices(run_dir, cache, config, scene.width, limit)
  record_grid(run_dir, config)
  maps = style_maps(scene, cache, photos, styles, config)
  fill, start = starting_colours(cache, photos, maps, index, count, config.scene_box)
  consts = constants(scene, cache, photos, styles, config, fill, maps)
  n_views = len(photos)
  del cache, photos  # the steps read the constants' copies
  summary = loop_lib.fit(
      init_state(config, nerf_run.params, len(names), index, count, start),
      compile_train_step(config, consts, devices, scene.white_background),
      lambda i: batch_of(i, config, n_views, names, (scene.height, scene.width)),
      run_dir=run_dir, **loop_lib.bookkeeping(config.optim),
      parallel=devices, desc="paint train",
      progress=progress, callback=callback, shown=("mse", config.style_loss, "content"))
  if distributed.is_primary():
    runs_lib.write_summary(run_dir, {k: summary[k] for k in ("steps", "resumed_from",
                                                             "seconds", "devices")})
  return summary
