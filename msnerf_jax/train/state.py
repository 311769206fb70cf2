"""Shared training machinery: TrainState, optimizers with a freeze mask (devices:
msnerf_jax.core.parallel)."""

from typing import Any, Callable, Optional

import jax
import optax
from flax.training import train_state

from msnerf_jax.core.config import OptimConfig

TrainState = train_state.TrainState


def exponential_lr(optim: OptimConfig) -> optax.Schedule:
  """lr_init * (lr_final / lr_init) ** (step / lr_decay_steps) (the reference decay) of a
  config's optimisation block."""
  return optax.exponential_decay(optim.lr_init, transition_steps=optim.lr_decay_steps,
                                 decay_rate=optim.lr_final / optim.lr_init)


def adam(schedule, frozen: Optional[Callable[[Any], Any]] = None,
         **adam_args: float) -> optax.GradientTransformation:
  """Adam (optax.adam with `adam_args`, e.g. b2, eps); leaves for which the `frozen(params)`
  mask is True get no update and no state.

  `frozen` maps a params pytree to a pytree of booleans (True = frozen). Frozen leaves go
  through optax.set_to_zero(), which keeps no optimizer state for them.
  """
  if frozen is None:
    return optax.adam(schedule, **adam_args)
  def labels(params):
    return jax.tree_util.tree_map(lambda f: "frozen" if f else "train", frozen(params))
  return optax.multi_transform({"train": optax.adam(schedule, **adam_args),
                                "frozen": optax.set_to_zero()}, labels)


def create_state(params, tx: optax.GradientTransformation) -> TrainState:
  return TrainState.create(apply_fn=None, params=params, tx=tx)


def checkpoint_tree(state: TrainState):
  """What a checkpoint holds of a TrainState."""
  return {"step": state.step, "params": state.params, "opt_state": state.opt_state}


def restore_state(state: TrainState, tree) -> TrainState:
  return state.replace(step=tree["step"], params=tree["params"], opt_state=tree["opt_state"])
