"""Painting colour fields on a NeRF run's frozen geometry, top to bottom: the training views'
sample lists cached once (nerf.sample_cache), each step a batch of (training view, style)
pairs rendered from the cache (a gather and a segment sum: no trunk evaluation), fitted
first to the photos colour-transferred to the style (MSE), then with a style loss on the
whole rendered views (style.painting_loss: NNFM or AdaIN statistics, content, total
variation); Adam on the colour grids alone. No per-view pixel target is used after the
first init_steps, so views cannot disagree: one 3D texture serves them all."""

import dataclasses
import functools
import os
from typing import Any, Callable, Dict, List, Optional, Sequence

import jax
import jax.numpy as jnp
import numpy as np

from msnerf_jax.core import config as config_lib
from msnerf_jax.core import distributed, run_lock
from msnerf_jax.core.config import PaintConfig
from msnerf_jax.core.errors import UserError
from msnerf_jax.core.files import atomic_path
from msnerf_jax.core.parallel import DataParallel, data_parallel
from msnerf_jax.core.progress import progress_bar
from msnerf_jax.data.images import cover_crop, read_style_image
from msnerf_jax.kinds import runs as runs_lib
from msnerf_jax.kinds.painted import NAME as KIND, save_style_images
from msnerf_jax.models import vgg
from msnerf_jax.models.nerf import NerfField
from msnerf_jax.models.painted_field import init_painted_params, trilinear
from msnerf_jax.nerf import sample_cache
from msnerf_jax.style import painting_loss
from msnerf_jax.style.transfer import apply_colour_map, colour_map
from msnerf_jax.train import loop as loop_lib
from msnerf_jax.train import multistyle as multistyle_lib
from msnerf_jax.train import nerf as nerf_lib
from msnerf_jax.train import state as state_lib

FROZEN, TRAINED = "nerf", "paint"  # params {"nerf": the NeRF run's, "paint": {"grids"}}.
CACHE_FILE = "sample_cache.npz"


# ----------------------------------------------------------------------------- state


def frozen_mask(params):
  """True for every leaf of the NeRF (the optimizer's freeze mask)."""
  return {FROZEN: jax.tree_util.tree_map(lambda _: True, params[FROZEN]),
          TRAINED: jax.tree_util.tree_map(lambda _: False, params[TRAINED])}


def init_state(config: PaintConfig, nerf_params, n_styles: int) -> state_lib.TrainState:
  """Grey grids for `n_styles` styles beside a copy of the NeRF's params; Adam on the grids
  only (the NeRF gets no optimizer state)."""
  params = {FROZEN: jax.tree_util.tree_map(jnp.array, nerf_params),
            TRAINED: init_painted_params(n_styles, config.resolution)}
  tx = state_lib.adam(state_lib.exponential_lr(config.lr_init, config.lr_final, config.steps),
                      frozen=frozen_mask)
  return state_lib.create_state(params, tx)


# ----------------------------------------------------------------------------- the step


def render_pairs(grids: jnp.ndarray, cache, views: jnp.ndarray, styles: jnp.ndarray,
                 bound: float, background: jnp.ndarray) -> jnp.ndarray:
  """Training views `views` [B] rendered from their cached samples, each in its style
  `styles` [B] of grids [M, R, R, R, 3]: [B, n, 3] (n pixels of a view)."""
  def one(view, style):
    lists = {k: cache[k][view] for k in ("points", "weights", "pixel", "accumulation")}
    colour = lambda points: jax.nn.sigmoid(trilinear(grids[style][None], points, bound))[0]
    return sample_cache.cached_render(colour, lists, background)
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


def loss_fn(grids, batch, consts, config: PaintConfig, white_background: bool):
  """The loss of a batch of (view, style) pairs and its terms: MSE to photo_targets while
  batch["init"] (the first init_steps), else style_weight x (NNFM or AdaIN) + content_weight
  x content + tv_weight x total variation (painting_loss.painting_losses)."""
  views, styles = batch["view"], batch["style"]
  shape = consts["photos"].shape[1:]
  renders = render_pairs(grids, consts["cache"], views, styles, config.scene_box,
                         consts["background"]).reshape(-1, *shape)
  photos = photo_targets(consts, views, styles, white_background)
  mse = jnp.mean(jnp.square(renders - photos))
  zero = jnp.zeros((), jnp.float32)

  def init_terms():
    return mse, {"nnfm": zero, "adain": zero, "content": zero, "tv": zero}

  def style_terms():
    targets = jax.tree_util.tree_map(lambda x: x[styles], consts["targets"])
    terms = {k: jnp.mean(v) for k, v in painting_loss.painting_losses(
        consts["encoder"], renders, jax.lax.stop_gradient(photos), targets).items()}
    loss = (config.style_weight * terms[config.style_loss]
            + config.content_weight * terms["content"] + config.tv_weight * terms["tv"])
    return loss, terms

  loss, terms = jax.lax.cond(batch["init"][0], init_terms, style_terms)
  return loss, {"loss": loss, "mse": mse, **terms}


def train_step(state: state_lib.TrainState, batch, consts, *, config: PaintConfig,
               white_background: bool, axis_name: Optional[str] = None):
  """One Adam step on the grids; the NeRF comes out bit-identical (passed through)."""
  params = state.params
  grads, stats = jax.grad(loss_fn, has_aux=True)(params[TRAINED]["grids"], batch, consts,
                                                 config, white_background)
  if axis_name is not None:
    grads = jax.lax.pmean(grads, axis_name)
    stats = jax.lax.pmean(stats, axis_name)
  zeros = jax.tree_util.tree_map(jnp.zeros_like, params[FROZEN])
  state = state.apply_gradients(grads={FROZEN: zeros, TRAINED: {"grids": grads}})
  return state.replace(params={FROZEN: params[FROZEN], TRAINED: state.params[TRAINED]}), stats


def batch_of(step: int, config: PaintConfig, n_views: int, n_styles: int) -> Dict[str, Any]:
  """The (view, style) pairs of a step: every style views_per_style times, each with a
  random training view (a pure function of the step, so a resumed run replays it)."""
  key = jax.random.fold_in(jax.random.PRNGKey(config.seed), step)
  b = n_styles * config.views_per_style
  return {"view": np.asarray(jax.random.randint(key, (b,), 0, n_views), np.int32),
          "style": np.tile(np.arange(n_styles, dtype=np.int32), config.views_per_style),
          "init": np.full((b,), step < config.init_steps)}


# ----------------------------------------------------------------------------- inputs


def style_name(path: str) -> str:
  return os.path.splitext(os.path.basename(path.rstrip("/")))[0]


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
  field = NerfField(nerf_run.config)
  views = [sample_cache.view_samples(field, nerf_run.params, scene.camera_rays(int(i)),
                                     nerf_run.config, config.top_k, config.cache_threshold)
           for i in progress_bar(scene.split("train"), desc="caching samples",
                                 disable=not progress, leave=False)]
  return sample_cache.pack_views(views)


def load_or_build_cache(run_dir: str, scene, nerf_run, config: PaintConfig, progress: bool
                        ) -> Dict[str, np.ndarray]:
  """The run's cached sample lists (RUN/sample_cache.npz), built and written atomically on
  first use. UserError for a cache made from another NeRF run (or another step of it)."""
  path = os.path.join(run_dir, CACHE_FILE)
  made_from = f"{os.path.abspath(nerf_run.run_dir)}@{nerf_run.step}"
  if os.path.exists(path):
    try:
      with np.load(path) as saved:
        cache = {k: saved[k] for k in saved.files}
    except (OSError, ValueError, KeyError) as e:
      raise UserError(f"{path}: not a sample cache ({e}); delete it to rebuild") from None
    source = str(cache.pop("nerf_run", ""))
    if source != made_from:
      raise UserError(f"{path}: made from the NeRF run {source or '(unknown)'}, not "
                      f"{made_from}; delete it to rebuild")
    return cache
  cache = build_cache(scene, nerf_run, config, progress)
  with atomic_path(path, sum(v.nbytes for v in cache.values())) as tmp:
    with open(tmp, "wb") as f:
      np.savez(f, nerf_run=np.array(made_from), **cache)
  return cache


def constants(scene, cache, styles: np.ndarray, config: PaintConfig) -> Dict[str, Any]:
  """What every step reads and no step changes (placed on the devices once), for the
  scene's training views and the style images: "cache" (the packed sample lists of the N
  training views, sample_cache.pack_views), "photos" [N, H, W, 3], "maps" (each style's
  colour map: "transform" [M, 3, 3], "mu_s", "mu_t" [M, 3]), "targets"
  (painting_loss.StyleTarget stacked [M, ...]), "encoder" (VGG params) and "background"
  [3]."""
  encoder = vgg.load_vgg_params()
  photos = np.asarray(scene.images[scene.split("train")], np.float32)
  maps = [colour_map(jnp.asarray(photos), jnp.asarray(s)) if config.colour_transfer else
          (jnp.eye(3), jnp.zeros(3), jnp.zeros(3)) for s in styles]
  targets = [painting_loss.style_target(encoder, jnp.asarray(s)) for s in styles]
  stack = lambda xs: jax.tree_util.tree_map(lambda *x: jnp.stack(x), *xs)
  return dict(
      cache={k: jnp.asarray(v) for k, v in cache.items()}, photos=jnp.asarray(photos),
      maps=dict(zip(("transform", "mu_s", "mu_t"), stack([tuple(m) for m in maps]))),
      targets=stack(targets), encoder=encoder,
      background=jnp.full((3,), 1.0 if scene.white_background else 0.0, jnp.float32))


def check_config(config: PaintConfig, n_styles: int, parallel: DataParallel) -> None:
  config.validate()
  if (n_styles * config.views_per_style) % parallel.size:
    raise UserError(f"{n_styles} styles x {config.views_per_style} views per style do not "
                    f"split over {parallel.size} devices")


# ----------------------------------------------------------------------------- the loop


@run_lock.released_after
def train(config: PaintConfig, nerf_run_dir: str, style_paths: Sequence[str], run_dir: str,
          n_devices: Optional[int] = None, progress: bool = True,
          callback: Optional[Callable[[int, Any], None]] = None, parallel: str = "shard_map"
          ) -> Dict[str, Any]:
  """Paints (or resumes painting) the styles `style_paths` on a NeRF run's frozen geometry
  in `run_dir`. `config.nerf` becomes the NeRF run's config and `config.scene_box` its scene
  box. Devices and processes as nerf.train's. Returns the loop's summary dict."""
  styles = read_styles(style_paths, config.style_size)
  names = [style_name(p) for p in style_paths]
  nerf_run, scene, data = multistyle_lib.load_nerf_run(nerf_run_dir)
  box = config.scene_box or nerf_run.config.scene_box or nerf_lib.scene_box(scene)
  config = dataclasses.replace(config, nerf=nerf_run.config, scene_box=float(box))
  devices = data_parallel(n_devices, parallel)
  check_config(config, len(names), devices)
  record = {"config": config_lib.to_dict(config), "data": config_lib.to_dict(data),
            "nerf_run": os.path.abspath(nerf_run_dir), "styles": names,
            "style_files": [os.path.abspath(p) for p in style_paths]}
  distributed.check_same(record, "settings")
  holder: List[Dict[str, np.ndarray]] = []

  def prepare():
    runs_lib.prepare_run_dir(run_dir, KIND, record, lock=True)
    save_style_images(run_dir, styles)
    holder.append(load_or_build_cache(run_dir, scene, nerf_run, config, progress))
  distributed.primary_first(prepare)
  cache = holder[0] if holder else load_or_build_cache(run_dir, scene, nerf_run, config, False)
  consts = constants(scene, cache, styles, config)
  step = devices.compile(functools.partial(train_step, config=config,
                                           white_background=scene.white_background),
                         (consts,))
  n_views = len(scene.split("train"))
  return loop_lib.fit(
      init_state(config, nerf_run.params, len(names)), step,
      lambda i: batch_of(i, config, n_views, len(names)),
      run_dir=run_dir, steps=config.steps, checkpoint_every=config.checkpoint_every,
      keep_checkpoints=config.keep_checkpoints, parallel=devices, desc="paint train",
      progress=progress, callback=callback, shown=("mse", config.style_loss, "content"))

