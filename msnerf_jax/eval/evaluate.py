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

from msnerf_jax.eval import consistency as consistency_lib
from msnerf_jax.kinds import stylized_scenes
from msnerf_jax.eval import metrics
from msnerf_jax.core import files
from msnerf_jax.style import transfer as stylize_lib
from msnerf_jax.data import video
from msnerf_jax.core.config import MultistyleConfig, NerfConfig
from msnerf_jax.data import images as images_lib
from msnerf_jax.data.scene import Scene
from msnerf_jax.data.stylized import StylizedData, read_manifest
from msnerf_jax.style.vectors import style_vector_of
from msnerf_jax.core.errors import UserError
from msnerf_jax.models import vgg
from msnerf_jax.kinds.runs import load_run, scene_of
from msnerf_jax.kinds.multistyle import style_vectors
from msnerf_jax.kinds.features import feature_painting
from msnerf_jax.kinds.painted import render_painted
from msnerf_jax.kinds.views import render_feature_styles, render_styles, render_view
from msnerf_jax.core.progress import progress_bar

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


def per_frame_adain(decoder, encoder, base: Sequence[Dict[str, np.ndarray]], style: np.ndarray,
                    alpha: float, white_background: bool, scale: int = 1) -> List[np.ndarray]:
  """The per-frame AdaIN baseline: each NeRF render in `base` stylized on its own, at the
  stylized dataset's `scale` (its manifest's stylize_scale); on white-background (Blender)
  scenes the background is put back to white, as in the stylized training views."""
  frames = [stylize_lib.stylize_image(decoder, encoder, b["rgb"], [style], alpha=alpha,
                                      scale=scale) for b in base]
  if white_background:
    frames = [f * b["accumulation"][..., None] + (1.0 - b["accumulation"][..., None])
              for f, b in zip(frames, base)]
  return frames


def feature_field_frames(field, scene, base, base_nerf: str, encoder,
                         pictures: Sequence[np.ndarray], alphas: Sequence[float],
                         chunk: Optional[int] = None, progress: bool = False):
  """(frames [K][P], geometry [P]) of a loaded feature run in K styles along the P cameras
  `base` was rendered on, one feature render per camera: each style's statistics from its
  picture cover-cropped to the decoded size (as per-frame AdaIN crops it), at its strength
  alpha (a blend towards the scene's own statistics), the features painted by the run's
  decoder; on white-background scenes the background is put back to white by the NeRF's
  opacity, as per_frame_adain does. The geometry is `base`'s when the field was trained on
  that NeRF run (`base_nerf`), else its own NeRF's renders."""
  decoder = stylized_scenes.load_decoder(field.record["decoder"])
  stats, original, size = feature_painting(field, scene)
  vectors = np.stack([alpha * style_vector_of(encoder, p, size) + (1.0 - alpha) * original
                      for p, alpha in zip(pictures, alphas)])
  geometry = base
  if os.path.abspath(field.record["nerf_run"]) != os.path.abspath(base_nerf):
    geometry = [render_view(scene, field.params["nerf"], field.config.nerf, b["pose"], chunk)
                for b in base]
  frames = [[] for _ in vectors]
  for b, g in zip(progress_bar(base, desc="feature-field path", disable=not progress,
                               leave=False), geometry):
    sweep = render_feature_styles(scene, field.params, field.config, b["pose"], decoder, stats,
                                  vectors, chunk)
    if scene.white_background:
      sweep = images_lib.over_background(sweep, g["accumulation"][..., None])
    for k, frame in enumerate(sweep):
      frames[k].append(frame)
  return frames, geometry


def painted_frames(run, scene, base, base_nerf: str, chunk: Optional[int] = None,
                   progress: bool = False):
  """({style name: frames [P]}, geometry [P]) of a loaded painted run along the P cameras
  `base` was rendered on, all its styles in one render per camera; the geometry is `base`'s
  when it was painted on that NeRF run (`base_nerf`), else its own NeRF's renders."""
  names = run.record["styles"]
  frames = {n: [] for n in names}
  same = os.path.abspath(run.record["nerf_run"]) == os.path.abspath(base_nerf)
  geometry = []
  for b in progress_bar(base, desc="painted path", disable=not progress, leave=False):
    for name, frame in zip(names, render_painted(scene, run.params, run.config, b["pose"],
                                                 chunk)["rgb"]):
      frames[name].append(frame)
    geometry.append(b if same else render_view(scene, run.params["nerf"], run.config.nerf,
                                               b["pose"], chunk))
  return frames, geometry


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
  singles = _single_style_runs(single_style_runs, names)
  decoder = _decoder_of(run, manifest, decoder_dir)
  nerf_run = load_run(run.record["nerf_run"], "nerf")
  encoder, lpips_params = vgg.load_vgg_params(), metrics.load_lpips_params()
  poses = scene.render_poses[np.linspace(0, len(scene.render_poses) - 1, frames)
                             .round().astype(int)] if frames else scene.render_poses
  methods = method_labels(runs)
  fields = [load_run(d, "features") for d in feature_runs]

  # The NeRF renders (geometry and the frames the per-frame baseline stylizes).
  base = [{**render_view(scene, nerf_run.params, nerf_run.config, c2w, chunk), "pose": c2w}
          for c2w in progress_bar(poses, desc="NeRF path", disable=not progress, leave=False)]
  swept = _multistyle_sweeps(runs, vectors, names, methods, scene, poses, chunk, progress)
  pictures = [images_lib.read_image(sources[n]["source"], max_side=1024) for n in names]
  # Every style from one feature render per view, for each feature run.
  painted = [feature_field_frames(field, scene, base, run.record["nerf_run"], encoder, pictures,
                                  [sources[n]["alpha"] for n in names], chunk, progress)
             for field in fields]
  painted_paths = [painted_frames(load_run(d, "painted"), scene, base, run.record["nerf_run"],
                                  chunk, progress) for d in painted_runs]
  rows, figure_rows = [], []
  for m, name in enumerate(progress_bar(names, desc="scoring styles", disable=not progress)):
    picture = pictures[m]
    style = stylize_lib.cover_crop(picture, scene.height, scene.width)  # what distances use.
    per_frame = per_frame_adain(decoder, encoder, base, picture, sources[name]["alpha"],
                                scene.white_background, manifest["stylize_scale"])
    candidates = [(method, [s["rgb"][m] for s in sw],
                   [{"depth": s["depth"][m], "accumulation": s["accumulation"][m]} for s in sw])
                  for method, sw in zip(methods, swept)]
    if name in singles:
      candidates.append(_single_style_frames(singles[name], name, scene, poses, chunk,
                                             progress))
    for i, (frames_k, geometry) in enumerate(painted):
      label = "feature-field" + (f"#{i + 1}" if len(painted) > 1 else "")
      candidates.append((label, frames_k[m], geometry))
    for i, (frames_by_name, geometry) in enumerate(painted_paths):
      if name in frames_by_name:
        label = "painted" + (f"#{i + 1}" if len(painted_paths) > 1 else "")
        candidates.append((label, frames_by_name[name], geometry))
    candidates.append(("adain-per-frame", per_frame, base))
    for label, frames_, geometry in candidates:
      rows.append({"method": label, "style": name,
                   **score(frames_, [g["depth"] for g in geometry],
                           [g["accumulation"] for g in geometry], poses, scene.K, scene.ndc,
                           style, encoder, lpips_params)})
      figure_rows.append([style] + list(frames_[:4]))
  files = write_tables(rows, out_dir)
  files.append(video.write_grid(os.path.join(out_dir, "frames.png"), figure_rows))
  return {"rows": rows, "files": files, "seconds": time.time() - t0}


def _decoder_of(run, manifest, decoder_dir):
  """The AdaIN decoder of the per-frame baseline: `decoder_dir`, or the stylized dataset's."""
  decoder_dir = decoder_dir or manifest.get("decoder")
  if not decoder_dir:
    raise UserError(f"{run.record['stylized']}: no decoder recorded; pass --decoder ADAIN_RUN")
  return stylized_scenes.load_decoder(decoder_dir)


def _multistyle_sweeps(runs, vectors, names, methods, scene, poses, chunk, progress):
  """Per multi-style run, its render of every path camera in all `names` styles at once."""
  stack = [np.stack([v[n] for n in names]) for v in vectors]
  return [[render_styles(scene, r.params, r.config, c2w, s, chunk)
           for c2w in progress_bar(poses, desc=f"{m} path", disable=not progress, leave=False)]
          for r, s, m in zip(runs, stack, methods)]


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


def _single_style_runs(run_dirs: Sequence[str], names: Sequence[str]) -> Dict[str, Any]:
  """style name -> the loaded NeRF run trained on that style alone, each checked."""
  singles = {}
  for d in run_dirs:
    single = load_run(d)
    style = single.record.get("style") or {}
    if single.kind != "nerf" or "name" not in style:
      raise UserError(f"{d}: not a single-style NeRF run (train one with `msnerf nerf train "
                      "--stylized DIR --style NAME`)")
    if style["name"] not in names:
      raise UserError(f"{d}: trained on style {style['name']!r}, which is not evaluated here "
                      f"({', '.join(names)})")
    singles[style["name"]] = single
  return singles


def _single_style_frames(single, name, scene, poses, chunk, progress):
  """(label, frames, geometry) of a single-style NeRF along the path."""
  renders = [render_view(scene, single.params, single.config, c2w, chunk)
             for c2w in progress_bar(poses, desc=f"single-style {name}", disable=not progress,
                                     leave=False)]
  return "nerf-single-style", [r["rgb"] for r in renders], renders


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
