"""A new style on a painted run without retraining it (`msnerf paint add`): 1-3 key training
views stylized by per-frame AdaIN, painted into 3D (each painted vertex takes its colour from
the one key view that sees it most, never an average of views), the vertices no key view
sees filled from their painted neighbours, then a short polish of that style alone with the
style loss; the style joins the run as one more colour table."""

import dataclasses
import os
from typing import Any, Dict, Optional, Sequence

import jax
import jax.numpy as jnp
import numpy as np

from msnerf_jax.core import run_lock
from msnerf_jax.core.checkpoint import Checkpoints
from msnerf_jax.core.errors import UserError
from msnerf_jax.core.files import write_json
from msnerf_jax.core.parallel import data_parallel
from msnerf_jax.core.progress import progress_bar
from msnerf_jax.kinds import runs as runs_lib
from msnerf_jax.kinds.painted import save_style_images, style_images
from msnerf_jax.kinds.stylized_scenes import load_decoder
from msnerf_jax.models import vgg
from msnerf_jax.style.transfer import apply_colour_map, colour_map, stylize_image
from msnerf_jax.train import paint, paint_data
from msnerf_jax.train.paint_coverage import view_spread


def key_views(c2w: np.ndarray, count: int) -> np.ndarray:
  """`count` training views spread around the scene: the first, then each time the view
  whose camera is farthest from those chosen (farthest-point sampling of camera centres)."""
  centres = np.asarray(c2w)[:, :3, 3]
  chosen = [0]
  for _ in range(1, min(count, len(centres))):
    gap = np.min(np.linalg.norm(centres[:, None] - centres[chosen][None], axis=-1), 1)
    chosen.append(int(np.argmax(gap)))
  return np.asarray(chosen)


def lift_key_views(cache, views: Sequence[int], pictures: np.ndarray, index: np.ndarray,
                   count: int, bound: float) -> Dict[str, np.ndarray]:
  """Colours of the painted vertices from stylized key views: for each key view, every
  cached sample spreads its pixel's colour to its 8 vertices by weight x trilinear weight;
  a vertex takes the colour of the one key view that gives it the most weight (the view
  that sees it largest and most squarely), averaged within that view only.

  Args: cache: the run's packed sample lists; views: the key views' indices into them;
    pictures: [K, n, 3] the stylized key views' pixels; index: [R, R, R] the paint index of
    `count` (V) painted vertices.
  Returns: {"colours": [V + 1, 3], "seen": [V + 1] bool}.
  """
  rows_count = count + 1
  best = np.zeros(rows_count)
  colours = np.full((rows_count, 3), 0.5)
  for view, picture in zip(views, pictures):
    rows, spread, pixel = view_spread(cache, view, index, bound)
    colour = picture[pixel]
    total = np.bincount(rows, spread, rows_count)
    sums = np.stack([np.bincount(rows, spread * colour[:, c], rows_count) for c in range(3)], -1)
    better = total > best
    colours[better] = sums[better] / total[better, None]
    best = np.maximum(best, total)
  seen = best > 1e-6
  seen[-1] = False  # the unpainted row
  return {"colours": colours, "seen": seen}


def fill_from_neighbours(colours: np.ndarray, seen: np.ndarray, index: np.ndarray,
                         max_rounds: int = 64) -> np.ndarray:
  """The painted vertices no key view saw, filled from their painted neighbours: each round,
  every unfilled vertex with filled 6-neighbours takes their mean (a front growing out of
  the seen surface); after max_rounds the rest keep the seen colours' mean. colours [V + 1,
  3] and seen [V + 1] as lift_key_views gives them (row V: unpainted). Returns [V + 1, 3]."""
  r = index.shape[0]
  painted = (index < len(colours) - 1).reshape(-1)
  grid = np.zeros((r ** 3, 3))
  filled = np.zeros(r ** 3, bool)
  rows = index.reshape(-1)
  grid[painted] = colours[rows[painted]]
  filled[painted] = seen[rows[painted]]
  grid, filled = grid.reshape(r, r, r, 3), filled.reshape(r, r, r)
  todo = painted.reshape(r, r, r) & ~filled
  for _ in range(max_rounds):
    if not todo.any():
      break
    total, count = np.zeros_like(grid), np.zeros(filled.shape)
    for axis in range(3):
      for shift in (1, -1):
        total += np.roll(grid * filled[..., None], shift, axis)
        count += np.roll(filled, shift, axis)
    grow = todo & (count > 0)
    grid[grow] = total[grow] / count[grow][:, None]
    filled |= grow
    todo &= ~grow
  out = colours.copy()
  flat_grid, flat_filled = grid.reshape(-1, 3), filled.reshape(-1)
  take = painted & flat_filled
  out[rows[take]] = flat_grid[take]
  rest = painted & ~flat_filled
  out[rows[rest]] = colours[seen].mean(0) if seen.any() else 0.5
  return out


@run_lock.released_after
def add_style(run_dir: str, style_path: str, decoder_dir: str,
              views: Optional[Sequence[int]] = None, count: int = 2, polish_steps: int = 150,
              scale: int = 1, progress: bool = True) -> Dict[str, Any]:
  """Adds the style of `style_path` to the painted run in `run_dir` (the new-style path).

  Args:
    decoder_dir: the AdaIN run that stylizes the key views (per-frame AdaIN).
    views: the key training views (indices into the training split), or None: `count` of
      them spread around the scene (key_views).
    polish_steps: steps of the style loss on that style alone afterwards (0: none).
    scale: the key views are stylized enlarged this many times (stylize_image's scale).
  Returns: {"style", "views", "seen" (share of painted vertices a key view saw),
    "seconds", "step"}.
  """
  import time  # pylint: disable=g-import-not-at-top
  t0 = time.time()
  run = runs_lib.load_run(run_dir, "painted")
  scene, _ = runs_lib.scene_of(run)
  name = paint_data.style_name(style_path)
  if name in run.record["styles"]:
    raise UserError(f"{style_path}: the run already has a style named {name!r}")
  config = run.config
  picture = paint_data.read_styles([style_path], config.style_size)[0]
  train = scene.split("train")
  if views is None:
    views = key_views(scene.c2w[train], count)
  views = np.asarray(views, int)
  for v in views:
    if not 0 <= v < len(train):
      raise UserError(f"--key-views {v}: out of range (the run has {len(train)} training "
                      "views, 0.." f"{len(train) - 1})")
  decoder = load_decoder(decoder_dir)
  run_lock.acquire(run_dir)
  nerf_run = runs_lib.load_run(run.record["nerf_run"], "nerf")
  cache, photos = paint_data.painting_views(
      paint_data.load_or_build_cache(run_dir, scene, nerf_run, config, progress), scene,
      nerf_run, config)
  encoder = vgg.load_vgg_params()
  full = stylized_key_views(scene, train, views, picture, decoder, encoder, scale)
  index = np.asarray(run.params["paint"]["index"])
  count = run.params["paint"]["colours"].shape[1] - 1
  lifted = lift_key_views(cache, views, full.reshape(len(views), -1, 3), index, count,
                          config.scene_box)
  fill = paint_data.fill_map(cache, index, count, config.scene_box)
  colours = fill_from_neighbours(lifted["colours"], lifted["seen"], index)[fill]
  polished = _polish(run, scene, (cache, photos), name, picture, paint_data.logit(colours),
                     fill, polish_steps, progress)
  step = _append_style(run_dir, run, name, style_path, picture, polished)
  return {"style": name, "views": [int(v) for v in views],
          "seen": float(lifted["seen"][:-1].mean()), "seconds": time.time() - t0, "step": step}


def stylized_key_views(scene, train, views, picture, decoder, encoder, scale):
  """[K, H, W, 3] the key views stylized by per-frame AdaIN. Where the scene's background is
  white (by the photos' alpha): the object's colours are moved to the style's mean and
  covariance (AdaIN's statistics count the white background, which takes the style's light
  colours and leaves the object its darkest), then put back over white."""
  out = []
  for v in views:
    photo = scene.images[train[v]]
    styled = stylize_image(decoder, encoder, photo, [picture], scale=scale)
    if scene.white_background and scene.alphas is not None:
      alpha = scene.alphas[train[v]].astype(np.float32) / 255.0
      styled = np.asarray(apply_colour_map(styled, *colour_map(
          jnp.asarray(styled), jnp.asarray(picture), source_weights=jnp.asarray(alpha))))
      styled = styled * alpha[..., None] + (1.0 - alpha[..., None])
    out.append(styled)
  return np.stack(out)


def _polish(run, scene, views, name, picture, start, fill, steps, progress) -> np.ndarray:
  """The new style's colour logits [V + 1, 3] after `steps` Adam steps of the style loss on
  random views of the painting (`views`: paint_data.painting_views' (cache, photos)), with
  the run's loss settings, starting from `start` (`fill`: the run's fill_map)."""
  if steps == 0:
    return start
  config = dataclasses.replace(run.config, init_steps=0, views_per_style=1)
  cache, photos = views
  consts = paint_data.constants(scene, cache, photos, picture[None], config, fill,
                                paint_data.style_maps(scene, cache, photos, picture[None], config))
  index = np.asarray(run.params["paint"]["index"])
  state = paint.init_state(config, run.params["nerf"], 1, index, len(start) - 1)
  state = state.replace(params={**state.params, paint.TRAINED: {
      "colours": jnp.asarray(start)[None], "index": jnp.asarray(index)}})
  step = paint.compile_train_step(config, consts, data_parallel(1), scene.white_background)
  n_views = len(photos)
  for i in progress_bar(range(steps), desc=f"polishing {name}", disable=not progress):
    state, _ = step(state, paint.batch_of(i, config, n_views, [name],
                                          (scene.height, scene.width)))
  return np.asarray(state.params[paint.TRAINED]["colours"][0])


def _append_style(run_dir, run, name, style_path, picture, colours) -> int:
  """Writes the run with the new style appended: its colours (and zero Adam moments for
  them) in a new checkpoint, its picture, then run.json (the style exists once run.json
  names it; a checkpoint written before an interruption holds one unnamed extra table,
  which nothing reads)."""
  checkpoints = Checkpoints(run_dir, keep=run.config.optim.keep_checkpoints)
  try:
    tree = checkpoints.restore()
    old = tree["params"][paint.TRAINED]["colours"]
    m = len(run.record["styles"])
    grow = lambda x, new: (np.concatenate([np.asarray(x)[:m], new[None]])
                           if np.shape(x) == np.shape(old) else x)
    tree["params"] = {**tree["params"], paint.TRAINED: {
        **tree["params"][paint.TRAINED], "colours": grow(old, colours)}}
    tree["opt_state"] = jax.tree_util.tree_map(
        lambda x: grow(x, np.zeros_like(colours)), tree["opt_state"])
    step = int(tree["step"]) + 1
    tree["step"] = np.asarray(step)
    checkpoints.save(step, tree)
  finally:
    checkpoints.close()
  save_style_images(run_dir, np.concatenate([style_images(run), picture[None]]))
  record = runs_lib.read_run_file(run_dir)
  record["styles"] = list(record["styles"]) + [name]
  record["style_files"] = list(record["style_files"]) + [os.path.abspath(style_path)]
  write_json(os.path.join(run_dir, runs_lib.RUN_FILE), record)
  return step

