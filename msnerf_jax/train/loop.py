"""The training loop every trainer (NeRF, multi-style, AdaIN) shares: batches -> (p)jitted
step -> progress, NaN guard, history and atomic checkpoints with resume."""

import functools
import json
import os
import time
from typing import Any, Callable, Dict, Optional, Sequence, Tuple

import jax
import numpy as np
from tqdm.auto import tqdm

from msnerf_jax import checkpoint as ckpt_lib
from msnerf_jax.errors import UserError
from msnerf_jax.train import state as state_lib


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
        shown: Sequence[str] = ("psnr",), history: bool = True) -> Dict[str, Any]:
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
  Returns:
    summary dict: run_dir, steps, resumed_from, seconds, devices and the last stats.
  Raises:
    UserError when the loss becomes NaN/inf (naming the step; the last good checkpoint
    stays the latest one).
  """
  checkpoints = ckpt_lib.Checkpoints(run_dir, keep=keep_checkpoints)
  start = 0
  if checkpoints.latest_step() is not None:
    state = state_lib.restore_state(state, checkpoints.restore(state_lib.checkpoint_tree(state)))
    start = int(state.step)
  if n_devices > 1:
    state = state_lib.replicate(state, jax.local_devices()[:n_devices])
  t0 = time.time()
  stats, curve = {}, []
  bar = tqdm(range(start, steps), initial=start, total=steps, desc=desc,
             disable=not progress, dynamic_ncols=True)
  try:
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
        host = state_lib.unreplicate(state) if n_devices > 1 else state
        checkpoints.save(done, state_lib.checkpoint_tree(host))
        if callback is not None:
          t_cb = time.time()
          callback(done, host.params)
          t0 += time.time() - t_cb
  finally:
    bar.close()
    checkpoints.close()
  if history:
    append_history(run_dir, curve)
  final = {k: float(np.asarray(v).reshape(-1)[0]) for k, v in stats.items()}
  return {"run_dir": run_dir, "steps": steps, "resumed_from": start,
          "seconds": time.time() - t0, "devices": n_devices, **final}


def append_history(run_dir: str, history):
  """Appends training curve points to run_dir/history.jsonl (one JSON object a line)."""
  if not history:
    return
  with open(os.path.join(run_dir, "history.jsonl"), "a") as f:
    for row in history:
      f.write(json.dumps(row) + "\n")
