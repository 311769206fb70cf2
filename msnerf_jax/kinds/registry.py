"""The registry of run kinds: a new kind is one file in this package (its `KIND`) and one
line here. Nothing else in the package tests a run's kind by name."""

from typing import Dict

from msnerf_jax.core.errors import UserError
from msnerf_jax.kinds import adain, features, multistyle, nerf, painted
from msnerf_jax.kinds.base import RunKind

KINDS: Dict[str, RunKind] = {k.name: k for k in (
    nerf.KIND, adain.KIND, multistyle.KIND, features.KIND, painted.KIND)}


def get_kind(name: str) -> RunKind:
  """The RunKind saved as `name` in run.json; UserError for an unknown one."""
  if name not in KINDS:
    raise UserError(f"unknown run kind {name!r} (known: {', '.join(sorted(KINDS))})")
  return KINDS[name]
