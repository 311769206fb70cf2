"""A feature run's targets: the encoder's relu4_1 maps of the training views, cached in the run
folder, and the statistics of the trained field's own renders of them (what painting
normalises by)."""

import os
from typing import Tuple

import jax.numpy as jnp
import numpy as np

from msnerf_jax.kinds import features as feature_kind
from msnerf_jax.kinds import runs as runs_lib
from msnerf_jax.style import transfer as stylize_lib
from msnerf_jax.style.adain import encode
from msnerf_jax.core.config import FeatureConfig
from msnerf_jax.data.images import read_npy
from msnerf_jax.data.scene import Scene
from msnerf_jax.style.features import pooled_stats
from msnerf_jax.core.files import write_npy
from msnerf_jax.models import vgg
from msnerf_jax.core.progress import progress_bar

TARGETS = "targets.npy"  # [N, h, w, 512] float16: relu4_1 of the training views.


def view_targets(encoder, views, scale: int, progress: bool = False) -> np.ndarray:
  """relu4_1 of each view enlarged (stylize.enlarged): [N, ceil(sH/8), ceil(sW/8), 512]
  float16."""
  out = []
  for view in progress_bar(views, desc="feature targets", disable=not progress, leave=False):
    big = stylize_lib.enlarged(view, scale)
    out.append(np.asarray(encode(encoder, jnp.asarray(big[None]))["relu4_1"][0], np.float16))
  return np.stack(out)


def prepare_targets(run_dir: str, scene: Scene, config: FeatureConfig,
                    progress: bool = False) -> None:
  """Writes the run's target cache and the scene's content statistics (pooled over every
  cell of every training view) unless they are there already."""
  path = os.path.join(run_dir, TARGETS)
  if os.path.exists(path) and os.path.exists(os.path.join(run_dir, feature_kind.CONTENT_STATS)):
    return
  views = scene.images[scene.split("train")]
  targets = view_targets(vgg.load_vgg_params(), views, config.stylize_scale, progress)
  write_npy(os.path.join(run_dir, feature_kind.CONTENT_STATS), np.stack(pooled_stats(targets)))
  write_npy(path, targets)


STATS_VIEWS = 16  # training views (evenly spaced) the rendered statistics are pooled over.


def rendered_stats(params, config: FeatureConfig, scene: Scene, progress: bool = False
                   ) -> Tuple[np.ndarray, np.ndarray]:
  """(mean [512], std [512]) of the field's rendered relu4_1 cells (views.render_feature_map)
  over up to STATS_VIEWS evenly spaced training views: the statistics stylizing normalises
  by (feature_kind.content_stats)."""
  from msnerf_jax.kinds import views  # pylint: disable=g-import-not-at-top
  train = scene.split("train")
  pick = train[np.linspace(0, len(train) - 1, min(len(train), STATS_VIEWS)).round().astype(int)]
  return pooled_stats([views.render_feature_map(scene, params, config, int(i))["features"]
                       for i in progress_bar(pick, desc="rendered statistics",
                                             disable=not progress, leave=False)])


def write_rendered_stats(run_dir: str, scene: Scene, progress: bool = False) -> str:
  """Writes feature_kind.RENDERED_STATS of the run's latest step unless it is there; returns it."""
  run = runs_lib.load_run(run_dir, feature_kind.KIND.name)
  path = os.path.join(run_dir, feature_kind.RENDERED_STATS.format(step=run.step))
  if not os.path.exists(path):
    write_npy(path, np.stack(rendered_stats(run.params, run.config, scene, progress)))
  return path


def load_targets(run_dir: str, n_views: int, shape: Tuple[int, int]) -> np.ndarray:
  """The target cache [N, h, w, 512] float16 (prepare_targets), checked."""
  return read_npy(os.path.join(run_dir, TARGETS),
                  (n_views, *shape, vgg.LAYER_CHANNELS["relu4_1"])).astype(np.float16)


