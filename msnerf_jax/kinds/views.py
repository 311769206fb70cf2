"""Whole camera views of a trained run's scene: a NeRF's view, and a multi-style model's view
in K styles at once, each rendered in chunks by the one renderer (msnerf_jax.nerf.render)."""

from typing import Dict, List, Optional, Tuple

import jax.numpy as jnp
import numpy as np
from jax.sharding import Mesh

from msnerf_jax.nerf import render as render_lib
from msnerf_jax.core.config import FeatureConfig, MultistyleConfig, NerfConfig
from msnerf_jax.data.scene import Scene
from msnerf_jax.style.features import DEFAULT_GRIDS, cell_grid, decode_styles, grid_offsets
from msnerf_jax.models.feature_field import FeatureFieldFn
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


def render_feature_map(scene: Scene, params, config: FeatureConfig, camera, per_side: int = 2,
                       chunk: Optional[int] = None, offset: Tuple[int, int] = (0, 0),
                       pad: int = 0) -> Dict[str, np.ndarray]:
  """One camera (as render_view's) of a feature field, at its relu4_1 cells: the view
  enlarged config.stylize_scale times has one cell per 8 x 8 pixels, and each cell's
  feature is the mean of per_side x per_side rays inside it (feature_style.cell_grid, with
  its grid `offset` and `pad`), lifted to the encoder's channels after averaging (the lift
  is affine).

  Returns: {"features": [h, w, 512] (what the AdaIN decoder reads; the background feature
  fills 1 - accumulation), "accumulation": [h, w] the scene's opacity in each cell}.
  """
  height, width = scene.camera_parts(camera)[3:]
  rows, cols = cell_grid(height, width, config.stylize_scale, per_side, offset, pad)
  fn = FeatureFieldFn(config)
  out = render_lib.render_feature_image(NerfField(config.nerf), fn, params,
                                        scene.rays_at(camera, rows, cols), config.nerf,
                                        config.top_k, chunk)
  acc = out["accumulation"].mean(-1)
  lifted = fn.lift(params["features"], jnp.asarray(out["features"].mean(-2)), jnp.asarray(acc))
  return {"features": np.asarray(lifted), "accumulation": acc}


def feature_maps(scene: Scene, params, config: FeatureConfig, camera, grids: int = DEFAULT_GRIDS,
                 chunk: Optional[int] = None) -> List[Tuple[Tuple[int, int], Dict[str, np.ndarray]]]:
  """The feature maps (render_feature_map's) of one camera on each of `grids` cell grids
  (feature_style.GRID_OFFSETS), all of one shape: [(offset, map)]."""
  offsets = grid_offsets(grids)
  pad = max(max(o) for o in offsets)
  return [(o, render_feature_map(scene, params, config, camera, chunk=chunk, offset=o, pad=pad))
          for o in offsets]


def paint_feature_maps(maps, decoder, content_stats, styles: np.ndarray, height: int,
                       width: int, scale: int) -> np.ndarray:
  """Feature maps of one camera (feature_maps') in K styles: each map's AdaIN and decode,
  moved back by its grid offset, averaged over the maps. styles: [K, 1024] style vectors.

  Returns: [K, height, width, 3] float32 in [0, 1].
  """
  styles = np.atleast_2d(np.asarray(styles, np.float32))
  half = styles.shape[1] // 2
  # The background feature fills 1 - accumulation: every cell is whole.
  return np.mean([decode_styles(decoder, fmap["features"], np.ones_like(fmap["accumulation"]),
                                content_stats, styles[:, :half], styles[:, half:], 1.0,
                                height, width, scale, offset) for offset, fmap in maps], 0)


def render_feature_styles(scene: Scene, params, config: FeatureConfig, camera, decoder,
                          content_stats, styles: np.ndarray, chunk: Optional[int] = None,
                          grids: int = DEFAULT_GRIDS) -> np.ndarray:
  """One camera of a feature field in K styles: one feature render, K AdaIN maps and
  decodes. styles: [K, 1024] style vectors (relu4_1 means, then stds: adain.style_vector;
  blends and strengths are blends of them, e.g. with the scene's own statistics for alpha).
  decoder: stylize.Decoder; content_stats: (mean, std) [512] of the scene. grids: with 2 or
  4, the feature render and the decodes are repeated on the cell grid moved by half a cell
  (feature_style.GRID_OFFSETS) and averaged: the strokes the decoder pins to the grid
  average out, and the frames change less from view to view.

  Returns: [K, H, W, 3] float32 in [0, 1], the camera's size.
  """
  height, width = scene.camera_parts(camera)[3:]
  return paint_feature_maps(feature_maps(scene, params, config, camera, grids, chunk), decoder,
                            content_stats, styles, height, width, config.stylize_scale)
