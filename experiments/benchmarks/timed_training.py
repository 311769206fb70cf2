"""Training for a wall-clock budget, for the benchmark scripts beside this file.

A benchmark gives a trainer (`nerf.train`, `multistyle.train`, ...) a callback that evaluates
at every checkpoint; the evaluation's time is left out of the training time, and training stops
at the first checkpoint past the budget.
"""

import time


class _Done(Exception):
  pass


def train_within(minutes, train, evaluate, show):
  """Runs `train(callback)` until the first checkpoint whose training time passes `minutes`.

  Args:
    minutes: the budget of training time (evaluations excluded).
    train: train(callback) runs the trainer with `callback(step, params)` at its checkpoints.
    evaluate: evaluate(step, params) -> dict of figures for that checkpoint.
    show: show(row) prints a row: {"step", "train_seconds", **figures}.
  Returns:
    (rows, the params of the last checkpoint).
  """
  rows, last = [], {}
  clock = {"start": time.time(), "eval": 0.0}

  def callback(step, params):
    t = time.time()
    figures = evaluate(step, params)
    clock["eval"] += time.time() - t
    train_s = time.time() - clock["start"] - clock["eval"]
    rows.append({"step": step, "train_seconds": round(train_s, 1), **figures})
    last["params"] = params
    show(rows[-1])
    if train_s > minutes * 60:
      raise _Done()

  try:
    train(callback)
  except _Done:
    pass
  return rows, last["params"]
