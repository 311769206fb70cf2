"""Orbax checkpoints of a run folder: atomic saves, resume from the latest complete one.

Run folders themselves (run.json, `load_run`) are `msnerf_jax.kinds.runs`.
"""

import contextlib
import logging
import os
import shutil
from typing import Any, Optional

import jax
import numpy as np
import orbax.checkpoint as ocp

from msnerf_jax.core import files
from msnerf_jax.core.errors import UserError

CHECKPOINT_DIR = "checkpoints"
TMP_MARK = ".orbax-checkpoint-tmp"
# What orbax writes beside the arrays (metadata, OCDBT manifests), per checkpoint.
OVERHEAD_BYTES = 256 << 10


def latest_saved_step(run_dir: str) -> int:
  """The step of the latest checkpoint of a run folder, read from the folder names alone
  (nothing opened or cleaned up; 0: no run.json or no checkpoint)."""
  folder = os.path.join(run_dir, CHECKPOINT_DIR)
  if not os.path.isfile(os.path.join(run_dir, "run.json")) or not os.path.isdir(folder):
    return 0
  return max((int(n) for n in os.listdir(folder) if n.isdigit()), default=0)


def checkpoint_bytes(tree: Any) -> int:
  """About how many bytes one checkpoint of `tree` takes on disk."""
  leaves = jax.tree_util.tree_leaves(tree)
  return int(sum(x.nbytes if hasattr(x, "nbytes") else np.asarray(x).nbytes for x in leaves)
             * 1.05) + OVERHEAD_BYTES


@contextlib.contextmanager
def _quiet_writer_threads():
  """Orbax's writer threads log every failed array write at ERROR (screens of tracebacks on
  a full disk); the failure itself is raised to the caller, so they are silenced here."""
  loggers = [logging.getLogger(name) for name in ("absl", "asyncio")]
  levels = [logger.level for logger in loggers]
  for logger in loggers:
    logger.setLevel(logging.CRITICAL)
  try:
    yield
  finally:
    for logger, level in zip(loggers, levels):
      logger.setLevel(level)


class Checkpoints:
  """Orbax checkpoints of one run: atomic (written to a temporary folder, then renamed).

  A checkpoint is a dict pytree (params, optimizer state, step, PRNG key ...). A process
  killed mid-save leaves only a temporary folder, which is ignored and removed on the next
  start, so the latest *complete* checkpoint is what `restore` returns. On a full disk a
  save is refused before it starts when the estimate does not fit, and a save that fails
  anyway raises DiskError and leaves no temporary folder.
  """

  def __init__(self, run_dir: str, keep: int = 3):
    self.directory = os.path.abspath(os.path.join(run_dir, CHECKPOINT_DIR))
    # Temporary folders of killed or failed saves are removed here, synchronously: orbax's
    # own cleanup runs in a thread that a quickly exiting process would leave behind.
    if os.path.isdir(self.directory):
      self._remove_temporary()
    options = ocp.CheckpointManagerOptions(
        max_to_keep=keep, create=True, enable_async_checkpointing=False)
    self._manager = ocp.CheckpointManager(self.directory, options=options,
                                          item_handlers=ocp.StandardCheckpointHandler())

  def all_steps(self):
    return list(self._manager.all_steps())

  def latest_step(self) -> Optional[int]:
    return self._manager.latest_step()

  def check_space(self, tree: Any, count: int = 1) -> None:
    """DiskError up front unless `count` more checkpoints of `tree` fit on the disk."""
    if count > 0:
      files.check_free_space(self.directory, count * checkpoint_bytes(tree),
                             f"{count} checkpoint{'s' if count > 1 else ''}")

  def save(self, step: int, tree: Any) -> None:
    """Saves `tree` as checkpoint `step` (a no-op if it exists) or raises DiskError on a
    write fault (full disk ...), leaving no temporary folder and every earlier checkpoint
    as it was."""
    if step in self.all_steps():
      return
    self.check_space(tree)
    try:
      with _quiet_writer_threads():
        self._manager.save(step, args=ocp.args.StandardSave(tree), force=True)
        self._manager.wait_until_finished()
    except Exception as e:  # pylint: disable=broad-except
      error = files.disk_error(os.path.join(self.directory, str(step)), e,
                               checkpoint_bytes(tree))
      if error is None:
        raise
      self._remove_temporary()
      raise error from None

  def _remove_temporary(self) -> None:
    """Removes the temporary folders of failed saves (orbax would on the next start)."""
    for name in os.listdir(self.directory):
      if TMP_MARK in name:
        shutil.rmtree(os.path.join(self.directory, name), ignore_errors=True)

  def restore(self, template: Any = None, step: Optional[int] = None) -> Any:
    """The checkpoint at `step` (default latest) shaped like `template` (or raw dicts),
    as numpy arrays (however many processes and devices saved it or read it)."""
    step = self.latest_step() if step is None else step
    if step is None:
      raise UserError(f"{self.directory}: no checkpoint yet")
    try:
      if template is None:
        # The stored shapes and dtypes as a numpy template: restoring without one would
        # place arrays as they were saved, which fails under another device topology.
        template = jax.tree_util.tree_map(lambda m: np.zeros(m.shape, m.dtype),
                                          self._manager.item_metadata(step))
      return self._manager.restore(step, args=ocp.args.StandardRestore(template))
    except (ValueError, KeyError, TypeError) as e:
      raise UserError(f"{self.directory}/{step}: checkpoint does not match this config "
                      f"({str(e).splitlines()[0][:200]})") from None

  def close(self) -> None:
    with _quiet_writer_threads():
      self._manager.close()
