"""Whole camera views of a trained run's scene: a NeRF's view, and a multi-style model's view
in K styles at once, each rendered in chunks by the one renderer (msnerf_jax.render)."""

from typing import Dict, Optional

import jax.numpy as jnp
import numpy as np
from jax.sharding import Mesh

from msnerf_jax import render as render_lib
from msnerf_jax.config import MultistyleConfig, NerfConfig
from msnerf_jax.data.scene import Scene
from msnerf_jax.models.multistyle import MultistyleField
from msnerf_jax.models.nerf import NerfField


def render_view(scene: Scene, params, config: NerfConfig, camera,
                chunk: Optional[int] = None, mesh: Optional[Mesh] = None
                ) -> Dict[str, np.ndarray]:
  """Renders one camera of the scene: rgb [H, W, 3], depth, disparity, accumulation [H, W].

  camera: a dataset view's index (its own intrinsics and lens), a c2w [3, 4] seen with the
  scene's render camera, or a cameras.Camera (a camera path file's): Scene.camera_rays.
  mesh: the devices the rays are split over (render.render_image; default: this process's).
  """
  return render_lib.render_image(NerfField(config), params, scene.camera_rays(camera), config,
                                 scene.white_background, chunk, mesh=mesh)


def render_styles(scene: Scene, params, config: MultistyleConfig, camera,
                  styles: np.ndarray, chunk: Optional[int] = None,
                  mesh: Optional[Mesh] = None) -> Dict[str, np.ndarray]:
  """One camera (as render_view's) in K styles at once (a style sweep): rgb [K, H, W, 3],
  depth [K, H, W] ..."""
  styles = jnp.asarray(np.atleast_2d(styles), jnp.float32)
  return render_lib.render_image(MultistyleField(config), params, scene.camera_rays(camera),
                                 config.nerf, scene.white_background, chunk, styles=styles,
                                 mesh=mesh)
