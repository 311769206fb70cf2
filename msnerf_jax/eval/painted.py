"""Evaluating a painted run against per-frame AdaIN on one camera path, with the metric's
floors: for each painted style, the painted frames and the per-frame AdaIN frames (the NeRF's
render of each camera stylized on its own by an AdaIN decoder) get short- and long-range
consistency (warped RMSE and LPIPS, k = 1 and 7), the style distance to the style picture
(AdaIN statistics and Gram), the content loss (relu4_1 MSE to the NeRF's photo-real frame)
and, over the styles, how distinct they stay (the mean pairwise AdaIN-statistics distance
between the styles' frames of one camera). Floors of the consistency metric: the photo-real
NeRF's own frames, and a random texture painted on the same geometry (random colours at the
painted vertices) rendered along the same path.
"""

import itertools
import os
import time
from typing import Any, Dict, List, Optional, Sequence

import jax
import jax.numpy as jnp
import numpy as np

from msnerf_jax.core.errors import UserError
from msnerf_jax.core.progress import progress_bar
from msnerf_jax.data import images as images_lib
from msnerf_jax.data import video
from msnerf_jax.eval import metrics
from msnerf_jax.eval.evaluate import markdown_table, score, write_tables
from msnerf_jax.eval.paths import nerf_path, painted_frames, path_poses, per_frame_adain
from msnerf_jax.kinds import stylized_scenes
from msnerf_jax.kinds.painted import render_painted
from msnerf_jax.kinds.runs import load_run, scene_of
from msnerf_jax.models import vgg
from msnerf_jax.style import adain as adain_lib

COLUMNS = ("method", "style", "rmse_k1", "lpips_k1", "rmse_k7", "lpips_k7", "style_adain",
           "style_gram", "content", "distinct")
BASELINE = "adain-per-frame"
# Consistency columns also compared above the metric's floor (the photo-real NeRF's own
# figure): (painted - floor) / (per-frame AdaIN - floor).
CONSISTENCY = ("rmse_k1", "lpips_k1")


def content_loss(encoder, frames: Sequence[np.ndarray], photos: Sequence[np.ndarray]) -> float:
  """Mean relu4_1 MSE between frames and the photo-real frames of the same cameras."""
  ours = adain_lib.encode(encoder, jnp.asarray(np.stack(frames)))["relu4_1"]
  real = adain_lib.encode(encoder, jnp.asarray(np.stack(photos)))["relu4_1"]
  return float(jnp.mean(jnp.square(ours - real)))


def distinctness(encoder, frames_by_style: Sequence[Sequence[np.ndarray]]) -> float:
  """Mean over pairs of styles and cameras of the AdaIN-statistics distance between the two
  styles' frames of the camera (metrics.style_distance's "adain")."""
  pairs = []
  for a, b in itertools.combinations(range(len(frames_by_style)), 2):
    for fa, fb in zip(frames_by_style[a], frames_by_style[b]):
      pairs.append(float(metrics.style_distance(encoder, jnp.asarray(fa)[None],
                                                jnp.asarray(fb)[None])["adain"][0]))
  return float(np.mean(pairs)) if pairs else float("nan")


def random_texture(run, seed: int = 0) -> Dict[str, Any]:
  """The painted run's params with one style of random colours (uniform in [0, 1]) at its
  painted vertices: a texture truly on the geometry, with the contrast of noise."""
  colours = run.params["paint"]["colours"]
  noise = jax.random.uniform(jax.random.PRNGKey(seed), colours.shape[1:], minval=1e-3,
                             maxval=1.0 - 1e-3)
  return {**run.params, "paint": {**run.params["paint"],
                                  "colours": np.asarray(jnp.log(noise / (1.0 - noise)))[None]}}


def evaluate_painted(run_dir: str, decoder_dir: str, out_dir: str, frames: int = 40,
                     scale: int = 1, chunk: Optional[int] = None, progress: bool = True,
                     styles: Optional[Sequence[str]] = None) -> Dict[str, Any]:
  """Evaluates a painted run and per-frame AdaIN (decoder `decoder_dir`, each frame
  stylized at `scale` times its size, as `msnerf stylize-scene --stylize-scale`) in its
  painted `styles` (default: all) along `frames` cameras of the scene's render path; writes
  results.md/.csv/.json and frames.png (rows: style x method, 4 frames) in out_dir.

  Returns {"rows": [...], "ratios": {style: {column: painted / per-frame, and
  "COLUMN_over_floor" for the consistency columns: (painted - floor) / (per-frame - floor),
  the floor being the photo-real NeRF's figure}}, "files", "seconds"}.
  """
  t0 = time.time()
  run = load_run(run_dir, "painted")
  scene, _ = scene_of(run)
  decoder = stylized_scenes.load_decoder(decoder_dir)
  encoder, lpips_params = vgg.load_vgg_params(), metrics.load_lpips_params()
  poses = path_poses(scene, frames)
  files_of = dict(zip(run.record["styles"], run.record["style_files"]))
  names = list(styles) if styles else list(run.record["styles"])
  for name in names:
    if name not in files_of:
      raise UserError(f"style {name!r}: not a painted style of {run_dir} "
                      f"({', '.join(files_of)})")
  base = nerf_path(scene, run.params["nerf"], run.config.nerf, poses, chunk, progress)
  by_name, _ = painted_frames(run, scene, base, run.record["nerf_run"], chunk, progress)
  painted = [by_name[n] for n in names]
  noise = random_texture(run)
  texture = [render_painted(scene, noise, run.config, c2w, chunk)["rgb"][0] for c2w in poses]
  pictures = [images_lib.read_image(files_of[n], max_side=1024) for n in names]
  per_frame = [per_frame_adain(decoder, encoder, base, picture, 1.0, scene.white_background,
                               scale) for picture in progress_bar(
                                   pictures, desc="per-frame AdaIN", disable=not progress,
                                   leave=False)]
  scored = lambda frames_, style: {
      **score(frames_, [b["depth"] for b in base], [b["accumulation"] for b in base], poses,
              scene.K, scene.ndc, style, encoder, lpips_params),
      "content": content_loss(encoder, frames_, [b["rgb"] for b in base])}
  rows, figure = _rows(names, painted, per_frame, texture, base, pictures, scene, encoder,
                       scored)
  os.makedirs(out_dir, exist_ok=True)
  files = write_tables(rows, out_dir, COLUMNS)
  files.append(video.write_grid(os.path.join(out_dir, "frames.png"), figure))
  return {"rows": rows, "ratios": ratios_of(rows, names), "files": files,
          "seconds": time.time() - t0}


def _rows(names, painted, per_frame, texture, base, pictures, scene, encoder, scored):
  """(the table's rows: painted and per-frame AdaIN in each style, then the two floors;
  the figure's rows of 4 frames each), `scored(frames, style picture)` a row's numbers."""
  photos = [b["rgb"] for b in base]
  rows, figure = [], []
  distinct = {"painted": distinctness(encoder, painted), BASELINE: distinctness(encoder, per_frame)}
  for m, name in enumerate(names):
    style = images_lib.cover_crop(pictures[m], scene.height, scene.width)
    for method, frames_ in (("painted", painted[m]), (BASELINE, per_frame[m])):
      rows.append({"method": method, "style": name, **scored(frames_, style),
                   "distinct": distinct[method]})
      figure.append(list(frames_[:: max(1, len(frames_) // 4)][:4]))
  for method, frames_ in (("floor: photo-real NeRF", photos), ("floor: random texture", texture)):
    rows.append({"method": method, "style": "-", **scored(frames_, photos[0]),
                 "distinct": float("nan")})
  return rows, figure


def ratios_of(rows: Sequence[Dict[str, Any]], names: Sequence[str]
              ) -> Dict[str, Dict[str, float]]:
  """{style: {column: painted / per-frame, "COLUMN_over_floor": (painted - floor) /
  (per-frame - floor) for the consistency columns}} of `_rows`' table."""
  floor = rows[2 * len(names)]  # the photo-real NeRF's own figures
  return {name: {**{c: rows[2 * m][c] / rows[2 * m + 1][c] for c in COLUMNS[2:]},
                 **{f"{c}_over_floor": (rows[2 * m][c] - floor[c])
                    / (rows[2 * m + 1][c] - floor[c]) for c in CONSISTENCY}}
          for m, name in enumerate(names)}


def ratio_table(ratios: Dict[str, Dict[str, float]]) -> List[str]:
  """Markdown lines of painted / per-frame AdaIN per style and column."""
  rows = [{"style": name, **r} for name, r in ratios.items()]
  return markdown_table(rows, ("style",) + COLUMNS[2:] + tuple(f"{c}_over_floor"
                                                              for c in CONSISTENCY))
