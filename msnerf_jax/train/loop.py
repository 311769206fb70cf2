"""The training loop every trainer (NeRF, multi-style, AdaIN) shares: batches -> (p)jitted
step -> progress, NaN guard, history and atomic checkpoints with resume."""

import functools
import json
import os
import time
from typing import Any, Callable, Dict, Optional, Sequence, Tuple

import jax
import numpy as np

from msnerf_jax import checkpoint as ckpt_lib
from msnerf_jax import files
from msnerf_jax.errors import Interrupted, UserError
from msnerf_jax.progress import progress_bar
from msnerf_jax.train import state as state_lib
from msnerf_jax.train import stop as stop_lib


def compile_step(step_fn: Callable, n_devices: int, constants: Tuple[Any, ...] = ()
                 ) -> Callable:
  """`(state, batch) -> (state, stats)`: jax.jit (one device) or jax.pmap over axis "batch"
  (several) of `step_fn(state, batch, *constants, axis_name=None)`; the state is donated.

  `constants` (pytrees every step reads unchanged: style vectors, a frozen encoder) are put
  on the device(s) once, here, and passed as arguments rather than baked into the program.
  """
  if n_devices == 1:
    compiled = jax.jit(step_fn, donate_argnums=0)
    placed = jax.device_put(constants)
  else:
    compiled = jax.pmap(functools.partial(step_fn, axis_name="batch"), axis_name="batch",
                        donate_argnums=0)
    placed = state_lib.replicate(constants, jax.local_devices()[:n_devices])
  return lambda state, batch: compiled(state, batch, *placed)


def fit(state: state_lib.TrainState, step_fn: Callable, batch_fn: Callable[[int], Any], *,
        run_dir: str, steps: int, checkpoint_every: int, keep_checkpoints: int,
        n_devices: int, desc: str, progress: bool = True,
        callback: Optional[Callable[[int, Any], None]] = None,
        on_step: Optional[Callable[[int, Any, Dict[str, Any]], None]] = None,
        shown: Sequence[str] = ("psnr",), history: bool = True,
        stop_save_after: float = 60.0) -> Dict[str, Any]:
  """Trains from the run's latest checkpoint (if any) to `steps`.

  Args:
    state: a fresh TrainState (the template for restoring).
    step_fn: compiled `(state, batch) -> (state, stats)`; stats has "loss" and the `shown`.
    batch_fn: step -> the global batch of that step (a pure function of the step, so a
      resumed run replays the same batches).
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
    summary dict: run_dir, steps, resumed_from, seconds, devices and the last stats.
  Raises:
    Interrupted on SIGTERM or Ctrl-C (after the save above).
    DiskError when the checkpoints will not fit (checked before the first step) or a save
    fails for lack of space (the earlier checkpoints are kept).
    UserError when the loss becomes NaN/inf (naming the step; the last good checkpoint
    stays the latest one).
  """
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
  if n_devices > 1:
    state = state_lib.replicate(state, jax.local_devices()[:n_devices])
  t0 = time.time()
  stats, curve = {}, []
  last_save = None  # (step, time) of the last checkpoint this process saved
  bar = None

  def save(done):
    nonlocal last_save
    host = state_lib.unreplicate(state) if n_devices > 1 else state
    checkpoints.save(done, state_lib.checkpoint_tree(host))
    last_save = (done, time.time())
    return host

  try:
    with stop_lib.stop_requests() as stop_requested:
      bar = progress_bar(range(start, steps), initial=start, total=steps, desc=desc,
                         disable=not progress)
      for step in bar:
        batch = batch_fn(step)
        if n_devices > 1:
          batch = state_lib.shard(batch, n_devices)
        state, stats = step_fn(state, batch)
        if on_step is not None:
          on_step(step + 1, state, stats)
        loss = float(np.asarray(stats["loss"]).reshape(-1)[0])
        if not np.isfinite(loss):
          raise UserError(f"loss became {loss} at step {step + 1}; training stopped, the last "
                          f"good checkpoint (step {checkpoints.latest_step()}) is kept")
        done = step + 1
        if done % 25 == 0 or done == steps:
          values = {k: float(np.asarray(stats[k]).reshape(-1)[0]) for k in shown}
          bar.set_postfix(loss=f"{loss:.4f}", **{k: f"{v:.2f}" for k, v in values.items()})
          curve.append({"step": done, "loss": loss, **values, "time": time.time() - t0})
        if done % checkpoint_every == 0 or done == steps:
          host = save(done)
          if callback is not None:
            t_cb = time.time()
            callback(done, host.params)
            t0 += time.time() - t_cb
        signum = stop_requested()
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
  final = {k: float(np.asarray(v).reshape(-1)[0]) for k, v in stats.items()}
  return {"run_dir": run_dir, "steps": steps, "resumed_from": start,
          "seconds": time.time() - t0, "devices": n_devices, **final}


def append_history(run_dir: str, history):
  """Appends training curve points to run_dir/history.jsonl (one JSON object a line),
  atomically: a kill or a full disk leaves the previous file."""
  if history:
    files.append_lines(os.path.join(run_dir, "history.jsonl"), [json.dumps(r) for r in history])
