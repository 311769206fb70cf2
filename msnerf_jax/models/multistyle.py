"""The multi-style NeRF MLP: a frozen NeRF `trunk` with style-conditioned colour (and density) heads.

docs/method.md "Multi-style heads": a style MLP (1024 -> 1024 -> 512 -> W/2) maps the style
vector to a code that is concatenated with the trunk's view features and fed to a new rgb MLP
(W -> W/2 -> 3). The density-aware variant adds a style-to-density MLP (-> W) whose output,
concatenated with the trunk's last point layer, feeds a new density MLP (2W -> W -> 1).

The style vector is constant over a ray, so everything that depends only on the style runs
once per style (`codes`), including the style half of each head's first layer: a Dense over
`concat([x, code])` is `x @ K_x + (code @ K_code + b)`, and the bracket is per style.

`MultistyleField` is the model as the conditioned field the renderer (msnerf_jax.nerf.render) draws.
"""

import dataclasses
from typing import Any, Dict, Optional, Sequence, Union

import chex
import flax.linen as nn
import jax
import jax.numpy as jnp

from msnerf_jax.nerf import occupancy
from msnerf_jax.nerf.samplers import sampler_of
from msnerf_jax.models.hash_trunk import HashTrunk
from msnerf_jax.models.nerf import NerfField, NerfTrunk, nerf_trunk


class StyleMLP(nn.Module):
  """Dense layers with ReLU between them (none after the last): [..., in] -> [..., features[-1]].

  With `normalize`, the input is first standardised over its features (a LayerNorm without
  parameters). Style vectors are VGG statistics with entries up to ~10 and norms ~100; fed
  raw, Adam's first steps on the 1024-wide layer move every output by several units (all M
  inputs push the same way) and kill the colour head's ReLUs.
  """
  features: Sequence[int]
  normalize: bool = True

  @nn.compact
  def __call__(self, x: jnp.ndarray) -> jnp.ndarray:
    if self.normalize:
      x = nn.LayerNorm(use_scale=False, use_bias=False, name="norm")(x)
    for i, width in enumerate(self.features):
      x = nn.Dense(width, name=f"dense_{i}")(x)
      if i < len(self.features) - 1:
        x = nn.relu(x)
    return x


class ConcatDense(nn.Module):
  """Dense layer over concat([x, code]) with the code's half applied separately.

  Params `kernel` [x_dim + code_dim, features] and `bias` are those of one Dense on the
  concatenation; `project_code` is its per-style part, `__call__` adds the per-sample part.
  """
  features: int
  x_dim: int
  code_dim: int

  def setup(self):
    self.kernel = self.param("kernel", nn.initializers.lecun_normal(),
                             (self.x_dim + self.code_dim, self.features))
    self.bias = self.param("bias", nn.initializers.zeros_init(), (self.features,))

  def project_code(self, code: jnp.ndarray) -> jnp.ndarray:
    """code [M, code_dim] -> [M, features] (bias included)."""
    return code @ self.kernel[self.x_dim:] + self.bias

  def __call__(self, x: jnp.ndarray, projected: jnp.ndarray) -> jnp.ndarray:
    """x [..., x_dim] + projected code (broadcastable to [..., features]) -> [..., features]."""
    return x @ self.kernel[:self.x_dim] + projected


class MultiStyleMLP(nn.Module):
  """Frozen `trunk` + `style_rgb`, `rgb_hidden`, `rgb_out` (+ `style_density`, `density_hidden`,
  `density_out` when density-aware), and optional extra layers `rgb_extra_i` / `density_extra_i`.

  Params: {"trunk": <the NeRF's trunk>, "style_rgb": ..., "rgb_hidden": ..., "rgb_out": ...}.
  """
  trunk: Union[NerfTrunk, HashTrunk]
  density_aware: bool = False
  style_dim: int = 1024
  style_hidden: Sequence[int] = (1024, 512)
  rgb_extra_layers: int = 0
  density_extra_layers: int = 0
  normalize_styles: bool = True

  def setup(self):
    w = self.trunk.width
    self.style_rgb = StyleMLP((*self.style_hidden, w // 2), self.normalize_styles)
    self.rgb_hidden = ConcatDense(w // 2, w // 2, w // 2)
    self.rgb_extra = [nn.Dense(w // 2, name=f"rgb_extra_{i}") for i in range(self.rgb_extra_layers)]
    self.rgb_out = nn.Dense(3)
    if self.density_aware:
      hidden_dim = self.trunk.hidden_width
      self.style_density = StyleMLP((*self.style_hidden, w), self.normalize_styles)
      self.density_hidden = ConcatDense(w, hidden_dim, w)
      self.density_extra = [nn.Dense(w, name=f"density_extra_{i}")
                            for i in range(self.density_extra_layers)]
      self.density_out = nn.Dense(1)

  def codes(self, styles: jnp.ndarray) -> Dict[str, jnp.ndarray]:
    """Everything that depends only on the style, once per style.

    Args: styles [M, style_dim]. Returns {"rgb": [M, W/2]} (+ {"density": [M, W]}).
    """
    chex.assert_shape(styles, (None, self.style_dim))
    out = {"rgb": self.rgb_hidden.project_code(self.style_rgb(styles))}
    if self.density_aware:
      out["density"] = self.density_hidden.project_code(self.style_density(styles))
    return out

  def __call__(self, points: jnp.ndarray, viewdirs: jnp.ndarray,
               codes: Dict[str, jnp.ndarray]):
    """Colour (and density) of every sample in every style.

    Args:
      points: [R, S, 3] shared by all styles, or [M, R, S, 3] one set per style.
      viewdirs: [R, 1, 3] (or broadcastable to the points).
      codes: from `codes`, leading dimension M.
    Returns:
      rgb [M, R, S, 3] in [0, 1]; raw sigma [R, S] (frozen trunk density, or per-style
      points: [M, R, S]), or [M, R, S] when density-aware.
    """
    chex.assert_rank(points, {3, 4})
    per_style = lambda c: c[:, None, None, :]  # [M, C] -> [M, 1, 1, C]: broadcast over samples.
    out = self.trunk(points, viewdirs)
    rgb = self._colour(out["view_features"], per_style(codes["rgb"]))
    sigma = out["sigma"]
    if self.density_aware:
      d = nn.relu(self.density_hidden(out["hidden"], per_style(codes["density"])))
      for layer in self.density_extra:
        d = nn.relu(layer(d))
      sigma = self.density_out(d)[..., 0]
    return rgb, sigma

  def _colour(self, view_features: jnp.ndarray, projected: jnp.ndarray) -> jnp.ndarray:
    """The colour head: view features [..., W/2] + a projected style code (broadcastable)
    -> rgb [..., 3] in [0, 1]."""
    h = nn.relu(self.rgb_hidden(view_features, projected))
    for layer in self.rgb_extra:
      h = nn.relu(layer(h))
    return nn.sigmoid(self.rgb_out(h))

  def shade(self, feature: jnp.ndarray, viewdirs: jnp.ndarray,
            codes: Dict[str, jnp.ndarray]) -> jnp.ndarray:
    """rgb [M, ..., 3] of the trunk's `feature` [..., W] (e.g. a baked scene's) seen along
    viewdirs [..., 3] (or broadcastable: [R, 1, 3] for [R, S, W] features) in the M styles
    of `codes` (the view layers, then the colour head)."""
    view = self.trunk(None, viewdirs, feature)["view_features"]
    code = codes["rgb"]
    return self._colour(view, code.reshape(code.shape[0], *([1] * (view.ndim - 1)), -1))


def multistyle_mlp(config) -> MultiStyleMLP:
  """The MLP of a MultistyleConfig (its trunk is the NeRF config's)."""
  return MultiStyleMLP(trunk=nerf_trunk(config.nerf), density_aware=config.density_aware,
                       style_dim=config.style_dim,
                       style_hidden=(config.style_hidden, config.style_hidden2),
                       rgb_extra_layers=config.rgb_extra_layers,
                       density_extra_layers=config.density_extra_layers,
                       normalize_styles=config.normalize_styles)


@dataclasses.dataclass(frozen=True)
class MultistyleField:
  """The style field of a MultistyleConfig as a hashable value (a static jit argument)."""
  config: Any  # MultistyleConfig

  def codes(self, params, styles):
    """Style MLP outputs, once per style: styles [M, 1024] -> {"rgb": [M, W/2], ...}."""
    model = multistyle_mlp(self.config)
    return model.apply({"params": params}, styles, method=model.codes)

  def __call__(self, params, points, viewdirs, codes):
    """points [R, S, 3] or [M, R, S, 3] -> rgb [M, R, S, 3], raw sigma (see MultiStyleMLP)."""
    return multistyle_mlp(self.config).apply({"params": params}, points, viewdirs, codes)

  def geometry(self, params, points):
    """Density [...] and trunk `feature` [..., W] at points (the frozen trunk's: NerfField's)."""
    return NerfField(self.config.nerf).geometry(params, points)

  def shade(self, params, feature, viewdirs, codes):
    """rgb [M, ..., 3] of trunk features [..., W] along viewdirs [..., 3] in the styles of `codes`
    (MultiStyleMLP.shade)."""
    model = multistyle_mlp(self.config)
    return model.apply({"params": params}, feature, viewdirs, codes, method=model.shade)


def init_multistyle_params(config, key: jax.Array,
                           nerf_params: Optional[Dict] = None) -> Dict[str, Dict]:
  """Params {"coarse", "fine"} of a multi-style model ({"fine", "occupancy"} on a NeRF with
  the grid sampler); with `nerf_params` (a NeRF run's params), each `trunk` is that run's
  trunk, copied leaf for leaf (and its occupancy grid), and a density-aware head starts out
  reproducing the trunk's density (see start_from_density)."""
  model = multistyle_mlp(config)
  x = jnp.zeros((1, 1, 3), jnp.float32)
  styles = jnp.zeros((1, config.style_dim), jnp.float32)
  init = lambda k: model.init(k, x, x, styles, method=lambda m, p, d, s: m(p, d, m.codes(s)))
  params = {}
  sampler = sampler_of(config.nerf)
  for net, k in zip(("coarse", "fine"), jax.random.split(key)):
    if net not in sampler.levels:
      continue
    params[net] = dict(init(k)["params"])
    if nerf_params is not None:
      # A copy: training donates its state, and must not delete the caller's arrays.
      params[net]["trunk"] = jax.tree_util.tree_map(jnp.array, nerf_params[net]["trunk"])
      if config.density_aware:
        params[net] = start_from_density(params[net])
  if sampler.occupancy:
    params["occupancy"] = (occupancy.init_grid(config.nerf.grid_resolution)
                           if nerf_params is None else jnp.array(nerf_params["occupancy"]))
  return params


def start_from_density(params: Dict) -> Dict:
  """Sets two units of the new density MLP so that it outputs the trunk's density exactly.

  A randomly initialised density head starts with most raw densities below zero (no
  density, no gradient: the coarse pass never learns). Instead, hidden unit 0 computes the
  frozen head's value a = h @ w + b and unit 1 computes -a, and the output layer takes
  relu(a) - relu(-a) = a; extra layers pass both units through. The other units start as
  initialised, with zero output weights, so they learn the style-dependent change.
  """
  w, b = params["trunk"]["density"]["kernel"][:, 0], params["trunk"]["density"]["bias"][0]
  hidden = params["density_hidden"]
  n = w.shape[0]
  kernel = hidden["kernel"].at[:, :2].set(0.0).at[:n, 0].set(w).at[:n, 1].set(-w)
  params["density_hidden"] = {"kernel": kernel, "bias": hidden["bias"].at[:2].set(
      jnp.stack([b, -b]))}
  for name in sorted(k for k in params if k.startswith("density_extra_")):
    layer = params[name]
    k = layer["kernel"].at[:, :2].set(0.0).at[:2, :].set(0.0).at[0, 0].set(1.0).at[1, 1].set(1.0)
    params[name] = {"kernel": k, "bias": layer["bias"].at[:2].set(0.0)}
  out = params["density_out"]
  params["density_out"] = {"kernel": jnp.zeros_like(out["kernel"]).at[0, 0].set(1.0)
                           .at[1, 0].set(-1.0), "bias": jnp.zeros_like(out["bias"])}
  return params
