"""Crash safety: every trainer, run as `python -m msnerf_jax ...`, is SIGKILLed at random moments
and the same command re-run; it must resume from the last complete checkpoint (never a partial
one, never losing more than one checkpoint interval) and end with valid parameters, bit-identical
to those of an uninterrupted run of the same command (which also shows that the same command
with the same seed gives bit-identical parameters on CPU).

All of it carries the `slow` marker (the default suite's 10-minute budget; there,
test_machine_faults.py stops training with SIGTERM and a full disk and checks the resumes).
`-m slow` kills each trainer once and 20 times, and the pipeline, a stylized dataset and an
evaluation 20 times each, checking after every kill that each artefact is absent or
complete.
"""

import os
import random
import re
import signal
import subprocess
import sys
import time

import jax
import numpy as np
import pytest

import msnerf_jax
from msnerf_jax.core.config import DataConfig, override
from msnerf_jax.data.scene import load_scene
from msnerf_jax.models import decoder

from conftest import flat_params, trainer_env, untrained_nerf_run, write_blender_scene
from test_bad_input import write_style, write_stylized
from test_train_nerf import TINY

# Progress off a terminal: "nerf train: 12/120 (10%) 3s loss=..." lines (msnerf_jax.core.progress).
PROGRESS = re.compile(r"(?:nerf train|multistyle train|adain): [^\r\n]*?(\d+)/(\d+) \(")


def trainer_inputs(root, request):
  """A scene, an (untrained) NeRF run on it, a stylized dataset, and the environment of the
  trainer processes (a persistent JAX compilation cache, a progress line every step), in
  `root`: what the NeRF and multi-style trainers' process tests start from."""
  scene = write_blender_scene(str(root / "scene"), n_train=3, n_val=1, size=16)
  _, data = load_scene(DataConfig(path=scene))
  nerf_run = str(root / "nerf")
  untrained_nerf_run(nerf_run, data, override(TINY, steps=2, checkpoint_every=2))
  stylized = write_stylized(scene, str(root / "stylized"))
  # A progress line every step: the kills land in training steps.
  env = trainer_env(request, root / "jax-cache", MSNERF_PROGRESS_PERCENT="0.5")
  return {"root": root, "scene": scene, "nerf": nerf_run, "stylized": stylized, "env": env}


@pytest.fixture(scope="module")
def inputs(tmp_path_factory, request):
  """trainer_inputs, plus content and style folders (for the AdaIN trainer)."""
  root = tmp_path_factory.mktemp("kill")
  for folder in ("content", "styles"):
    (root / folder).mkdir()
  for i in range(2):
    write_style(root / "content" / f"c{i}.png", (30 + 100 * i, 160, 60), size=(24, 20))
    write_style(root / "styles" / f"s{i}.png", (200, 30 + 100 * i, 30), size=(20, 24))
  return {**trainer_inputs(root, request), "content": str(root / "content"),
          "styles": str(root / "styles")}


def command(trainer, inputs, out, steps):
  """(argv, checkpoint interval) of a tiny run of `trainer` into `out`."""
  every = 3
  if trainer == "nerf":
    argv = ["nerf", "train", "--data", inputs["scene"], "--batch-rays", "64"]
  elif trainer == "adain":
    argv = ["adain", "train", "--content", inputs["content"], "--styles", inputs["styles"],
            "--size", "16", "--resize", "16", "--batch", "1", "--sample-every", "100000"]
  else:
    argv = ["multistyle", "train", "--nerf", inputs["nerf"], "--stylized", inputs["stylized"],
            "--batch-rays", "16"]
  return argv + ["--out", out, "--steps", str(steps), "--checkpoint-every", str(every)], every


def start(argv, env, log):
  out, err = open(log + ".out", "w"), open(log + ".err", "w")
  proc = subprocess.Popen([sys.executable, "-m", "msnerf_jax", *argv], stdout=out, stderr=err,
                          env=env, start_new_session=True)
  out.close()
  err.close()
  return proc


def progress(log):
  """Steps shown by the progress bar of a process so far: (first, last) or None."""
  text = open(log + ".err", errors="replace").read()
  counts = [int(m.group(1)) for m in PROGRESS.finditer(text)]
  return (counts[0], counts[-1]) if counts else None


def complete_checkpoints(run):
  folder = os.path.join(run, "checkpoints")
  if not os.path.isdir(folder):
    return []
  return sorted(int(n) for n in os.listdir(folder) if n.isdigit())


def run_to_end(argv, env, log, timeout=600):
  proc = start(argv, env, log)
  try:
    code = proc.wait(timeout=timeout)
  except subprocess.TimeoutExpired:
    os.killpg(proc.pid, signal.SIGKILL)
    raise
  assert code == 0, open(log + ".err").read()[-3000:]
  return proc


def kill_and_resume(trainer, inputs, tmp_path, kills, steps, seed):
  """Runs the command `kills` times, SIGKILLing it at a random moment after its progress bar
  appears, then to the end; checks every resume. Returns (run folder, argv maker, kills done)."""
  rng = random.Random(seed)
  run = str(tmp_path / "killed")
  argv, every = command(trainer, inputs, run, steps)
  env = inputs["env"]
  done, mid_save, resumes = 0, 0, []
  expected_start = 0
  for k in range(kills):
    log = str(tmp_path / f"kill{k}")
    proc = start(argv, env, log)
    t_end = time.time() + 300
    # Every other kill waits for this process's first new checkpoint, the others only for
    # training steps to run; then a random delay (kills land in steps, saves and restarts).
    while proc.poll() is None and time.time() < t_end:
      shown = progress(log)
      if k % 2 == 0:
        if any(c > expected_start for c in complete_checkpoints(run)):
          break
      elif shown is not None and shown[1] > shown[0]:
        break
      time.sleep(0.02)
    time.sleep(rng.uniform(0.0, 1.0))
    if proc.poll() is None:
      os.killpg(proc.pid, signal.SIGKILL)
    code = proc.wait()
    shown = progress(log)
    if code == 0:  # finished before the kill: nothing more to interrupt.
      assert shown is not None and shown[0] == expected_start
      expected_start = steps
      break
    assert code == -signal.SIGKILL, open(log + ".err").read()[-3000:]
    done += 1
    complete = complete_checkpoints(run)
    folder = os.path.join(run, "checkpoints")
    if os.path.isdir(folder):
      mid_save += any(not n.isdigit() for n in os.listdir(folder))
    if shown is not None:
      # It resumed where the previous process left its last complete checkpoint ...
      assert shown[0] == expected_start, (k, shown, expected_start)
      # ... and its own last complete checkpoint is at most one interval behind its progress
      # (the bar lags the real step count, never leads it).
      latest = complete[-1] if complete else 0
      assert shown[1] - latest <= every, (k, shown, complete)
    expected_start = complete[-1] if complete else 0
    resumes.append(expected_start)
  log = str(tmp_path / "final")
  if expected_start < steps:
    run_to_end(argv, env, log)
    assert progress(log)[0] == expected_start, (progress(log), expected_start)
  leftovers = [n for n in os.listdir(os.path.join(run, "checkpoints")) if not n.isdigit()]
  assert not leftovers, leftovers
  assert complete_checkpoints(run)[-1] == steps
  print(f"{trainer}: killed {done} times, {mid_save} of them mid-save; resumed from "
        f"{resumes}")
  assert any(r > 0 for r in resumes), resumes  # some kill came after a checkpoint
  return run, done, mid_save


def check_final(run, clean, steps):
  loaded = msnerf_jax.load_run(run)
  assert loaded.step == steps
  got = flat_params(run)
  assert all(np.all(np.isfinite(v)) for _, v in got)
  if clean is not None:
    want = flat_params(clean)
    assert [p for p, _ in got] == [p for p, _ in want]
    for (path, a), (_, b) in zip(got, want):
      assert a.shape == b.shape and a.dtype == b.dtype, path
      assert np.array_equal(a.view(np.uint8), b.view(np.uint8)), f"{path} differs from a clean run"


STEPS = {"nerf": 45, "adain": 30, "multistyle": 36}


@pytest.mark.slow
@pytest.mark.parametrize("trainer", ["nerf", "multistyle", "adain"])
def test_kill_and_resume(trainer, inputs, tmp_path):
  """A random SIGKILL; NeRF ends bit-identical to an uninterrupted run of the same command
  (reproducibility; the slow test checks all three); multi-style and AdaIN end with valid
  params of their tree."""
  steps = STEPS[trainer]
  run, done, _ = kill_and_resume(trainer, inputs, tmp_path, kills=1, steps=steps, seed=7)
  assert done >= 1
  clean = None
  if trainer == "nerf":  # keeps the default suite within its CPU budget
    clean = str(tmp_path / "clean")
    run_to_end(command(trainer, inputs, clean, steps)[0], inputs["env"], str(tmp_path / "clean"))
  check_final(run, clean, steps)
  if trainer == "adain":
    want = jax.eval_shape(lambda: decoder.init_decoder(jax.random.PRNGKey(0)))
    got = msnerf_jax.load_run(run).params
    assert jax.tree_util.tree_structure(got) == jax.tree_util.tree_structure(want)


@pytest.mark.slow
@pytest.mark.parametrize("trainer", ["nerf", "multistyle", "adain"])
def test_kill_20_times_and_resume(trainer, inputs, tmp_path):
  steps = 20 * 6
  run, done, mid_save = kill_and_resume(trainer, inputs, tmp_path, kills=20, steps=steps,
                                        seed=20)
  assert done >= 15, done
  clean = str(tmp_path / "clean")
  run_to_end(command(trainer, inputs, clean, steps)[0], inputs["env"], str(tmp_path / "clean"))
  check_final(run, clean, steps)


# ------------------------------------------------- every other artefact, killed 20 times

DEMO = ["--size", "16", "--views", "4", "--adain-steps", "4", "--adain-size", "16",
        "--nerf-steps", "30", "--nerf-batch-rays", "64", "--ms-steps", "30",
        "--ms-batch-rays", "32", "--features-steps", "30", "--features-batch-cells", "8",
        "--frames", "6", "--grid-views", "2"]


def check_artefacts(folder):
  """Every file under `folder` is complete: it parses as what its name says. Hidden
  temporaries of a killed atomic write (.tmp-*) and orbax's temporary checkpoint folders are
  not artefacts (the next run ignores and removes them); complete checkpoints are checked by
  the trainer kill tests. Returns the artefacts' relative paths."""
  import imageio_ffmpeg  # pylint: disable=g-import-not-at-top
  import json  # pylint: disable=g-import-not-at-top
  from PIL import Image  # pylint: disable=g-import-not-at-top
  found = []
  for root, dirs, names in os.walk(folder):
    dirs[:] = [d for d in dirs if d != "checkpoints"]
    for name in names:
      path = os.path.join(root, name)
      if name.startswith(".tmp-"):
        continue
      ext = os.path.splitext(name)[1].lower()
      if ext in (".png", ".gif", ".jpg"):
        with Image.open(path) as im:
          im.load()
      elif ext == ".json":
        json.load(open(path))
      elif ext == ".jsonl":
        [json.loads(line) for line in open(path)]
      elif ext == ".npy":
        np.load(path, allow_pickle=False)
      elif ext == ".mp4":
        assert imageio_ffmpeg.count_frames_and_secs(path)[0] > 0, path
      elif ext in (".txt", ".md", ".csv"):
        open(path, encoding="utf-8").read()  # may be empty (an AdaIN run's holdout.txt)
      found.append(os.path.relpath(path, folder))
  return sorted(found)


def timed_run(argv, env, log):
  t = time.time()
  run_to_end(argv, env, log)
  return time.time() - t


def kill_20_times(argv, env, tmp_path, outputs, seed, duration):
  """SIGKILLs `argv` 20 times at random moments of its `duration` (an uninterrupted run's
  seconds; a fresh run that finishes first, its compilation cache warm, shortens it) and
  checks every artefact under `outputs` after each kill. Each re-run resumes and so has
  less left to do; one that finishes before its kill is checked too, and the
  outputs are then removed so that the next kills land in every stage again. Ends with a
  run to the end. Returns the number of runs that finished before their kill."""
  import shutil  # pylint: disable=g-import-not-at-top
  rng = random.Random(seed)
  kills = finished = 0
  while kills < 20:
    log = str(tmp_path / f"run{kills}-{finished}")
    fresh = not any(os.path.exists(folder) for folder in outputs)
    proc, t = start(argv, env, log), time.time()
    try:
      proc.wait(timeout=rng.uniform(0.3, duration))
    except subprocess.TimeoutExpired:
      os.killpg(proc.pid, signal.SIGKILL)
      proc.wait()
      kills += 1
    else:
      assert proc.returncode == 0, open(log + ".err").read()[-3000:]
      finished += 1
      assert finished <= 40, "the runs finish before their kills"
      if fresh:  # with the compilation cache warm, a whole run is faster than the first
        duration = min(duration, time.time() - t)
    for folder in outputs:
      check_artefacts(folder)
      if proc.returncode == 0:
        shutil.rmtree(folder)
  run_to_end(argv, env, str(tmp_path / "final"))
  return finished


@pytest.fixture(scope="module")
def demo_run(tmp_path_factory, inputs):
  out = str(tmp_path_factory.mktemp("demo") / "demo")
  run_to_end(["demo", "--out", out, *DEMO], inputs["env"], out + "-log")
  return out


@pytest.mark.slow
def test_kill_the_pipeline_20_times(inputs, tmp_path):
  out, clean = str(tmp_path / "demo"), str(tmp_path / "clean")
  duration = timed_run(["demo", "--out", clean, *DEMO], inputs["env"], str(tmp_path / "clean"))
  kill_20_times(["demo", "--out", out, *DEMO], inputs["env"], tmp_path, [out], 21, duration)
  killed, fresh = check_artefacts(out), check_artefacts(clean)
  assert killed == fresh
  for rel in fresh:  # the views, stylized images and grids are bit-identical
    if rel.endswith((".png", ".npy")):
      assert open(os.path.join(out, rel), "rb").read() == open(os.path.join(clean, rel),
                                                               "rb").read(), rel


@pytest.mark.slow
def test_kill_a_stylized_dataset_20_times(inputs, demo_run, tmp_path):
  styles = sorted(os.path.join(demo_run, "styles", n)
                  for n in os.listdir(os.path.join(demo_run, "styles")))
  argv = lambda out: ["stylize-scene", "--data", os.path.join(demo_run, "scene"), "--decoder",
                      os.path.join(demo_run, "adain"), "--styles", *styles,
                      "--include-original", "--out", out]
  out, clean = str(tmp_path / "stylized"), str(tmp_path / "clean")
  duration = timed_run(argv(clean), inputs["env"], str(tmp_path / "clean"))
  kill_20_times(argv(out), inputs["env"], tmp_path, [out], 22, duration)
  assert check_artefacts(out) == check_artefacts(clean)
  for rel in check_artefacts(clean):
    assert open(os.path.join(out, rel), "rb").read() == open(os.path.join(clean, rel),
                                                             "rb").read(), rel


@pytest.mark.slow
def test_kill_the_evaluation_20_times(inputs, demo_run, tmp_path):
  argv = lambda out: ["evaluate", "--run", os.path.join(demo_run, "multistyle"), "--frames",
                      "9", "--chunk", "256", "--out", out]
  out = str(tmp_path / "eval")
  duration = timed_run(argv(str(tmp_path / "clean")), inputs["env"], str(tmp_path / "clean"))
  kill_20_times(argv(out), inputs["env"], tmp_path, [out], 23, duration)
  assert {"results.md", "results.json", "frames.png"} <= set(check_artefacts(out))
