"""The sampler interface: how a renderer places samples along rays and renders a batch. The
one renderer (msnerf_jax.nerf.render) asks `samplers.sampler_of(config)` and never tests a
sampler by name."""

import dataclasses
from typing import Any, Callable, Dict, Optional

# call(params, config, white_background, mesh, piece, styles, budget=None, first=None) ->
# numpy image outputs of one jitted call on `piece`'s rays (render._render_call, bound).
RenderCall = Callable[..., Dict[str, Any]]


@dataclasses.dataclass(frozen=True)
class Sampler:
  """A way of sampling rays; hashable, so it can be a static argument.

  Attributes:
    name: NerfConfig.sampler's value.
    levels: the params keys of the field's levels it renders, e.g. ("coarse", "fine").
    occupancy: its params also hold an occupancy grid (`params["occupancy"]`, [G, G, G]).
  """
  name: str = ""
  levels: tuple = ()
  occupancy: bool = False

  def draw_randomness(self, key, n_rays: int, config) -> Dict[str, Any]:
    """Every random number one training batch of rays needs, drawn up front ({} renders
    deterministically)."""
    raise NotImplementedError

  def render_rays(self, field, params, rays, config, randomness, white_background,
                  background=None, conditioning=None) -> Dict[str, Dict[str, Any]]:
    """{level: outputs} of a batch of rays (render.render_rays' contract)."""
    raise NotImplementedError

  def image_rays(self, field, params, rays, config, white_background, conditioning=None,
                 budget=None, first=None) -> Dict[str, Any]:
    """The last level's outputs of a rendering call's rays (deterministic)."""
    raise NotImplementedError

  def render_config(self, config):
    """The config a whole image renders with (forward only)."""
    return config

  def host_state(self, params) -> Any:
    """What the host needs of the params between rendering calls (None: nothing)."""
    del params
    return None

  def render_piece(self, call: RenderCall, params, host_state, config, white_background, mesh,
                   piece, styles) -> Dict[str, Any]:
    """Numpy image outputs of one chunk of rays, through `call` once or more."""
    raise NotImplementedError

  def feature_rays(self, field, feature_fn, params, rays, config, top_k: int,
                   budget: Optional[int] = None) -> Dict[str, Any]:
    """A feature field composited with the frozen NeRF's weights (render_feature_rays)."""
    raise NotImplementedError

  def weighted_samples(self, field, nerf_params, rays, config, top_k: int,
                       budget: Optional[int] = None) -> Dict[str, Any]:
    """The frozen NeRF's samples along rays [R] that carry its compositing weight (the
    `top_k` heaviest a ray, or every sample marched in `budget` slots), no gradient:
    {"points": [S, 3], "weights": [S], "ray": [S] int32 (R for an empty slot), "complete":
    [R] bool}. What feature_rays composites and painted fields cache."""
    raise NotImplementedError

  def piece_budget(self, host_state, config, piece) -> Optional[int]:
    """The static sample budget of a feature-rendering call on `piece` (None: unbounded)."""
    del host_state, config, piece
    return None
