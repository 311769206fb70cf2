"""The VGG feature field: the scene's AdaIN content features (the encoder's relu4_1) as a field
on a NeRF's frozen geometry, so a style becomes one affine map of that field for every view.

Two modules (docs: FEATURE_FIELD.md, "deferred style transformation"):
- `FeatureField`: points -> a low-dimensional feature [..., D], from a multiresolution hash
  grid of its own (`tables`) and a small MLP: spatial capacity the frozen trunk's hidden
  features lack. Volume-rendered with the NeRF's weights (render.render_feature_rays).
- `FeatureLift`: the composited feature [..., D] and the accumulated opacity A -> the
  encoder's [..., 512]: `f @ kernel + bias * A + background * (1 - A)`. The bias scaled by A
  is what each sample's lift would contribute (no halo at silhouettes), and `background` is
  the feature of what shows through where the scene is transparent (white, on Blender). The
  map is affine in (f, A), so lifting the composite equals compositing the lifted samples,
  and averaging rays (a relu4_1 cell) commutes with it.
"""

import dataclasses
from typing import Any, Dict

import chex
import flax.linen as nn
import jax
import jax.numpy as jnp

from msnerf_jax.models.hash_trunk import encode_in_box

CHANNELS = 512  # relu4_1 of the VGG encoder the AdaIN decoder reads.


class FeatureField(nn.Module):
  """Points [..., 3] -> features [..., dim]: hash encoding (own `tables` [L, T, F]) over the
  scene box [-bound, bound]^3, then `hidden` (width, ReLU) and `out` (dim, linear)."""
  dim: int = 32
  width: int = 64
  bound: float = 1.5
  levels: int = 16
  features: int = 2
  table_size: int = 2 ** 16
  min_res: int = 16
  max_res: int = 256

  @nn.compact
  def __call__(self, points: jnp.ndarray) -> jnp.ndarray:
    x = encode_in_box(self, points)
    if self.width:
      x = nn.gelu(nn.Dense(self.width, name="hidden")(x))
    return nn.Dense(self.dim, name="out")(x)


class FeatureLift(nn.Module):
  """(features [..., dim], accumulation [...]) -> [..., channels]: `f @ kernel + bias * A +
  background * (1 - A)` (params `kernel` [dim, channels], `bias`, `background` [channels])."""
  channels: int = CHANNELS

  @nn.compact
  def __call__(self, features: jnp.ndarray, accumulation: jnp.ndarray) -> jnp.ndarray:
    chex.assert_equal_shape_prefix([features, accumulation], accumulation.ndim)
    kernel = self.param("kernel", nn.initializers.lecun_normal(),
                        (features.shape[-1], self.channels))
    bias = self.param("bias", nn.initializers.zeros_init(), (self.channels,))
    background = self.param("background", nn.initializers.zeros_init(), (self.channels,))
    a = accumulation[..., None]
    return features @ kernel + bias * a + background * (1.0 - a)


def feature_field(config, bound: float) -> FeatureField:
  """The FeatureField of a FeatureConfig, over the box [-bound, bound]^3."""
  return FeatureField(dim=config.dim, width=config.width, bound=bound,
                      levels=config.hash_levels, features=config.hash_features,
                      table_size=config.hash_table_size, min_res=config.hash_min_res,
                      max_res=config.hash_max_res)


def init_feature_params(config, bound: float, key: jax.Array) -> Dict[str, Dict]:
  """{"field": FeatureField params, "lift": FeatureLift params} of a FeatureConfig."""
  k_field, k_lift = jax.random.split(key)
  field = feature_field(config, bound).init(k_field, jnp.zeros((1, 3)))["params"]
  lift = FeatureLift().init(k_lift, jnp.zeros((1, config.dim)), jnp.zeros((1,)))["params"]
  return {"field": dict(field), "lift": dict(lift)}


@dataclasses.dataclass(frozen=True)
class FeatureFieldFn:
  """The feature field of a FeatureConfig (scene_box resolved) as a hashable value (a static
  jit argument): `fn(params, points [..., 3]) -> [..., dim]` reads params["field"], `lift`
  params["lift"]."""
  config: Any  # FeatureConfig

  def __call__(self, params, points: jnp.ndarray) -> jnp.ndarray:
    field = feature_field(self.config, self.config.scene_box)
    return field.apply({"params": params["field"]}, points)

  def lift(self, params, features: jnp.ndarray, accumulation: jnp.ndarray) -> jnp.ndarray:
    """features [..., dim], accumulation [...] -> [..., 512] (FeatureLift)."""
    return FeatureLift().apply({"params": params["lift"]}, features, accumulation)
