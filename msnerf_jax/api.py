"""The public surface: what a JAX user needs, importable as `import msnerf_jax as ms`.

Loading a run and its scene (`load_run`, `scene_of`), its field and sampling config
(`field_of`), rendering rays and images of any run kind in any style vectors
(`render_rays`, `render_image`, `render_run_rays`), style vectors and blends
(`style_vectors` of a multi-style run, `style_vector_of` any picture, `blend`), painted colour
fields (`paint` paints styles on a NeRF run, `view_samples` caches a view's samples, `cached_render` renders a colour field from
them, `deferred_grad`, the style losses `painting_losses`), the configs, and the primitives
(rays, sampling, volume rendering); a baked scene (`bake`, `render_baked_image`: density and
trunk features on bricks in the occupied cells, rendered without the trunk). Everything here is a pure function of its arguments or a frozen dataclass;
`render_rays` jits and vmaps (over style vectors, for one).
"""

from typing import Any, Dict, Optional, Tuple

import jax.numpy as jnp

from msnerf_jax.core.config import (AdainConfig, DataConfig, FeatureConfig, MultistyleConfig,
                                    NerfConfig, OptimConfig, PaintConfig, nerf_preset, override)
from msnerf_jax.core.errors import UserError
from msnerf_jax.data.scene import Scene, load_scene
from msnerf_jax.kinds.base import RunKind
from msnerf_jax.kinds.multistyle import style_vectors
from msnerf_jax.kinds.registry import KINDS, get_kind
from msnerf_jax.kinds.runs import Run, load_run
from msnerf_jax.kinds.runs import scene_of as _scene_and_data
from msnerf_jax.models.feature_field import FeatureFieldFn
from msnerf_jax.models.multistyle import MultistyleField
from msnerf_jax.models.nerf import NerfField
from msnerf_jax.models.painted_field import PaintedField
from msnerf_jax.kinds.painted import render_painted
from msnerf_jax.nerf.baked import (BakedScene, bake, heavy_samples, render_baked_image,
                                   shade_samples)
from msnerf_jax.nerf.sample_cache import cached_render, deferred_grad, pack_views, view_samples
from msnerf_jax.style.painting_loss import nnfm, painting_losses, style_target
from msnerf_jax.train.paint import train as paint
from msnerf_jax.nerf.rays import get_rays, ray_bundle
from msnerf_jax.nerf.render import (draw_randomness, flat_rays, render_feature_rays,
                                    render_image, render_rays)
from msnerf_jax.nerf.sampling import sample_pdf, stratified_samples
from msnerf_jax.nerf.samplers import SAMPLERS, sampler_of
from msnerf_jax.nerf.volume_rendering import volume_render
from msnerf_jax.style.adain import adain, style_vector
from msnerf_jax.style.vectors import blend, style_vector_of


def scene_of(run: Run) -> Scene:
  """The scene a loaded run was trained on, reloaded as it was (its cameras, normalised
  world and images)."""
  return _scene_and_data(run)[0]


def field_of(run: Run) -> Tuple[Any, NerfConfig]:
  """(field, NerfConfig) a loaded run renders with through `render_rays` (for a
  multi-style run, a style field: pass style vectors [M, 1024] as `conditioning`).
  UserError for a kind the one renderer does not draw (an AdaIN decoder; a feature field,
  whose features `render_feature_rays` composites)."""
  kind = get_kind(run.kind)
  if kind.field is None:
    raise UserError(f"{run.run_dir}: a {run.kind!r} run has no field for render_rays")
  return kind.field(run.config), kind.nerf_config(run.config)


def render_run_rays(run: Run, rays: Dict[str, jnp.ndarray],
                    styles: Optional[jnp.ndarray] = None) -> Dict[str, Dict[str, jnp.ndarray]]:
  """`render_rays` of a loaded run on rays [R] (deterministic): {level: {"rgb": [R, 3] or
  [M, R, 3] with styles [M, 1024], "depth", "accumulation", ...}}."""
  field, config = field_of(run)
  return render_rays(field, run.params, rays, config, white_background=False,
                     conditioning=None if styles is None else jnp.asarray(styles, jnp.float32))


__all__ = [
    # runs and scenes
    "load_run", "Run", "scene_of", "load_scene", "Scene", "KINDS", "get_kind", "RunKind",
    # fields and rendering
    "field_of", "render_run_rays", "render_rays", "render_image", "render_feature_rays",
    "draw_randomness", "flat_rays", "NerfField", "MultistyleField", "FeatureFieldFn",
    "SAMPLERS", "sampler_of",
    # a baked scene: density and trunk features on bricks, for fast looking
    "bake", "BakedScene", "render_baked_image", "heavy_samples", "shade_samples",
    # painted colour fields: cached sample lists, their render, the style losses
    "paint", "PaintedField", "render_painted", "view_samples", "pack_views", "cached_render",
    "deferred_grad", "painting_losses", "nnfm", "style_target",
    # styles
    "style_vectors", "style_vector_of", "style_vector", "blend", "adain",
    # configs
    "NerfConfig", "MultistyleConfig", "FeatureConfig", "PaintConfig", "AdainConfig", "DataConfig",
    "OptimConfig", "nerf_preset", "override",
    # primitives
    "get_rays", "ray_bundle", "stratified_samples", "sample_pdf", "volume_render",
    "UserError",
]
