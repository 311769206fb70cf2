"""Orbax checkpoints of a run folder: atomic saves, resume from the latest complete one.

Run folders themselves (run.json, `load_run`) are `msnerf_jax.runs`.
"""

import os
from typing import Any, Optional

import orbax.checkpoint as ocp

from msnerf_jax.errors import UserError

CHECKPOINT_DIR = "checkpoints"


class Checkpoints:
  """Orbax checkpoints of one run: atomic (written to a temporary folder, then renamed).

  A checkpoint is a dict pytree (params, optimizer state, step, PRNG key ...). A process
  killed mid-save leaves only a temporary folder, which orbax ignores and removes, so the
  latest *complete* checkpoint is what `restore` returns.
  """

  def __init__(self, run_dir: str, keep: int = 3):
    self.directory = os.path.abspath(os.path.join(run_dir, CHECKPOINT_DIR))
    options = ocp.CheckpointManagerOptions(
        max_to_keep=keep, create=True, enable_async_checkpointing=False,
        cleanup_tmp_directories=True)
    self._manager = ocp.CheckpointManager(self.directory, options=options)

  def latest_step(self) -> Optional[int]:
    return self._manager.latest_step()

  def save(self, step: int, tree: Any) -> None:
    if step in self._manager.all_steps():
      return
    self._manager.save(step, args=ocp.args.StandardSave(tree), force=True)
    self._manager.wait_until_finished()

  def restore(self, template: Any = None, step: Optional[int] = None) -> Any:
    """The checkpoint at `step` (default latest) shaped like `template` (or raw dicts)."""
    step = self.latest_step() if step is None else step
    if step is None:
      raise UserError(f"{self.directory}: no checkpoint yet")
    try:
      if template is None:
        return self._manager.restore(step, args=ocp.args.StandardRestore())
      return self._manager.restore(step, args=ocp.args.StandardRestore(template))
    except (ValueError, KeyError, TypeError) as e:
      raise UserError(f"{self.directory}/{step}: checkpoint does not match this config "
                      f"({str(e).splitlines()[0][:200]})") from None

  def close(self) -> None:
    self._manager.close()
