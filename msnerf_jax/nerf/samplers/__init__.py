"""Samplers, registered by NerfConfig.sampler's value: a new sampler is one file in this
package and one entry here."""

from typing import Dict

from msnerf_jax.core.errors import UserError
from msnerf_jax.nerf.samplers.base import Sampler
from msnerf_jax.nerf.samplers.grid import GRID
from msnerf_jax.nerf.samplers.hierarchical import HIERARCHICAL

SAMPLERS: Dict[str, Sampler] = {s.name: s for s in (HIERARCHICAL, GRID)}


def sampler_of(config) -> Sampler:
  """The sampler a NerfConfig names (UserError naming --sampler for an unknown one)."""
  if config.sampler not in SAMPLERS:
    raise UserError(f"--sampler {config.sampler}: unknown sampler "
                    f"(choose from {', '.join(SAMPLERS)})")
  return SAMPLERS[config.sampler]
