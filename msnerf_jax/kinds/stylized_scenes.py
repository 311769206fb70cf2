"""Stylized datasets made from runs: a scene folder's views painted by an AdaIN decoder run
(`msnerf stylize-scene`), or a feature run's renders of them painted in 3D
(`--from-features`). Also the loader of a decoder run."""

import os
from typing import Any, Dict, Optional, Sequence, Tuple

import jax
import jax.numpy as jnp

from msnerf_jax.core import config as config_lib
from msnerf_jax.core.errors import UserError
from msnerf_jax.data import stylized as stylized_lib
from msnerf_jax.data.scene import Scene, load_scene
from msnerf_jax.kinds import features as feature_kind
from msnerf_jax.kinds import runs as runs_lib
from msnerf_jax.kinds import views
from msnerf_jax.models import decoder as decoder_lib
from msnerf_jax.models import vgg
from msnerf_jax.style import transfer
from msnerf_jax.style.transfer import Decoder
from msnerf_jax.style.vectors import style_vector_of


def load_decoder(run_dir: str) -> Decoder:
  """Loads and checks an AdaIN run folder (kind, encoder, parameter shapes).

  Raises:
    UserError naming the file when it is not an AdaIN run, was trained against another
    encoder, or its checkpoint has other layer sizes.
  """
  run_file = os.path.join(run_dir, runs_lib.RUN_FILE)
  record = runs_lib.read_run_file(run_dir, "adain")
  config = config_lib.from_dict(config_lib.AdainConfig, record["config"], run_file)
  if config.encoder != vgg.ENCODER_NAME:
    raise UserError(f"{run_file}: decoder trained for encoder {config.encoder!r}, "
                    f"this build has {vgg.ENCODER_NAME!r}")
  if config.upsample not in decoder_lib.UPSAMPLE_MODES:
    raise UserError(f"{run_file}: unknown upsample mode {config.upsample!r}")
  run = runs_lib.load_run(run_dir)  # checks the layers against the config's decoder.
  params = jax.tree_util.tree_map(lambda a: jnp.asarray(a, jnp.float32), run.params)
  return Decoder(run_dir=run_dir, config=config, params=params, step=run.step)


def stylize_scene_folder(data: str, decoder_dir: str, style_paths: Sequence[str], out: str,
                         alphas: Optional[Sequence[float]] = None, include_original: bool = False,
                         downscale: int = 0, stylize_scale: int = 1, scene_stats: bool = False,
                         progress: bool = True, scene_format: str = "auto",
                         layout: str = "auto") -> Tuple[Dict[str, Any], Scene]:
  """Writes (or completes) the stylized dataset of the scene folder `data` in `out`: every
  view in every style image by the AdaIN decoder of `decoder_dir` (`msnerf stylize-scene`).

  Args:
    alphas: strength per style in [0, 1] (default 1 each).
    include_original: add the unstylized views as the style "original".
    downscale: the scene's image downscale (0 = the format's default).
    scene_format, layout: as DataConfig's (a capture read as COLMAP or LLFF, ...).
    stylize_scale: stylize each view enlarged this many times (see `stylize_image`).
    scene_stats: normalise every view by the training views' statistics
      (`scene_content_stats`) instead of its own.
  Returns:
    (data.stylized.stylize_scene's summary dict, the loaded scene).
  """
  alphas = list(alphas) if alphas is not None else [1.0] * len(style_paths)
  decoder = load_decoder(decoder_dir)
  scene, data_config = load_scene(config_lib.DataConfig(
      path=os.path.abspath(data), downscale=downscale, format=scene_format, layout=layout))
  encoder = vgg.load_vgg_params()
  summary = stylized_lib.stylize_scene(
      scene, data_config,
      lambda _, view, style, alpha, scale, stats: transfer.stylize_image(
          decoder, encoder, view, [style], alpha=alpha, scale=scale, content_stats=stats),
      lambda image: style_vector_of(encoder, image),
      style_paths, alphas, include_original, out, progress=progress,
      decoder=decoder_dir, stylize_scale=stylize_scale,
      content_stats_fn=(lambda views, scale: transfer.scene_content_stats(
          encoder, views, scale, progress=progress)) if scene_stats else None)
  return summary, scene


def stylize_scene_from_features(run_dir: str, style_paths: Sequence[str], out: str,
                                alphas: Optional[Sequence[float]] = None,
                                include_original: bool = False,
                                decoder_dir: Optional[str] = None, progress: bool = True,
                                chunk: Optional[int] = None) -> Tuple[Dict[str, Any], Scene]:
  """As `stylize_scene_folder`, but every view is the feature run's render of its camera,
  stylized in 3D (`msnerf stylize-scene --from-features RUN`): the scene's pooled content
  statistics, each style image's own, the strength `alpha` a blend of the two, and the
  decoder of the feature run (or `decoder_dir`). The scene, downscale and stylize scale are
  the feature run's."""
  run = runs_lib.load_run(run_dir, "features")
  scene, data_config = runs_lib.scene_of(run)
  decoder_dir = decoder_dir or run.record["decoder"]
  decoder = load_decoder(decoder_dir)
  stats, original, size = feature_kind.feature_painting(run, scene)
  encoder = vgg.load_vgg_params()
  last = {"picture": None, "vector": None}  # stylize_scene goes style by style: one encoding each

  def stylize_fn(index, view, style, alpha, scale, content_stats):
    del view, scale, content_stats  # the feature run's camera, stylize scale and statistics.
    if last["picture"] is not style:
      last.update(picture=style, vector=style_vector_of(encoder, style, size))
    # AdaIN is one affine map per channel: blending the statistics blends the features.
    vector = (1.0 - alpha) * original + alpha * last["vector"]
    # The view index, not its pose: a capture's views each have their own intrinsics.
    return views.render_feature_styles(scene, run.params, run.config, int(index), decoder,
                                       stats, vector[None], chunk)[0]

  summary = stylized_lib.stylize_scene(
      scene, data_config, stylize_fn,
      lambda image: style_vector_of(encoder, image),
      style_paths, list(alphas) if alphas is not None else [1.0] * len(style_paths),
      include_original, out, progress=progress, decoder=decoder_dir,
      stylize_scale=run.config.stylize_scale, features=run_dir)
  return summary, scene
