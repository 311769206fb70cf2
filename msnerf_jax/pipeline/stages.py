"""The pipeline's stages as a table: each stage's name, the settings its output depends on
(its key in pipeline.json), whether its output is complete, how to run it and what it
writes. `msnerf_jax.pipeline.run` walks the table."""

import dataclasses
import json
import os
import shutil
from typing import Any, Callable, Dict, List, Optional, Sequence, Tuple

from msnerf_jax.core import config as config_lib
from msnerf_jax.core import files
from msnerf_jax.core.checkpoint import latest_saved_step
from msnerf_jax.data import images as images_lib
from msnerf_jax.data.scene import detect_format, load_scene
from msnerf_jax.data.stylized import MANIFEST, load_stylized
from msnerf_jax.kinds import features as feature_kind
from msnerf_jax.kinds import stylized_scenes
from msnerf_jax.pipeline import renders
from msnerf_jax.pipeline.settings import (Settings, adain_config, feature_config,
                                          multistyle_config, nerf_config, paint_config)
from msnerf_jax.train import adain as train_adain
from msnerf_jax.train import features as train_features
from msnerf_jax.train import multistyle as train_multistyle
from msnerf_jax.train import nerf as train_nerf
from msnerf_jax.train import paint as train_paint


@dataclasses.dataclass
class Context:
  """One pipeline call: its inputs (absolute paths), settings and the scene, loaded on first
  use (a fully cached re-run never loads it)."""
  out: str
  data: str
  styles: List[str]
  decoder: Optional[str]  # a given decoder run, or None: the adain stage trains one.
  settings: Settings
  progress: bool
  log: Callable[[str], None]
  names: List[str]  # the stylized dataset's styles.
  _scene: Any = None

  @property
  def decoder_dir(self) -> str:
    return self.decoder or self.path("adain")

  def path(self, *parts: str) -> str:
    return os.path.join(self.out, *parts)

  def scene(self):
    """(scene, data config), loaded once."""
    if self._scene is None:
      s = self.settings
      self._scene = load_scene(config_lib.DataConfig(
          path=self.data, downscale=s.downscale, format=s.format, layout=s.layout))
    return self._scene


@dataclasses.dataclass(frozen=True)
class Stage:
  """A stage: `key` (what its output depends on, saved in pipeline.json), `done` (its output
  is complete), `run` (runs or resumes it; returns its outputs), `outputs` (when skipped),
  `skip` ((status, message) when it does not run at all, else None). After a stage runs,
  JAX's compiled programs are dropped (they hold memory the next stage needs) unless
  `keep_compiled`: the next stage renders with them."""
  name: str
  key: Callable[[Context], Dict[str, Any]]
  done: Callable[[Context], bool]
  run: Callable[[Context], List[str]]
  outputs: Callable[[Context], List[str]]
  skip: Callable[[Context], Optional[Tuple[str, str]]] = lambda c: None
  keep_compiled: bool = False


def _base(c: Context) -> Dict[str, Any]:
  s = c.settings
  base = {"data": c.data, "downscale": s.downscale, "seed": s.seed}
  if (s.format, s.layout) != ("auto", "auto"):  # records of earlier versions stay valid
    base.update(format=s.format, layout=s.layout)
  return base


# ----------------------------------------------------------------------------- adain


def _inputs(c: Context):
  """inputs/content (training views, composited) and inputs/styles (copies of the styles)."""
  content_dir, style_dir = c.path("inputs", "content"), c.path("inputs", "styles")
  scene, _ = c.scene()
  for k, i in enumerate(scene.split("train")):
    path = os.path.join(content_dir, f"{k:04d}.png")
    if not os.path.exists(path):
      images_lib.write_image(path, scene.images[i])
  os.makedirs(style_dir, exist_ok=True)
  for path in c.styles:
    target = os.path.join(style_dir, os.path.basename(path))
    if not os.path.exists(target):
      with files.atomic_path(target) as tmp:
        shutil.copyfile(path, tmp)
  return content_dir, style_dir


def _adain_key(c: Context):
  return {**_base(c), "styles": c.styles, "config": config_lib.to_dict(adain_config(c.settings))}


def _run_adain(c: Context):
  content_dir, style_dir = _inputs(c)
  train_adain.train(adain_config(c.settings), [content_dir], style_dir, c.path("adain"),
                    progress=c.progress, log=lambda m: c.log("    " + m))
  return [c.path("adain")]


def _given_decoder(c: Context):
  return None if c.decoder is None else ("given", f"using the given decoder {c.decoder}")


# ----------------------------------------------------------------------------- nerf


def _nerf_key(c: Context):
  s = c.settings
  return {**_base(c), "preset": s.preset, "steps": s.nerf_steps, "batch": s.nerf_batch_rays}


def _nerf_steps(c: Context) -> int:
  s = c.settings
  if s.nerf_steps:
    return s.nerf_steps
  return config_lib.nerf_preset(s.preset, detect_format(c.data) if s.format == "auto"
                                else s.format).optim.steps


def _run_nerf(c: Context):
  scene, data_config = c.scene()
  train_nerf.train(scene, nerf_config(c.settings, data_config.format), data_config,
                   c.path("nerf"), progress=c.progress)
  return [c.path("nerf")]


# ----------------------------------------------------------------------------- stylized


def _stylized_key(c: Context):
  return {**_base(c), "styles": c.styles, "decoder": c.decoder_dir,
          "upstream": _adain_key(c) if c.decoder is None else c.decoder_dir}


def _stylized_done(c: Context) -> bool:
  try:
    with open(c.path("stylized", MANIFEST)) as f:
      manifest = json.load(f)
    return ([x["name"] for x in manifest["styles"]] == list(c.names)
            and set(manifest["done"]) >= set(c.names))
  except (OSError, ValueError, KeyError, TypeError):
    return False


def _run_stylized(c: Context):
  s = c.settings
  stylized_scenes.stylize_scene_folder(c.data, c.decoder_dir, c.styles, c.path("stylized"),
                                       include_original=True, downscale=s.downscale,
                                       progress=c.progress, scene_format=s.format,
                                       layout=s.layout)
  return [c.path("stylized")]


# ----------------------------------------------------------------------------- multistyle


def _multistyle_key(c: Context):
  s = c.settings
  return {**_base(c), "steps": s.ms_steps, "batch": s.ms_batch_rays,
          "upstream": [_nerf_key(c), _stylized_key(c)]}


def _run_multistyle(c: Context):
  stylized = load_stylized(c.path("stylized"), progress=c.progress)
  train_multistyle.train(multistyle_config(c.settings), c.path("nerf"), stylized,
                         c.path("multistyle"), progress=c.progress)
  return [c.path("multistyle")]


# ----------------------------------------------------------------------------- features


def _features_key(c: Context):
  return {**_base(c), "config": config_lib.to_dict(feature_config(c.settings)),
          "upstream": [_nerf_key(c), _stylized_key(c)["upstream"]]}


def _features_done(c: Context) -> bool:
  """Trained to its steps, with the statistics of its renders written (the trainer's last
  act)."""
  run_dir = c.path("features")
  step = latest_saved_step(run_dir)
  return step >= c.settings.features_steps and os.path.exists(
      os.path.join(run_dir, feature_kind.RENDERED_STATS.format(step=step)))


def _run_features(c: Context):
  train_features.train(feature_config(c.settings), c.path("nerf"), c.decoder_dir,
                       c.path("features"), progress=c.progress)
  return [c.path("features")]


def _features_off(c: Context):
  return None if c.settings.features_steps else ("off", "off (--features-steps 0)")


# ----------------------------------------------------------------------------- painted


def _painted_key(c: Context):
  return {**_base(c), "config": config_lib.to_dict(paint_config(c.settings)),
          "styles": c.styles, "upstream": _nerf_key(c)}


def _run_painted(c: Context):
  train_paint.train(paint_config(c.settings), c.path("nerf"), c.styles, c.path("painted"),
                    progress=c.progress)
  return [c.path("painted")]


def _painted_off(c: Context):
  return None if c.settings.paint_steps else ("off", "off (--paint-steps 0)")


# ----------------------------------------------------------------------------- renders


def _renders_key(c: Context):
  s = c.settings
  key = {"frames": s.frames, "fps": s.fps, "grid_views": s.grid_views,
         "upstream": _multistyle_key(c)}
  if s.features_steps:  # records of earlier versions (no feature field) stay valid
    key.update(features=_features_key(c), styles=c.styles)
  # The grid's per-frame AdaIN column and the painted videos (earlier records drew neither).
  key.update(per_frame=_stylized_key(c))
  if s.paint_steps:
    key.update(painted=_painted_key(c))
  return key


def _render_outputs(c: Context):
  return [c.path("renders", f) for f in renders.render_files(c.settings)]


def _trained(name: str, steps: Callable[[Settings], int]):
  """`done` of a trainer's stage: its run folder has a checkpoint at `steps` or later."""
  return lambda c: latest_saved_step(c.path(name)) >= steps(c)


def _folder(name: str):
  return lambda c: [c.path(name)]


STAGES: Sequence[Stage] = (
    Stage("adain", _adain_key, _trained("adain", lambda c: c.settings.adain_steps), _run_adain,
          _folder("adain"), _given_decoder),
    Stage("nerf", _nerf_key, _trained("nerf", _nerf_steps), _run_nerf, _folder("nerf")),
    Stage("stylized", _stylized_key, _stylized_done, _run_stylized, _folder("stylized")),
    Stage("multistyle", _multistyle_key, _trained("multistyle", lambda c: c.settings.ms_steps),
          _run_multistyle, _folder("multistyle")),
    Stage("features", _features_key, _features_done, _run_features, _folder("features"),
          _features_off),
    Stage("painted", _painted_key, _trained("painted", lambda c: c.settings.paint_steps),
          _run_painted, _folder("painted"), _painted_off, keep_compiled=True),
    Stage("renders", _renders_key, lambda c: all(map(os.path.exists, _render_outputs(c))),
          lambda c: renders.run_renders(c.out, c.styles, c.decoder_dir, c.settings, c.progress),
          _render_outputs),
)
