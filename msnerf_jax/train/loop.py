"""The training loop every trainer (NeRF, multi-style, AdaIN) shares: batches -> a
data-parallel step (msnerf_jax.core.parallel) -> progress, NaN guard, history and atomic
checkpoints with resume, on one process or several (msnerf_jax.core.distributed)."""

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
  """Trains from the run's latest checkpoint (if any) to `steps`.

  Args:
    state: a fresh TrainState (the template for restoring).
    step_fn: `parallel.compile`d `(state, batch) -> (state, stats)`; stats has "loss" and
      the `shown`.
    batch_fn: step -> the global batch of that step (a pure function of the step, so a
      resumed run replays the same batches, and every process computes the same one).
    parallel: the devices (and processes) the step runs on. With several processes, only
      process 0 shows progress, writes the history and runs `callback`; all of them take
      part in the checkpoints (orbax) and stop at the same step.
    callback: `callback(step, params)` after every checkpoint; not counted in the time.
    on_step: `on_step(step, state, stats)` after every step, before the loss check and that
      step's checkpoint: a trainer's own checks (raise to stop; that step is not saved) and
      outputs (AdaIN's sample images).
    shown: the stats shown beside the loss on the progress bar and, with `history`,
      appended with it to run_dir/history.jsonl, every 25 steps.
    stop_save_after: on SIGTERM or Ctrl-C (see `stop.stop_requests`) the step in flight
      finishes, a checkpoint is saved there unless this process saved one less than this
      many seconds ago, and Interrupted is raised.
  Returns:
    summary dict: run_dir, steps, resumed_from, seconds, devices, processes and the last
    stats.
  Raises:
    Interrupted on SIGTERM or Ctrl-C (after the save above).
    DiskError when the checkpoints will not fit (checked before the first step) or a save
    fails for lack of space (the earlier checkpoints are kept).
    UserError when the loss becomes NaN/inf (naming the step; the last good checkpoint
    stays the latest one).
  """
  checkpoints, state, start = _resume(run_dir, state, steps, checkpoint_every,
                                      keep_checkpoints)
  state = parallel.put_state(state)
  primary = distributed.is_primary()
  history = history and primary
  t0 = time.time()
  stats, curve = {}, []
  last_save = None  # (step, time) of the last checkpoint this process saved
  bar = None

  def save(done):
    nonlocal last_save
    host = parallel.to_host(state)
    checkpoints.save(done, state_lib.checkpoint_tree(host))
    last_save = (done, time.time())
    return host

  try:
    with stop_lib.stop_requests() as stop_requested:
      bar = progress_bar(range(start, steps), initial=start, total=steps, desc=desc,
                         disable=not (progress and primary))
      for step in bar:
        state, stats = step_fn(state, parallel.put_batch(batch_fn(step)))
        if on_step is not None:
          on_step(step + 1, state, stats)
        stats = parallel.to_host(stats)
        loss = float(stats["loss"])
        if not np.isfinite(loss):
          raise UserError(f"loss became {loss} at step {step + 1}; training stopped, the last "
                          f"good checkpoint (step {checkpoints.latest_step()}) is kept")
        done = step + 1
        if done % 25 == 0 or done == steps:
          values = {k: float(stats[k]) for k in shown}
          bar.set_postfix(loss=f"{loss:.4f}", **{k: f"{v:.2f}" for k, v in values.items()})
          curve.append({"step": done, "loss": loss, **values, "time": time.time() - t0})
        if done % checkpoint_every == 0 or done == steps:
          host = save(done)
          if callback is not None and primary:
            t_cb = time.time()
            callback(done, host.params)
            t0 += time.time() - t_cb
        signum = distributed.agreed_stop(stop_requested())
        if signum is not None and done < steps:
          # Save unless this process saved less than a minute ago: a preempted job loses
          # at most a minute, and a quick second request is not slowed by a save.
          if last_save is None or time.time() - last_save[1] >= stop_save_after:
            save(done)
          if history:  # the curve up to the checkpoint the next run resumes from
            append_history(run_dir, [r for r in curve if r["step"] <= last_save[0]])
          raise Interrupted(signum, done, last_save[0])
  finally:
    if bar is not None:
      bar.close()
    checkpoints.close()
  if history:
    append_history(run_dir, curve)
  final = {k: float(v) for k, v in stats.items()}
  return {"run_dir": run_dir, "steps": steps, "resumed_from": start,
          "seconds": time.time() - t0, "devices": parallel.size,
          "processes": jax.process_count(), **final}


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
