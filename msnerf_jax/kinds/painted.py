"""The "painted" run kind: colour fields per style painted on a NeRF run's frozen geometry
(`msnerf paint train`); it renders its painted styles, their blends (a mix of colours) and
their strength over the photo-real scene (a blend with "original", the NeRF's own colours)."""

import os
from typing import Dict, Optional

import numpy as np

from msnerf_jax.core.config import PaintConfig
from msnerf_jax.core.errors import UserError
from msnerf_jax.core.files import write_npy
from msnerf_jax.data.images import read_npy
from msnerf_jax.data.stylized import ORIGINAL
from msnerf_jax.kinds import views
from msnerf_jax.kinds.base import RunKind, check_param_shapes
from msnerf_jax.models.nerf import NerfField, init_nerf_params
from msnerf_jax.models.painted_field import PaintedField
from msnerf_jax.nerf import render as render_lib

NAME = "painted"
STYLE_IMAGES = "style_images.npy"  # the painted styles' pictures, [M, S, S, 3] float32.


def painted_field(config: PaintConfig) -> PaintedField:
  """The colour fields of a PaintConfig (scene_box resolved)."""
  return PaintedField(config.scene_box)


def save_style_images(run_dir: str, images: np.ndarray) -> None:
  write_npy(os.path.join(run_dir, STYLE_IMAGES), np.asarray(images, np.float32))


def style_images(run) -> np.ndarray:
  """[M, S, S, 3] the pictures a painted run's styles were painted from."""
  s = run.config.style_size
  return read_npy(os.path.join(run.run_dir, STYLE_IMAGES), (len(run.record["styles"]), s, s, 3))


def check_params(params, config: PaintConfig, record, where: str) -> None:
  """UserError naming `where` unless a painted run's params are {"nerf": its NeRF config's
  params, "paint": {"colours" [M, V + 1, 3] for run.json's M styles, "index" [R, R, R]
  int32 with rows up to V}}."""
  import jax  # pylint: disable=g-import-not-at-top
  if not isinstance(params, dict) or set(params) != {"nerf", "paint"} or set(
      params["paint"]) != {"colours", "index"}:
    raise UserError(f"{where}: not the params of a painted run")
  check_param_shapes(params["nerf"], jax.eval_shape(
      lambda: init_nerf_params(config.nerf, jax.random.PRNGKey(0))), where)
  colours, index = params["paint"]["colours"], params["paint"]["index"]
  r, m = config.resolution, len(record.get("styles", []))
  if np.shape(index) != (r, r, r) or np.shape(colours)[2:] != (3,) or np.ndim(colours) != 3:
    raise UserError(f"{where}: paint index {np.shape(index)} and colours "
                    f"{np.shape(colours)}, its config expects ({r}, {r}, {r}) and (M, V + 1, 3)")
  if np.shape(colours)[0] < m or int(np.max(index)) >= np.shape(colours)[1]:
    raise UserError(f"{where}: colours for {np.shape(colours)[0]} styles and "
                    f"{np.shape(colours)[1]} rows; run.json names {m} styles and the index "
                    f"reaches row {int(np.max(index))}")


def render_painted(scene, params, config: PaintConfig, camera, chunk: Optional[int] = None
                   ) -> Dict[str, np.ndarray]:
  """One camera (as views.render_view's) of a painted run in all its M styles: the colour
  fields composited with the frozen NeRF's weights (render.render_feature_image), over
  white on white-background scenes.

  Returns: {"rgb": [M, H, W, 3], "accumulation": [H, W]}.
  """
  field = painted_field(config)
  out = render_lib.render_feature_image(
      NerfField(config.nerf), field, {"nerf": params["nerf"], "features": params["paint"]},
      scene.camera_rays(camera), config.nerf, config.top_k, chunk)
  acc = out["accumulation"]
  rgb = out["features"].reshape(*acc.shape, -1, 3)
  if scene.white_background:
    rgb = rgb + (1.0 - acc)[..., None, None]
  return {"rgb": np.moveaxis(rgb, -2, 0), "accumulation": acc}


def style_table(run, scene):
  """{name: blend weights [M + 1]}: each painted style one-hot, and "original" (the NeRF's
  own colours, the last entry): blends and strengths are mixes of colours."""
  del scene
  names = list(run.record["styles"]) + [ORIGINAL]
  return dict(zip(names, np.eye(len(names), dtype=np.float32))), None


def style_renderer(run, scene, chunk=None, grids=None, decoder=None):
  """Renders one camera of a loaded painted run in K blends [K, M + 1] of its styles (and of
  the NeRF's own colours): one render of the M colour fields, mixed."""
  del grids, decoder
  m = len(run.record["styles"])

  def render(camera, styles):
    weights = np.stack(styles).astype(np.float32)
    if weights.ndim != 2 or weights.shape[1] != m + 1:
      raise UserError(f"{run.run_dir}: a painted run renders its painted styles "
                      f"({', '.join(run.record['styles'])}) and blends of them; add a new "
                      "style with `msnerf paint add`")
    rgb = render_painted(scene, run.params, run.config, camera, chunk)["rgb"]
    mixed = np.einsum("km,mhwc->khwc", weights[:, :m], rgb)
    if np.any(weights[:, m] != 0):
      photo = views.render_view(scene, run.params["nerf"], run.config.nerf, camera, chunk)["rgb"]
      mixed = mixed + weights[:, m, None, None, None] * photo
    return mixed.astype(np.float32)
  return render


KIND = RunKind(
    name=NAME,
    config_class=PaintConfig,
    train_command="msnerf paint train",
    title="painted",
    params_layout=('{"nerf": the NeRF run\'s params (frozen, bit-identical), "paint": '
                   '{"grids": [M, R, R, R, 3] colour logits, one grid per style}}'),
    nerf_config=lambda config: config.nerf,
    style_table=style_table,
    style_renderer=style_renderer,
    check_params=check_params,
)
