"""The training loop every trainer (NeRF, multi-style, AdaIN, features, paint) shares:
batches -> a data-parallel step (msnerf_jax.core.parallel) -> progress, NaN guard, history
and atomic checkpoints with resume, on one process or several (msnerf_jax.core.distributed).

- Resume: training starts from the run's latest checkpoint; the checkpoints still to save are
  checked to fit on the disk first (DiskError if not).
- With several processes only process 0 shows progress, writes the history and runs the
  callback; all of them take part in the checkpoints (orbax) and stop at the same step.
- A loss that becomes NaN or infinite stops training with a UserError naming the step; the
  last good checkpoint stays the latest one.
- On SIGTERM or Ctrl-C (`stop.stop_requests`) the step in flight finishes, a checkpoint is
  saved there unless this process saved one less than `stop_save_after` seconds ago (a
  preempted job loses at most that long, and a quick second request is not slowed by a
  save), and Interrupted is raised.
"""

import json
import os
import time
from typing import Any, Callable, Dict, Optional, Sequence

import jax
import numpy as np

from msnerf_jax.core import checkpoint as ckpt_lib
from msnerf_jax.core import distributed
from msnerf_jax.core import files
from msnerf_jax.core.errors import Interrupted, UserError
from msnerf_jax.core.parallel import DataParallel
from msnerf_jax.core.progress import progress_bar
from msnerf_jax.train import state as state_lib
from msnerf_jax.train import stop as stop_lib


def fit(state: state_lib.TrainState, step_fn: Callable, batch_fn: Callable[[int], Any], *,
        run_dir: str, steps: int, checkpoint_every: int, keep_checkpoints: int,
        parallel: DataParallel, desc: str, progress: bool = True,
        callback: Optional[Callable[[int, Any], None]] = None,
        on_step: Optional[Callable[[int, Any, Dict[str, Any]], None]] = None,
        shown: Sequence[str] = ("psnr",), history: bool = True,
        stop_save_after: float = 60.0) -> Dict[str, Any]:
  """Trains from the run's latest checkpoint (if any) to `steps` (see the module's docstring).

  Args:
    state: a fresh TrainState (the template for restoring).
    step_fn: `parallel.compile`d `(state, batch) -> (state, stats)`; stats has "loss" and
      the `shown`.
    batch_fn: step -> the global batch of that step (a pure function of the step, so a
      resumed run replays the same batches, and every process computes the same one).
    callback: `callback(step, params)` after every checkpoint; not counted in the time.
    on_step: `on_step(step, state, stats)` after every step, before the loss check and that
      step's checkpoint: a trainer's own checks (raise to stop; that step is not saved) and
      outputs (AdaIN's sample images).
    shown: the stats shown beside the loss on the progress bar and, with `history`,
      appended with it to run_dir/history.jsonl, every 25 steps.
  Returns:
    summary dict: run_dir, steps, resumed_from, seconds, devices, processes and the last
    stats.
  Raises Interrupted (stop request), DiskError, UserError (NaN loss).
  """
  checkpoints, state, start = _resume(run_dir, state, steps, checkpoint_every,
                                      keep_checkpoints)
  primary = distributed.is_primary()
  run = _Run(run_dir, checkpoints, parallel, history and primary)
  state = parallel.put_state(state)
  stats, bar = {}, None
  try:
    with stop_lib.stop_requests() as stop_requested:
      bar = progress_bar(range(start, steps), initial=start, total=steps, desc=desc,
                         disable=not (progress and primary))
      for step in bar:
        state, stats = step_fn(state, parallel.put_batch(batch_fn(step)))
        done = step + 1
        if on_step is not None:
          on_step(done, state, stats)
        stats = parallel.to_host(stats)
        run.record(bar, done, stats, shown, done % 25 == 0 or done == steps)
        if done % checkpoint_every == 0 or done == steps:
          host = run.save(done, state)
          if callback is not None and primary:
            run.untimed(callback, done, host.params)
        signum = distributed.agreed_stop(stop_requested())
        if signum is not None and done < steps:
          run.interrupt(signum, done, state, stop_save_after)
  finally:
    if bar is not None:
      bar.close()
    checkpoints.close()
  run.write_history(steps)
  return {"run_dir": run_dir, "steps": steps, "resumed_from": start, "seconds": run.seconds(),
          "devices": parallel.size, "processes": jax.process_count(),
          **{k: float(v) for k, v in stats.items()}}


class _Run:
  """What `fit` keeps between steps: the training curve, the time spent training (callbacks
  left out) and the (step, time) of the last checkpoint this process saved."""

  def __init__(self, run_dir: str, checkpoints: ckpt_lib.Checkpoints, parallel: DataParallel,
               history: bool):
    self.run_dir, self.checkpoints, self.parallel = run_dir, checkpoints, parallel
    self.history, self.curve, self.last_save = history, [], None
    self.t0 = time.time()

  def seconds(self) -> float:
    return time.time() - self.t0

  def untimed(self, fn: Callable, *args) -> None:
    """Calls fn(*args) without counting its time."""
    t = time.time()
    fn(*args)
    self.t0 += time.time() - t

  def record(self, bar, done: int, stats: Dict[str, Any], shown: Sequence[str],
             show: bool) -> None:
    """UserError when the loss is NaN or infinite; else, when `show`, the loss and the `shown`
    stats on the progress bar and a point of the curve."""
    loss = float(stats["loss"])
    if not np.isfinite(loss):
      raise UserError(f"loss became {loss} at step {done}; training stopped, the last "
                      f"good checkpoint (step {self.checkpoints.latest_step()}) is kept")
    if show:
      values = {k: float(stats[k]) for k in shown}
      bar.set_postfix(loss=f"{loss:.4f}", **{k: f"{v:.2f}" for k, v in values.items()})
      self.curve.append({"step": done, "loss": loss, **values, "time": self.seconds()})

  def save(self, done: int, state: state_lib.TrainState) -> state_lib.TrainState:
    """Saves the device `state` as step `done`; returns it on the host."""
    host = self.parallel.to_host(state)
    self.checkpoints.save(done, state_lib.checkpoint_tree(host))
    self.last_save = (done, time.time())
    return host

  def write_history(self, up_to: int) -> None:
    """Appends the curve's points up to step `up_to` to the history (process 0)."""
    if self.history:
      append_history(self.run_dir, [r for r in self.curve if r["step"] <= up_to])

  def interrupt(self, signum: int, done: int, state: state_lib.TrainState,
                save_after: float) -> None:
    """Stops at step `done`: saves there unless this process saved less than `save_after`
    seconds ago, writes the curve up to the checkpoint the next run resumes from and raises
    Interrupted."""
    if self.last_save is None or time.time() - self.last_save[1] >= save_after:
      self.save(done, state)
    self.write_history(self.last_save[0])
    raise Interrupted(signum, done, self.last_save[0])


def bookkeeping(optim) -> Dict[str, int]:
  """fit's steps, checkpoint_every and keep_checkpoints from a config's optimisation block
  (config_lib.OptimConfig), or from an AdaIN config, which holds them at its top."""
  return {"steps": optim.steps, "checkpoint_every": optim.checkpoint_every,
          "keep_checkpoints": optim.keep_checkpoints}


def _resume(run_dir: str, state: state_lib.TrainState, steps: int, checkpoint_every: int,
            keep_checkpoints: int):
  """(the run's checkpoints, the state restored from the latest one or as given, its step),
  once the checkpoints still to save are known to fit on the disk (DiskError if not)."""
  checkpoints = ckpt_lib.Checkpoints(run_dir, keep=keep_checkpoints)
  try:
    start = 0
    if checkpoints.latest_step() is not None:
      state = state_lib.restore_state(state,
                                      checkpoints.restore(state_lib.checkpoint_tree(state)))
      start = int(state.step)
    saves = len({s for s in range(start + 1, steps + 1) if s % checkpoint_every == 0} | {steps})
    kept = len(checkpoints.all_steps())
    # Orbax writes a new checkpoint before it deletes the oldest: at most keep + 1 at once.
    checkpoints.check_space(state_lib.checkpoint_tree(state),
                            max(0, min(keep_checkpoints + 1, kept + saves) - kept))
  except BaseException:
    checkpoints.close()
    raise
  return checkpoints, state, start


def append_history(run_dir: str, history):
  """Appends training curve points to run_dir/history.jsonl (one JSON object a line),
  atomically: a kill or a full disk leaves the previous file."""
  if history:
    files.append_lines(os.path.join(run_dir, "history.jsonl"), [json.dumps(r) for r in history])
