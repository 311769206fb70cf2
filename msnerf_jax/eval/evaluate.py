"""Evaluating trained runs.

Held-out views: `evaluate_nerf` (PSNR/SSIM of a NeRF, and on scenes with alpha the rendered
opacity on empty space and object) and `evaluate_multistyle` (per-style PSNR/SSIM against the
stylized views), what `msnerf nerf eval` and `msnerf multistyle eval` report.

The stylized-3D evaluation of multi-style runs against the baselines, on one camera path
(`evaluate_run`, what `msnerf evaluate` reports).

For each style, these methods render the same path:
  - `multistyle` / `multistyle-density`: each multi-style run, all styles in one sweep per view;
  - `nerf-single-style`: a NeRF trained on that style's stylized views alone, where given;
  - `adain-per-frame`: the NeRF the (first) run was built on renders the path, and every frame
    is stylized independently by the AdaIN decoder (direct 2D style transfer on NeRF renders).
Each gets: short- and long-range consistency (warped RMSE and LPIPS, k = 1 and 7, see
msnerf_jax.eval.consistency; both methods warp with the geometry they render, which for the
standard multi-style model and the baseline is the same NeRF density) and the style distance
of its frames to the style image (AdaIN statistics and Gram losses, msnerf_jax.eval.metrics).
"""

import csv
import io
import json
import os
import time
from typing import Any, Dict, List, Optional, Sequence, Tuple

import numpy as np

from msnerf_jax.core import files
from msnerf_jax.core.config import MultistyleConfig, NerfConfig
from msnerf_jax.core.errors import UserError
from msnerf_jax.core.progress import progress_bar
from msnerf_jax.data import images as images_lib
from msnerf_jax.data import video
from msnerf_jax.data.scene import Scene
from msnerf_jax.data.stylized import StylizedData, read_manifest
from msnerf_jax.eval import consistency as consistency_lib
from msnerf_jax.eval import metrics
from msnerf_jax.eval import paths
from msnerf_jax.kinds import stylized_scenes
from msnerf_jax.kinds.multistyle import style_vectors
from msnerf_jax.kinds.runs import load_run, scene_of
from msnerf_jax.kinds.views import render_styles, render_view
from msnerf_jax.models import vgg
from msnerf_jax.style import transfer as stylize_lib


def evaluate_nerf(scene: Scene, params, config: NerfConfig, split: str = "val",
                  chunk: Optional[int] = None, progress: bool = True):
  """PSNR/SSIM of the fine renders on a split. Returns (per-view list, mean dict, renders).

  On scenes with alpha, each view also gets the mean rendered opacity on its ground-truth
  empty space and on its object (metrics.mask_opacity: "opacity_background",
  "opacity_object"): white fog over a white background costs no PSNR, but shows there.
  """
  idx = scene.split(split)
  rows, renders = [], []
  for i in progress_bar(idx, desc=f"eval {split}", disable=not progress, leave=False):
    out = render_view(scene, params, config, int(i), chunk)
    target = scene.images[i]
    row = {"view": os.path.basename(scene.image_paths[i]),
           "psnr": float(metrics.psnr(out["rgb"], target)),
           "ssim": float(metrics.ssim(out["rgb"], target))}
    if scene.alphas is not None:
      opacity = metrics.mask_opacity(out["accumulation"], scene.alphas[i])
      row.update({f"opacity_{k}": v for k, v in opacity.items()})
    rows.append(row)
    renders.append(out)
  mean = {k: float(np.nanmean([r[k] for r in rows])) for k in rows[0] if k != "view"}
  return rows, mean, renders


def evaluate_multistyle(scene: Scene, stylized: StylizedData, params, config: MultistyleConfig,
                        split: str = "val", chunk: Optional[int] = None, progress: bool = True
                        ) -> Tuple[List[Dict[str, Any]], Dict[str, Dict[str, float]]]:
  """Per-style PSNR/SSIM on the held-out stylized views of a split.

  Returns (rows: one per (style, view), means: style -> {"psnr", "ssim"} plus "mean").
  """
  idx = scene.split(split)
  rows = []
  for i in progress_bar(idx, desc=f"eval {split}", disable=not progress, leave=False):
    out = render_styles(scene, params, config, int(i), stylized.vectors, chunk)
    for m, name in enumerate(stylized.names):
      target = stylized.images[m, i].astype(np.float32) / 255.0
      rows.append({"style": name, "view": int(i),
                   "psnr": float(metrics.psnr(out["rgb"][m], target)),
                   "ssim": float(metrics.ssim(out["rgb"][m], target))})
  means = {}
  for name in stylized.names + ["mean"]:
    mine = [r for r in rows if name in ("mean", r["style"])]
    means[name] = {k: float(np.mean([r[k] for r in mine])) for k in ("psnr", "ssim")}
  return rows, means


# ----------------------------------------------------------------------------- against baselines

COLUMNS = ("method", "style", "rmse_k1", "lpips_k1", "rmse_k7", "lpips_k7", "style_adain",
           "style_gram", "coverage_k1")


def score(frames, depths, accs, poses, K, ndc, style_image, encoder, lpips_params
          ) -> Dict[str, float]:
  """Consistency at k = 1 and 7 and style distances of one rendered path."""
  import jax.numpy as jnp  # pylint: disable=g-import-not-at-top
  lp = lambda a, b: np.asarray(metrics.lpips(lpips_params, jnp.asarray(a), jnp.asarray(b)))
  row = {}
  for k in (1, 7):
    c = consistency_lib.consistency(frames, depths, accs, poses, K, ndc, k, lp)
    row[f"rmse_k{k}"], row[f"lpips_k{k}"] = c["rmse"], c["lpips"]
    row[f"coverage_k{k}"] = c["coverage"]
  d = metrics.style_distance(encoder, jnp.asarray(np.stack(frames)), jnp.asarray(style_image)[None])
  row["style_adain"] = float(np.mean(d["adain"]))
  row["style_gram"] = float(np.mean(d["gram"]))
  return row


def markdown_table(rows: Sequence[Dict[str, Any]], columns: Sequence[str]) -> List[str]:
  """Lines of a Markdown table of `rows` (floats with 4 decimals)."""
  fmt = lambda v: f"{v:.4f}" if isinstance(v, float) else str(v)
  return (["| " + " | ".join(columns) + " |", "|" + "---|" * len(columns)]
          + ["| " + " | ".join(fmt(r[c]) for c in columns) + " |" for r in rows])


def method_labels(runs) -> List[str]:
  """Table labels of multi-style runs: multistyle / multistyle-density, with "-styleloss" when
  trained with the patch style loss, numbered when repeated."""
  labels = [("multistyle-density" if r.config.density_aware else "multistyle")
            + ("-styleloss" if r.config.style_weight > 0 else "") for r in runs]
  return [x if labels.count(x) == 1 else f"{x}#{labels[:i + 1].count(x)}"
          for i, x in enumerate(labels)]


def evaluate_run(run_dirs, out_dir: str, styles: Optional[Sequence[str]] = None,
                 decoder_dir: Optional[str] = None, frames: int = 40,
                 chunk: Optional[int] = None, progress: bool = True,
                 single_style_runs: Sequence[str] = (),
                 feature_runs: Sequence[str] = (),
                 painted_runs: Sequence[str] = ()) -> Dict[str, Any]:
  """Evaluates multi-style runs and the baselines on one camera path; writes tables and figures.

  Args:
    run_dirs: one multi-style run folder, or several of the same scene and stylized dataset
      (the standard and the density-aware variant, say); the first one's NeRF and decoder
      make the per-frame AdaIN baseline.
    single_style_runs: NeRF runs each trained on one style of that dataset (`msnerf nerf
      train --stylized DIR --style NAME`): the single-style baseline of their style.
    feature_runs: feature-field runs of the same scene (`msnerf features train`), each
      painting every evaluated style from its image (row "feature-field").
    painted_runs: painted runs of the same scene (`msnerf paint train`), each on the
      evaluated styles it painted, matched by name (row "painted").
  Returns {"rows": [...], "files": [...], "seconds": float}.
  """
  t0 = time.time()
  run_dirs = [run_dirs] if isinstance(run_dirs, str) else list(run_dirs)
  runs = [load_run(d, "multistyle") for d in run_dirs]
  run = runs[0]
  scene, _ = scene_of(run)
  manifest = read_manifest(run.record["stylized"])
  sources = {s["name"]: s for s in manifest["styles"] if s["source"]}
  vectors = [style_vectors(r) for r in runs]
  names = _evaluated_styles(run_dirs, vectors, sources, styles)
  others = (paths.single_style_runs(single_style_runs, names),
            [load_run(d, "features") for d in feature_runs],
            [load_run(d, "painted") for d in painted_runs])
  decoder = _decoder_of(run, manifest, decoder_dir)
  nerf_run = load_run(run.record["nerf_run"], "nerf")
  encoder, lpips_params = vgg.load_vgg_params(), metrics.load_lpips_params()
  poses = paths.path_poses(scene, frames)
  base = paths.nerf_path(scene, nerf_run.params, nerf_run.config, poses, chunk, progress)
  pictures = [images_lib.read_image(sources[n]["source"], max_side=1024) for n in names]
  methods = _method_paths(runs, vectors, names, scene, poses, base, pictures, sources,
                          encoder, *others, chunk, progress)
  rows, figure_rows = [], []
  for m, name in enumerate(progress_bar(names, desc="scoring styles", disable=not progress)):
    style = stylize_lib.cover_crop(pictures[m], scene.height, scene.width)  # what distances use.
    per_frame = paths.per_frame_adain(decoder, encoder, base, pictures[m],
                                      sources[name]["alpha"], scene.white_background,
                                      manifest["stylize_scale"])
    for label, frames_, geometry in [(label, by_name[name], geometry[name])
                                     for label, by_name, geometry in methods
                                     if name in by_name] + [("adain-per-frame", per_frame, base)]:
      rows.append({"method": label, "style": name,
                   **score(frames_, [g["depth"] for g in geometry],
                           [g["accumulation"] for g in geometry], poses, scene.K, scene.ndc,
                           style, encoder, lpips_params)})
      figure_rows.append([style] + list(frames_[:4]))
  files = write_tables(rows, out_dir)
  files.append(video.write_grid(os.path.join(out_dir, "frames.png"), figure_rows))
  return {"rows": rows, "files": files, "seconds": time.time() - t0}


def _method_paths(runs, vectors, names, scene, poses, base, pictures, sources, encoder,
                  singles, fields, painters, chunk, progress) -> List[paths.Path]:
  """The Paths of every method but per-frame AdaIN, in the order of the table's rows: the
  multi-style runs, the single-style NeRFs ({style: run}), the loaded feature runs, the
  loaded painted runs."""
  nerf_dir = runs[0].record["nerf_run"]
  methods = paths.multistyle_paths(runs, vectors, names, method_labels(runs), scene, poses,
                                   chunk, progress)
  methods += [paths.single_style_path(singles[n], n, scene, poses, chunk, progress)
              for n in names if n in singles]
  numbered = lambda label, i, count: label + (f"#{i + 1}" if count > 1 else "")
  for i, field in enumerate(fields):  # every style from one feature render per view
    frames_k, geometry = paths.feature_field_frames(
        field, scene, base, nerf_dir, encoder, pictures, [sources[n]["alpha"] for n in names],
        chunk, progress)
    methods.append((numbered("feature-field", i, len(fields)), dict(zip(names, frames_k)),
                    {n: geometry for n in names}))
  for i, painter in enumerate(painters):
    by_name, geometry = paths.painted_frames(painter, scene, base, nerf_dir, chunk, progress)
    methods.append((numbered("painted", i, len(painters)), by_name,
                    {n: geometry for n in by_name}))
  return methods


def _decoder_of(run, manifest, decoder_dir):
  """The AdaIN decoder of the per-frame baseline: `decoder_dir`, or the stylized dataset's."""
  decoder_dir = decoder_dir or manifest.get("decoder")
  if not decoder_dir:
    raise UserError(f"{run.record['stylized']}: no decoder recorded; pass --decoder ADAIN_RUN")
  return stylized_scenes.load_decoder(decoder_dir)


def _evaluated_styles(run_dirs, vectors, sources, styles) -> List[str]:
  """The styles to evaluate (default: every stylized training style), each checked to be a
  stylized training style of every run."""
  names = list(styles) if styles else [n for n in vectors[0] if n in sources]
  for name in names:
    for d, v in zip(run_dirs, vectors):
      if name not in sources or name not in v:
        raise UserError(f"style {name!r}: not a stylized training style of {d} "
                        f"(has {', '.join(n for n in v if n in sources)})")
  return names


def write_tables(rows: List[Dict[str, Any]], out_dir: str,
                 columns: Sequence[str] = COLUMNS) -> List[str]:
  """results.md, results.csv and results.json of `columns` in out_dir (atomically)."""
  md = markdown_table(rows, columns)
  buffer = io.StringIO()
  writer = csv.DictWriter(buffer, fieldnames=list(columns), extrasaction="ignore")
  writer.writeheader()
  writer.writerows(rows)
  paths = [os.path.join(out_dir, f"results.{ext}") for ext in ("md", "csv", "json")]
  for path, text in zip(paths, ("\n".join(md) + "\n", buffer.getvalue(),
                                json.dumps(rows, indent=2))):
    files.atomic_write_bytes(path, text.encode())
  return paths


def print_table(rows: List[Dict[str, Any]]) -> None:
  print(f"{'method':<20} {'style':<24} {'RMSE k1':>8} {'LPIPS k1':>8} {'RMSE k7':>8} "
        f"{'LPIPS k7':>8} {'style':>8} {'gram':>8}")
  for r in rows:
    print(f"{r['method']:<20} {r['style']:<24} {r['rmse_k1']:8.4f} {r['lpips_k1']:8.4f} "
          f"{r['rmse_k7']:8.4f} {r['lpips_k7']:8.4f} {r['style_adain']:8.3f} "
          f"{r['style_gram']:8.3f}")
