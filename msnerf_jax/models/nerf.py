"""The NeRF MLP: a `trunk` (points -> density and view features) and an `rgb` layer; and
`NerfField`, the MLP as the field the renderer (msnerf_jax.nerf.render) draws."""

import dataclasses
from typing import Any, Dict, Optional, Tuple, Union

import flax.linen as nn
import jax
import jax.numpy as jnp

from msnerf_jax.nerf import occupancy
from msnerf_jax.nerf.samplers import sampler_of
from msnerf_jax.nerf.encoding import encoded_size, positional_encoding
from msnerf_jax.models.hash_trunk import HashTrunk, hash_trunk
from msnerf_jax.models.layers import ConcatInputDense


class NerfTrunk(nn.Module):
  """Everything of the NeRF MLP but the final colour layer; frozen by the multi-style model.

  Point layers (`point_0` ... with the encoded input re-concatenated after `skip_layer`),
  the density head `density` (W -> 1), the feature layer `feature` (W -> W) and the view
  layer `view` ((W + encoded dirs) -> W/2, ReLU), as in the reference code.
  """
  depth: int = 8
  width: int = 256
  skip_layer: int = 4
  pos_freqs: int = 10
  dir_freqs: int = 4

  @property
  def hidden_width(self) -> int:
    """Width of `hidden`, what a density-aware head reads (the encoded input is part of it
    when the skip connection is the last layer's)."""
    return self.width + (encoded_size(3, self.pos_freqs) if self.skip_layer == self.depth - 1
                         else 0)

  @nn.compact
  def __call__(self, points: jnp.ndarray, viewdirs: jnp.ndarray,
               feature: Optional[jnp.ndarray] = None) -> Dict[str, jnp.ndarray]:
    """Args: points [..., 3]; viewdirs [..., 3] (unit), or [..., 1, 3] (one per ray,
    encoded once and broadcast over the samples). With `feature` [..., W] (a `feature`
    output, e.g. a baked scene's) the points are not read: only the view layer runs.

    Returns: dict of raw density `sigma` [...] (before activation), `hidden` [..., W]
    (last point layer), `feature` [..., W] (what the view layer reads) and `view_features`
    [..., W/2]; with a `feature` given, `view_features` alone.
    """
    out = {}
    if feature is None:
      x = positional_encoding(points, self.pos_freqs)
      parts = [x]  # the layer input, as the parts of its concatenation.
      for i in range(self.depth):
        h = nn.relu(ConcatInputDense(self.width, name=f"point_{i}")(parts))
        parts = [x, h] if i == self.skip_layer else [h]
      sigma = ConcatInputDense(1, name="density")(parts)[..., 0]
      feature = ConcatInputDense(self.width, name="feature")(parts)
      hidden = parts[0] if len(parts) == 1 else jnp.concatenate(parts, -1)
      out = {"sigma": sigma, "hidden": hidden, "feature": feature}
    d = positional_encoding(viewdirs, self.dir_freqs)
    d = jnp.broadcast_to(d, (*feature.shape[:-1], d.shape[-1]))
    view = nn.relu(ConcatInputDense(self.width // 2, name="view")([feature, d]))
    return {**out, "view_features": view}


class NerfMLP(nn.Module):
  """Trunk + the final colour layer `rgb` (W/2 -> 3, sigmoid).

  Params: {"trunk": {...}, "rgb": {...}} (the submodule takes its attribute's name).
  """
  trunk: Union[NerfTrunk, HashTrunk]

  @nn.compact
  def __call__(self, points: jnp.ndarray, viewdirs: jnp.ndarray,
               feature: Optional[jnp.ndarray] = None) -> Tuple[jnp.ndarray, jnp.ndarray]:
    """Args: points [..., 3], viewdirs [..., 3]; or a trunk `feature` [..., W] instead of
    the points (the trunk's). Returns rgb [..., 3] in [0, 1], raw sigma [...] (None with a
    `feature`)."""
    out = self.trunk(points, viewdirs, feature)
    rgb = nn.sigmoid(ConcatInputDense(3, name="rgb")([out["view_features"]]))
    return rgb, out.get("sigma")


def nerf_trunk(config) -> Union[NerfTrunk, HashTrunk]:
  """The trunk of a NerfConfig (what a multi-style model freezes): the MLP, or the hash grid
  with trunk = "hash"."""
  if config.trunk == "hash":
    return hash_trunk(config)
  return NerfTrunk(config.net_depth, config.net_width, config.skip_layer, config.pos_freqs,
                   config.dir_freqs)


def nerf_mlp(config) -> NerfMLP:
  """The MLP of a NerfConfig."""
  return NerfMLP(trunk=nerf_trunk(config))


@dataclasses.dataclass(frozen=True)
class NerfField:
  """The radiance field of a NerfConfig as a hashable callable (a static jit argument)."""
  config: Any  # NerfConfig

  def __call__(self, params, points, viewdirs):
    return nerf_mlp(self.config).apply({"params": params}, points, viewdirs)

  def geometry(self, params, points):
    """Density (activated, >= 0) [...] and trunk `feature` [..., W] at points [..., 3]: what
    a baked scene stores (msnerf_jax.nerf.baked)."""
    out = nerf_trunk(self.config).apply({"params": params["trunk"]}, points, points)
    return jax.nn.relu(out["sigma"]), out["feature"]

  def shade(self, params, feature, viewdirs, conditioning=None):
    """rgb [..., 3] of trunk features [..., W] seen along viewdirs [..., 3] (the view layers and
    the rgb layer: the field's colour where its trunk gave `feature`)."""
    del conditioning  # a NeRF has one colour.
    return nerf_mlp(self.config).apply({"params": params}, None, viewdirs, feature)[0]


def init_nerf_params(config, key: jax.Array) -> Dict[str, Dict]:
  """Fresh params of a run: {"coarse": {"trunk", "rgb"}, "fine": {"trunk", "rgb"}}; with the
  occupancy-grid sampler {"fine": {"trunk", "rgb"}, "occupancy": [G, G, G]} (every cell
  unknown, see msnerf_jax.nerf.occupancy)."""
  model = nerf_mlp(config)
  k_coarse, k_fine = jax.random.split(key)
  x = jnp.zeros((1, 3), jnp.float32)
  fine = model.init(k_fine, x, x)["params"]
  if sampler_of(config).occupancy:
    return {"fine": fine, "occupancy": occupancy.init_grid(config.grid_resolution)}
  return {"coarse": model.init(k_coarse, x, x)["params"], "fine": fine}


def mlp_flops_per_sample(config) -> int:
  """Multiply-adds x 2 of one forward pass of the MLP at one sample (matmuls only)."""
  in_pts = 3 * (1 + 2 * config.pos_freqs)
  in_dir = 3 * (1 + 2 * config.dir_freqs)
  w = config.net_width
  macs = 0
  fan_in = in_pts
  for i in range(config.net_depth):
    macs += fan_in * w
    fan_in = w + (in_pts if i == config.skip_layer else 0)
  macs += fan_in * 1 + fan_in * w + (w + in_dir) * (w // 2) + (w // 2) * 3
  return 2 * macs
