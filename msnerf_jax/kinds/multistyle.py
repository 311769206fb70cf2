"""The "multistyle" run kind: the paper's style heads around a NeRF run's frozen trunk
(`msnerf multistyle train`); it renders its training styles, their blends and any picture's
style vector."""

import os
from typing import Dict

import numpy as np

from msnerf_jax.core.config import MultistyleConfig
from msnerf_jax.core.files import write_npy
from msnerf_jax.data.images import read_npy
from msnerf_jax.kinds import views
from msnerf_jax.kinds.base import RunKind
from msnerf_jax.models.multistyle import MultistyleField, init_multistyle_params

STYLE_VECTORS = "style_vectors.npy"  # a multi-style run's training styles, [M, 1024].


def save_style_vectors(run_dir: str, vectors: np.ndarray) -> None:
  write_npy(os.path.join(run_dir, STYLE_VECTORS), np.asarray(vectors, np.float32))


def style_vectors(run) -> Dict[str, np.ndarray]:
  """name -> [1024] vector of every training style of a multi-style run."""
  names = run.record.get("styles", [])
  vectors = read_npy(os.path.join(run.run_dir, STYLE_VECTORS), (len(names), run.config.style_dim))
  return dict(zip(names, vectors))


def style_renderer(run, scene, chunk=None, grids=None, decoder=None):
  """Renders one camera of a loaded multi-style run in K styles at once (one trunk pass)."""
  del grids, decoder  # the heads paint no cell grid.
  return lambda camera, styles: views.render_styles(scene, run.params, run.config, camera,
                                                    np.stack(styles), chunk)["rgb"]


KIND = RunKind(
    name="multistyle",
    config_class=MultistyleConfig,
    train_command="msnerf multistyle train",
    title="multi-style",
    params_layout=('{"coarse", "fine"} (the NeRF run\'s levels; {"fine", "occupancy"} with the '
                   'grid sampler), each {"trunk": the NeRF run\'s trunk, frozen, "style_rgb", '
                   '"rgb_hidden", "rgb_out"[, "style_density", "density_hidden", '
                   '"density_out" (density-aware)][, "rgb_extra_i", "density_extra_i"]}'),
    init_params=init_multistyle_params,
    nerf_config=lambda config: config.nerf,
    field=MultistyleField,
    style_table=lambda run, scene: (style_vectors(run), None),
    style_renderer=style_renderer,
)
