"""The "features" run kind: the VGG relu4_1 feature field on a NeRF run's frozen geometry
(`msnerf features train`), painted in any style at render time by an AdaIN decoder."""

import os

import numpy as np

from msnerf_jax.core.config import FeatureConfig
from msnerf_jax.data.images import over_background, read_npy
from msnerf_jax.data.stylized import ORIGINAL
from msnerf_jax.kinds import views
from msnerf_jax.kinds.base import RunKind
from msnerf_jax.models.feature_field import init_feature_params
from msnerf_jax.models.nerf import init_nerf_params
from msnerf_jax.style.features import DEFAULT_GRIDS, painted_size, style_vector_of_stats

# A feature run's scene statistics (relu4_1 mean and std, [2, 512]): of its targets (the
# encoder's features of the training views), and of the trained field's own renders of those
# views at a step (what stylizing normalises by; see content_stats).
CONTENT_STATS = "content_stats.npy"
RENDERED_STATS = "rendered_stats_{step}.npy"


def content_stats(run):
  """(mean [512], std [512]) the features of a loaded feature run are normalised by before a
  style's statistics are put on: those of the field's own renders of the training views at
  the run's step, pooled over every cell (written when training ends). The rendered features
  are the mean of views that disagree, so their spread is narrower than the encoder's (a
  third of it on the demo scene); normalising by the encoder's statistics would shrink every
  style's contrast by as much. Runs without them (training stopped early, or made before
  they were written) fall back to the encoder's statistics of the training views."""
  path = os.path.join(run.run_dir, RENDERED_STATS.format(step=run.step))
  if not os.path.exists(path):
    path = os.path.join(run.run_dir, CONTENT_STATS)
  stats = read_npy(path, (2, 512))
  return stats[0], stats[1]


def feature_painting(run, scene):
  """What painting a loaded feature run's views in a style needs besides the style: its
  content statistics (content_stats), its "original" style vector (those statistics as a
  style: AdaIN towards them is the identity, so blending a style's vector towards it sets
  the strength) and the (height, width) its decoder paints a view of `scene` at (what a
  style picture is cover-cropped to, as per-frame AdaIN crops it).

  Returns: ((mean [512], std [512]), original [1024], (height, width)).
  """
  stats = content_stats(run)
  return (stats, style_vector_of_stats(stats),
          painted_size(scene.height, scene.width, run.config.stylize_scale))


def style_table(run, scene):
  """Its one named style, "original": the scene's own statistics (the strength control
  blends towards them), and the size style pictures are cover-cropped to."""
  _, original, size = feature_painting(run, scene)
  return {ORIGINAL: original}, size


def style_renderer(run, scene, chunk=None, grids=None, decoder=None):
  """Renders one camera of a loaded feature run in K styles: one feature render, K AdaIN
  maps and decodes by `decoder` (style.transfer.Decoder) on `grids` cell grids
  (views.render_feature_styles'; None: its default). On white-background (Blender) scenes
  the frames are put over white by the NeRF's opacity, as the stylized views a multi-style
  run learns are."""
  stats = content_stats(run)
  grids = grids or DEFAULT_GRIDS

  def render(camera, styles):
    frames = views.render_feature_styles(scene, run.params, run.config, camera, decoder,
                                         stats, np.stack(styles), chunk, grids)
    if not scene.white_background:
      return frames
    acc = views.render_view(scene, run.params["nerf"], run.config.nerf, camera,
                            chunk)["accumulation"][..., None]
    return over_background(frames, acc)
  return render


def init_params(config, key):
  """{"nerf": the NeRF run's params, frozen, "features": {"field", "lift"}}."""
  return {"nerf": init_nerf_params(config.nerf, key),
          "features": init_feature_params(config, config.scene_box, key)}


KIND = RunKind(
    name="features",
    config_class=FeatureConfig,
    train_command="msnerf features train",
    title="feature-field",
    params_layout=('{"nerf": the NeRF run\'s params (frozen, bit-identical), "features": '
                   '{"field": the hash-grid feature field, "lift": the lift to 512 channels}}'),
    init_params=init_params,
    nerf_config=lambda config: config.nerf,
    style_table=style_table,
    style_renderer=style_renderer,
    paints_any_style=True,
)
