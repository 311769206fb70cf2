"""Every stage in one call: AdaIN decoder -> NeRF -> stylized dataset -> multi-style NeRF ->
feature field -> renders.

Each stage writes one subfolder of the output folder:

  inputs/      the scene's training views (the decoder's content images) and the style images
  adain/       the AdaIN decoder run            (skipped when a decoder run is given)
  nerf/        the NeRF run
  stylized/    the stylized dataset (every view in every style, plus the original)
  multistyle/  the multi-style NeRF run (the paper's model)
  features/    the feature-field run (AdaIN in 3D; skipped with features_steps 0)
  renders/     styles.mp4/.gif (all styles side by side along the orbit), morph.mp4/.gif (one
               orbit whose style morphs through the styles), features.mp4/.gif (as styles.mp4,
               painted by the feature field) and grid.png (styles x views, the paper's model and
               the feature field side by side)

plus pipeline.json (what each stage was run with) and summary.json / summary.txt.

Caching: a stage whose output is complete and whose settings are those recorded in
pipeline.json is skipped. Otherwise it is run, and resumes: the trainers continue from their
latest checkpoint and the stylized dataset from its last finished image, so an interrupted
pipeline re-run with the same command picks up where it stopped.
"""

import dataclasses
import json
import os
import shutil
import time
from typing import Any, Callable, Dict, Optional, Sequence, Tuple

import numpy as np

from msnerf_jax.core import config as config_lib
from msnerf_jax.kinds import features as feature_kind
from msnerf_jax.kinds import stylized_scenes
from msnerf_jax.core import files
from msnerf_jax.data import images as images_lib
from msnerf_jax.core.errors import UserError

RECORD = "pipeline.json"
STAGES = ("adain", "nerf", "stylized", "multistyle", "features", "renders")


@dataclasses.dataclass(frozen=True)
class Settings:
  """Sizes and lengths of every stage (the `msnerf pipeline` options)."""
  downscale: int = 0  # scene image downscale (0 = the format's default).
  format: str = "auto"  # scene format (DataConfig.format).
  layout: str = "auto"  # capture layout (DataConfig.layout).
  adain_steps: int = 2000
  adain_size: int = 96  # side of the decoder's training crops (images are resized to it).
  adain_batch: int = 2
  adain_lr: float = 2e-4
  style_weight: float = 10.0
  # NeRF preset: `fast` (hash grid + occupancy grid) trains lego and fern to 5 dB more than
  # `cpu` in the same time and renders lego 6.6x faster, fern as fast (README, Benchmarks).
  preset: str = "fast"
  nerf_steps: int = 0  # 0 = the preset's.
  nerf_batch_rays: int = 0  # 0 = the preset's.
  ms_steps: int = 3000
  ms_batch_rays: int = 1024
  features_steps: int = 2000  # 0 = no feature field.
  features_batch_cells: int = 512
  frames: int = 0  # frames of the videos (0 = the scene's whole render path).
  fps: int = 12
  grid_views: int = 4
  chunk: int = 0  # rays per rendering call (0 = the config's).
  seed: int = 0


def _checkpoint_step(run_dir: str) -> int:
  """Step of the latest complete checkpoint of a run folder (0 = none)."""
  folder = os.path.join(run_dir, "checkpoints")
  if not os.path.isfile(os.path.join(run_dir, "run.json")) or not os.path.isdir(folder):
    return 0
  steps = [int(n) for n in os.listdir(folder) if n.isdigit()]
  return max(steps, default=0)


def _load_record(out: str) -> Dict[str, Any]:
  path = os.path.join(out, RECORD)
  if not os.path.exists(path):
    return {"stages": {}}
  record = images_lib.read_json(path, "; delete it to re-check every stage")
  if not isinstance(record, dict) or not isinstance(record.get("stages"), dict):
    raise UserError(f"{path}: not a pipeline record; delete it to re-check every stage")
  return record


def _save_record(out: str, record: Dict[str, Any]) -> None:
  files.write_json(os.path.join(out, RECORD), record)


class _Scene:
  """The scene, loaded on first use (a fully cached re-run never loads it)."""

  def __init__(self, data: str, s: "Settings"):
    self.config = config_lib.DataConfig(path=os.path.abspath(data), downscale=s.downscale,
                                        format=s.format, layout=s.layout)
    self._loaded = None

  def get(self):
    if self._loaded is None:
      from msnerf_jax.data.scene import load_scene  # pylint: disable=g-import-not-at-top
      self._loaded = load_scene(self.config)
    return self._loaded


# ----------------------------------------------------------------------------- the stages


def _inputs(out: str, scene: _Scene, styles: Sequence[str]):
  """inputs/content (training views, composited) and inputs/styles (copies of the styles)."""
  content_dir = os.path.join(out, "inputs", "content")
  style_dir = os.path.join(out, "inputs", "styles")
  scene_obj, _ = scene.get()
  for k, i in enumerate(scene_obj.split("train")):
    path = os.path.join(content_dir, f"{k:04d}.png")
    if not os.path.exists(path):
      images_lib.write_image(path, scene_obj.images[i])
  os.makedirs(style_dir, exist_ok=True)
  for path in styles:
    target = os.path.join(style_dir, os.path.basename(path))
    if not os.path.exists(target):
      with files.atomic_path(target) as tmp:
        shutil.copyfile(path, tmp)
  return content_dir, style_dir


def adain_config(s: Settings) -> config_lib.AdainConfig:
  return config_lib.AdainConfig(
      size=s.adain_size, resize=s.adain_size, batch=s.adain_batch, steps=s.adain_steps,
      lr=s.adain_lr, style_weight=s.style_weight, seed=s.seed,
      sample_every=max(1, min(500, s.adain_steps)),
      checkpoint_every=max(1, min(500, s.adain_steps)))


def _run_adain(out, scene, styles, s: Settings, progress, log):
  from msnerf_jax.train import adain as train_adain  # pylint: disable=g-import-not-at-top
  content_dir, style_dir = _inputs(out, scene, styles)
  run_dir = os.path.join(out, "adain")
  train_adain.train(adain_config(s), [content_dir], style_dir, run_dir, progress=progress,
                    log=lambda m: log("    " + m))
  return [run_dir]


def nerf_config(s: Settings, scene_format: str) -> config_lib.NerfConfig:
  return config_lib.nerf_preset(s.preset, scene_format, steps=s.nerf_steps or None,
                                batch_rays=s.nerf_batch_rays or None, seed=s.seed,
                                checkpoint_every=min(500, s.nerf_steps) if s.nerf_steps else None)


def _run_nerf(out, scene, s: Settings, progress):
  from msnerf_jax.train import nerf  # pylint: disable=g-import-not-at-top
  scene_obj, data_config = scene.get()
  run_dir = os.path.join(out, "nerf")
  nerf.train(scene_obj, nerf_config(s, data_config.format), data_config, run_dir,
             progress=progress)
  return [run_dir]


def _stylized_done(folder: str, names: Sequence[str]) -> bool:
  from msnerf_jax.data.stylized import MANIFEST  # pylint: disable=g-import-not-at-top
  try:
    with open(os.path.join(folder, MANIFEST)) as f:
      manifest = json.load(f)
    return ([x["name"] for x in manifest["styles"]] == list(names)
            and set(manifest["done"]) >= set(names))
  except (OSError, ValueError, KeyError, TypeError):
    return False


def _run_stylized(out, data, decoder, styles, s: Settings, progress):
  from msnerf_jax.style import transfer as stylize  # pylint: disable=g-import-not-at-top
  folder = os.path.join(out, "stylized")
  stylized_scenes.stylize_scene_folder(data, decoder, styles, folder, include_original=True,
                               downscale=s.downscale, progress=progress, scene_format=s.format,
                               layout=s.layout)
  return [folder]


def multistyle_config(s: Settings) -> config_lib.MultistyleConfig:
  return config_lib.MultistyleConfig(steps=s.ms_steps, batch_rays=s.ms_batch_rays, seed=s.seed,
                                     checkpoint_every=max(1, min(500, s.ms_steps)))


def _run_multistyle(out, s: Settings, progress):
  # pylint: disable=g-import-not-at-top
  from msnerf_jax.data.stylized import load_stylized
  from msnerf_jax.train import multistyle
  run_dir = os.path.join(out, "multistyle")
  stylized = load_stylized(os.path.join(out, "stylized"), progress=progress)
  multistyle.train(multistyle_config(s), os.path.join(out, "nerf"), stylized, run_dir,
                   progress=progress)
  return [run_dir]


def feature_config(s: Settings) -> config_lib.FeatureConfig:
  return config_lib.FeatureConfig(steps=s.features_steps, batch_cells=s.features_batch_cells,
                                  lr_decay_steps=max(1, s.features_steps), seed=s.seed,
                                  checkpoint_every=max(1, min(500, s.features_steps)))


def _features_done(run_dir: str, steps: int) -> bool:
  """Trained to `steps`, with the statistics of its renders written (the trainer's last act)."""
  step = _checkpoint_step(run_dir)
  return step >= steps and os.path.exists(
      os.path.join(run_dir, feature_kind.RENDERED_STATS.format(step=step)))


def _run_features(out, decoder_dir, s: Settings, progress):
  from msnerf_jax.train import features  # pylint: disable=g-import-not-at-top
  run_dir = os.path.join(out, "features")
  features.train(feature_config(s), os.path.join(out, "nerf"), decoder_dir, run_dir,
                 progress=progress)
  return [run_dir]


def render_files(s: Settings) -> Tuple[str, ...]:
  """The files the renders stage writes."""
  return (("styles.mp4", "styles.gif", "morph.mp4", "morph.gif", "grid.png")
          + (("features.mp4", "features.gif") if s.features_steps else ()))


def _feature_renderer(out, styles, names, s: Settings):
  """Renders one camera in the styles `names` by the feature run (the statistics of the style
  images cover-cropped as per-frame AdaIN crops them; "original": the scene's own, i.e. the
  decoder's picture of the scene's features)."""
  # pylint: disable=g-import-not-at-top
  from msnerf_jax.kinds import runs
  from msnerf_jax.kinds.renderers import style_rendering
  from msnerf_jax.style import vectors as styles_lib
  from msnerf_jax.data.stylized import style_name
  run, scene = runs.load_run_and_scene(os.path.join(out, "features"), "features")
  table, size, render = style_rendering(run, scene, s.chunk or None)
  cache = {}
  vectors = {**table,
             **{style_name(p): styles_lib.resolve_style(p, {}, cache, size) for p in styles}}
  return lambda c2w: render(c2w, [vectors[n] for n in names])


def _style_tile(styles, name, scene):
  """The grid's first column: the style picture of `name` cover-cropped to the view's size,
  or, for the original, the first training photo."""
  from msnerf_jax.data.stylized import style_name  # pylint: disable=g-import-not-at-top
  paths = {style_name(p): p for p in styles}
  if name not in paths:
    return scene.images[scene.split("train")[0]]
  return images_lib.cover_crop(images_lib.read_image(paths[name], max_side=1024), scene.height,
                               scene.width)


def _run_renders(out, styles, s: Settings, progress):
  # pylint: disable=g-import-not-at-top
  from msnerf_jax.core.progress import progress_bar
  from msnerf_jax.pipeline import videos as style_videos
  from msnerf_jax.style import vectors as styles_lib
  from msnerf_jax.data import video
  from msnerf_jax.kinds.renderers import style_rendering
  from msnerf_jax.kinds.runs import load_run_and_scene
  run, scene = load_run_and_scene(os.path.join(out, "multistyle"), "multistyle")
  vectors, _, render = style_rendering(run, scene, s.chunk or None)
  names = list(vectors)
  poses = scene.path_poses(s.frames)
  folder = os.path.join(out, "renders")
  # All styles at once per camera (one trunk pass): the side-by-side video and the grid.
  sweeps = [render(c2w, list(vectors.values()))
            for c2w in progress_bar(poses, desc="render styles", disable=not progress)]
  written = video.write_videos(os.path.join(folder, "styles"),
                               [video.grid([sw]) for sw in sweeps], s.fps)
  morph_names = [n for n in names if n != styles_lib.ORIGINAL] or names
  path = styles_lib.morph_loop([vectors[n] for n in morph_names], len(poses))
  frames = [render(c2w, [v])[0] for c2w, v in progress_bar(
      list(zip(poses, path)), desc="render morph", disable=not progress)]
  written += video.write_videos(os.path.join(folder, "morph"), frames, s.fps)
  views = np.linspace(0, len(poses), max(1, s.grid_views) + 1)[:-1].round().astype(int)
  groups = [[[_style_tile(styles, n, scene)], [sweeps[v][m] for v in views]]
            for m, n in enumerate(names)]
  labels = ["style", "multi-style NeRF (paper)"]
  if s.features_steps:
    # One feature render per camera, every style painted from it.
    render_features = _feature_renderer(out, styles, names, s)
    feature_sweeps = [render_features(c2w) for c2w in progress_bar(
        poses, desc="render feature field", disable=not progress)]
    written += video.write_videos(os.path.join(folder, "features"),
                                  [video.grid([sw]) for sw in feature_sweeps],
                                  s.fps)
    for m, row in enumerate(groups):
      row.append([feature_sweeps[v][m] for v in views])
    labels.append("feature field (AdaIN in 3D)")
  path = os.path.join(folder, "grid.png")
  images_lib.write_image(path, video.labelled_grid(groups, names, labels))
  written.append(path)
  files.atomic_write_bytes(os.path.join(folder, "grid_rows.txt"),
                           "".join(n + "\n" for n in names).encode())
  return written


# ----------------------------------------------------------------------------- the driver


def check_inputs(data: str, styles: Sequence[str], out: str, decoder: Optional[str],
                 s: Settings) -> None:
  """Cheap checks of every input before any stage starts."""
  if not os.path.isdir(data):
    raise UserError(f"{data}: no such scene folder")
  if not styles:
    raise UserError("--styles: give at least one style image")
  for path in styles:
    if not os.path.isfile(path):
      raise UserError(f"{path}: no such style image")
  if os.path.exists(out) and not os.path.isdir(out):
    raise UserError(f"{out}: is a file, expected an output folder")
  if decoder is not None and not os.path.isfile(os.path.join(decoder, "run.json")):
    raise UserError(f"{decoder}: not an AdaIN run folder (no run.json)")
  if s.preset not in config_lib.PRESETS:
    raise UserError(f"--preset {s.preset}: choose from {', '.join(config_lib.PRESETS)}")
  for name in ("adain_steps", "ms_steps", "adain_batch", "ms_batch_rays", "fps", "grid_views",
               "features_batch_cells"):
    if getattr(s, name) < 1:
      raise UserError(f"--{name.replace('_', '-')} {getattr(s, name)}: must be >= 1")
  for name in ("nerf_steps", "nerf_batch_rays", "frames", "chunk", "downscale",
               "features_steps"):
    if getattr(s, name) < 0:
      raise UserError(f"--{name.replace('_', '-')} {getattr(s, name)}: must be >= 0")
  if s.adain_size < 16 or s.adain_size % 8:
    raise UserError(f"--adain-size {s.adain_size}: must be a multiple of 8, at least 16")


def run_pipeline(data: str, styles: Sequence[str], out: str, decoder: Optional[str] = None,
                 settings: Settings = Settings(), progress: bool = True,
                 log: Callable[[str], None] = print) -> Dict[str, Any]:
  """Runs (or completes) every stage; returns the summary (also in OUT/summary.json)."""
  s = settings
  check_inputs(data, styles, out, decoder, s)
  data = os.path.abspath(data)
  styles = [os.path.abspath(p) for p in styles]
  os.makedirs(out, exist_ok=True)
  record = _load_record(out)
  scene = _Scene(data, s)
  from msnerf_jax.data.stylized import ORIGINAL, style_name  # pylint: disable=g-import-not-at-top
  names = [style_name(p) for p in styles] + [ORIGINAL]
  decoder_dir = os.path.abspath(decoder) if decoder else os.path.join(out, "adain")
  base = {"data": data, "downscale": s.downscale, "seed": s.seed}
  if (s.format, s.layout) != ("auto", "auto"):  # records of earlier versions stay valid
    base.update(format=s.format, layout=s.layout)
  keys = {
      "adain": {**base, "styles": styles, "config": config_lib.to_dict(adain_config(s))},
      "nerf": {**base, "preset": s.preset, "steps": s.nerf_steps, "batch": s.nerf_batch_rays},
      "stylized": {**base, "styles": styles, "decoder": decoder_dir},
      "multistyle": {**base, "steps": s.ms_steps, "batch": s.ms_batch_rays},
      "features": {**base, "config": config_lib.to_dict(feature_config(s))},
      "renders": {"frames": s.frames, "fps": s.fps, "grid_views": s.grid_views},
  }
  keys["stylized"]["upstream"] = keys["adain"] if decoder is None else decoder_dir
  keys["multistyle"]["upstream"] = [keys["nerf"], keys["stylized"]]
  keys["features"]["upstream"] = [keys["nerf"], keys["stylized"]["upstream"]]
  keys["renders"]["upstream"] = keys["multistyle"]
  if s.features_steps:  # records of earlier versions (no feature field) stay valid
    keys["renders"].update(features=keys["features"], styles=styles)

  def nerf_steps():
    if s.nerf_steps:
      return s.nerf_steps
    from msnerf_jax.data.scene import detect_format  # pylint: disable=g-import-not-at-top
    return config_lib.nerf_preset(s.preset, detect_format(data) if s.format == "auto"
                                  else s.format).steps

  stages = {
      "adain": (lambda: _checkpoint_step(os.path.join(out, "adain")) >= s.adain_steps,
                lambda: _run_adain(out, scene, styles, s, progress, log),
                [os.path.join(out, "adain")]),
      "nerf": (lambda: _checkpoint_step(os.path.join(out, "nerf")) >= nerf_steps(),
               lambda: _run_nerf(out, scene, s, progress), [os.path.join(out, "nerf")]),
      "stylized": (lambda: _stylized_done(os.path.join(out, "stylized"), names),
                   lambda: _run_stylized(out, data, decoder_dir, styles, s, progress),
                   [os.path.join(out, "stylized")]),
      "multistyle": (lambda: _checkpoint_step(os.path.join(out, "multistyle")) >= s.ms_steps,
                     lambda: _run_multistyle(out, s, progress),
                     [os.path.join(out, "multistyle")]),
      "features": (lambda: _features_done(os.path.join(out, "features"), s.features_steps),
                   lambda: _run_features(out, decoder_dir, s, progress),
                   [os.path.join(out, "features")]),
      "renders": (lambda: all(os.path.exists(os.path.join(out, "renders", f))
                              for f in render_files(s)),
                  lambda: _run_renders(out, styles, s, progress),
                  [os.path.join(out, "renders", f) for f in render_files(s)]),
  }
  results = []
  t_all = time.time()
  for k, name in enumerate(STAGES, 1):
    done_fn, run_fn, outputs = stages[name]
    tag = f"[{k}/{len(STAGES)}] {name}"
    if name == "adain" and decoder is not None:
      log(f"{tag}: using the given decoder {decoder}")
      results.append({"stage": name, "status": "given", "seconds": 0.0, "outputs": [decoder]})
      continue
    if name == "features" and not s.features_steps:
      log(f"{tag}: off (--features-steps 0)")
      results.append({"stage": name, "status": "off", "seconds": 0.0, "outputs": []})
      continue
    saved = record["stages"].get(name, {})
    if saved.get("key") == keys[name] and done_fn():
      log(f"{tag}: already complete, skipped ({outputs[0]})")
      results.append({"stage": name, "status": "skipped", "seconds": 0.0,
                      "trained_seconds": saved.get("seconds", 0.0), "outputs": outputs})
      continue
    log(f"{tag}: running ...")
    t0 = time.time()
    outputs = run_fn()
    seconds = time.time() - t0
    log(f"{tag}: done in {seconds:.1f} s")
    record["stages"][name] = {"key": keys[name], "seconds": round(seconds, 1),
                              "outputs": outputs}
    _save_record(out, record)
    results.append({"stage": name, "status": "ran", "seconds": round(seconds, 1),
                    "outputs": outputs})
  summary = {"out": os.path.abspath(out), "data": data, "styles": styles,
             "seconds": round(time.time() - t_all, 1), "stages": results,
             "settings": dataclasses.asdict(s)}
  files.atomic_write_bytes(os.path.join(out, "summary.json"),
                                json.dumps(summary, indent=2).encode())
  files.atomic_write_bytes(os.path.join(out, "summary.txt"), format_summary(summary).encode())
  return summary


def format_summary(summary: Dict[str, Any]) -> str:
  """The summary as aligned text lines (printed at the end and saved as summary.txt)."""
  lines = [f"pipeline {summary['out']}: {summary['seconds']:.1f} s in all"]
  for r in summary["stages"]:
    if r["status"] == "ran":
      what = f"ran in {r['seconds']:.1f} s"
    elif r["status"] == "skipped":
      what = f"skipped (done before, took {r.get('trained_seconds', 0.0):.1f} s)"
    else:
      what = r["status"]
    lines.append(f"  {r['stage']:<11} {what}")
    for path in r["outputs"]:
      lines.append(f"  {'':<11}   {path}")
  if summary["settings"].get("features_steps"):
    lines.append(f"paint it in any style: msnerf render --run "
                 f"{os.path.join(summary['out'], 'features')} --style IMG --out VIDEO")
  lines.append(f"look around it in the browser: msnerf view --run "
               f"{os.path.join(summary['out'], 'multistyle')}")
  return "\n".join(lines) + "\n"
