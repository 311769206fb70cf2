"""The optimisation block every trainer on a NeRF run shares (the NeRF, the multi-style heads,
the feature field, the painted fields): Adam's exponentially decaying learning rate, the
steps, the seed and the checkpoints. Each config holds one as `optim`, with its own defaults
(`optimisation`); its settings are the config's own options (--steps, --lr-final, ...) and
overrides (`override(config, steps=...)`)."""

import dataclasses
import functools
from typing import Any, Optional

from msnerf_jax.core.config.base import check_at_least, check_positive, setting


@dataclasses.dataclass(frozen=True)
class OptimConfig:
  """Adam's schedule lr_init * (lr_final / lr_init) ** (step / lr_decay_steps), the steps,
  the seed and the checkpoints of a run. Its defaults here are generic: set a config's
  block from that config's own defaults, `override(PaintConfig(), steps=40)`."""
  steps: int = setting(1000, "training steps")
  lr_init: float = setting(1e-3, "initial learning rate (decays exponentially to --lr-final at "
                                 "--lr-decay-steps)")
  lr_final: float = setting(1e-4, "learning rate reached at --lr-decay-steps (exponential "
                                  "decay)")
  lr_decay_steps: int = setting(1000, "steps over which the learning rate decays to "
                                      "--lr-final")
  seed: int = setting(0, "random seed")
  checkpoint_every: int = setting(500, "steps between checkpoints")
  keep_checkpoints: int = setting(3, "checkpoints kept in RUN/checkpoints")

  def validate(self, lr_flag: Optional[str] = None) -> "OptimConfig":
    """The block itself, or UserError `--OPTION VALUE: problem` naming the first setting
    that cannot work; `lr_flag` the option that sets lr_init where it is not --lr-init."""
    check_at_least(self, ("steps",))
    check_positive(self, ("lr_init",), lr_flag)
    check_positive(self, ("lr_final",))
    check_at_least(self, ("lr_decay_steps", "checkpoint_every", "keep_checkpoints"))
    return self


def optimisation(**defaults: Any) -> Any:
  """A config's `optim` field: an OptimConfig with that trainer's defaults, whose settings
  are the config's own options (config_lib.flat_fields)."""
  return dataclasses.field(default_factory=functools.partial(OptimConfig, **defaults),
                           metadata={"flat": True})
