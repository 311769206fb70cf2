"""One trainer per run folder (msnerf_jax.core.run_lock): a second trainer is refused with one line
naming the running one and writes nothing; the lock of a process that is gone is taken over."""

import json
import os
import socket
import subprocess
import sys

import pytest

from msnerf_jax import cli
from msnerf_jax.core import config as config_lib
from msnerf_jax.core import run_lock
from msnerf_jax.kinds import runs

from conftest import write_blender_scene

RECORD = {"config": config_lib.to_dict(config_lib.NerfConfig())}


@pytest.fixture
def sleeper():
  """A live process of this host (not this one)."""
  proc = subprocess.Popen([sys.executable, "-c", "import time; time.sleep(60)"])
  yield proc
  proc.kill()
  proc.wait()


def _write_lock(run_dir, **holder):
  with open(os.path.join(run_dir, run_lock.LOCK_FILE), "w") as f:
    json.dump({"host": socket.gethostname(), "since": "2026-12-02 04:00:00",
               "command": "msnerf nerf train --out x", **holder}, f)


def _snapshot(folder):
  return {name: (os.stat(os.path.join(folder, name)).st_mtime_ns,
                 open(os.path.join(folder, name), "rb").read())
          for name in sorted(os.listdir(folder)) if os.path.isfile(os.path.join(folder, name))}


def test_second_trainer_is_refused_naming_the_first_and_writes_nothing(tmp_path, sleeper,
                                                                        capsys):
  scene = write_blender_scene(str(tmp_path / "scene"), n_train=2, n_val=1, size=8)
  run = str(tmp_path / "run")
  argv = ["nerf", "train", "--data", scene, "--out", run, "--preset", "cpu", "--steps", "2"]
  # A new run folder whose trainer (the live pid of `sleeper`) has just taken the lock.
  os.makedirs(run)
  _write_lock(run, pid=sleeper.pid, start=run_lock._start_ticks(sleeper.pid))
  before = _snapshot(run)
  capsys.readouterr()
  assert cli.main(argv) == 2
  err = capsys.readouterr().err.strip()
  assert len(err.splitlines()) == 1, err
  assert f"process {sleeper.pid}" in err and "another trainer is running" in err, err
  assert "msnerf nerf train --out x" in err
  assert _snapshot(run) == before  # nothing written, the lock untouched


def test_lock_is_taken_again_released_and_reentrant(tmp_path):
  run = str(tmp_path / "run")
  assert not runs.prepare_run_dir(run, "nerf", RECORD, lock=True)
  lock = os.path.join(run, run_lock.LOCK_FILE)
  holder = json.load(open(lock))
  assert holder["pid"] == os.getpid() and holder["host"] == socket.gethostname()
  assert runs.prepare_run_dir(run, "nerf", RECORD, lock=True)  # the same process: fine
  run_lock.release(run)
  assert not os.path.exists(lock)
  assert sorted(os.listdir(run)) == [runs.RUN_FILE]  # no private file left behind


@pytest.mark.parametrize("case", ["exited", "pid reused", "unreadable"])
def test_stale_lock_of_a_process_that_is_gone_is_taken_over(tmp_path, sleeper, case):
  run = str(tmp_path / "run")
  runs.prepare_run_dir(run, "nerf", RECORD)
  if case == "exited":
    gone = subprocess.Popen([sys.executable, "-c", "pass"])
    gone.wait()
    _write_lock(run, pid=gone.pid, start=1)
  elif case == "pid reused":  # a live pid, but started after the lock was written
    _write_lock(run, pid=sleeper.pid, start=run_lock._start_ticks(sleeper.pid) - 1)
  else:
    open(os.path.join(run, run_lock.LOCK_FILE), "w").write("{half")
  try:
    runs.prepare_run_dir(run, "nerf", RECORD, lock=True)
    assert json.load(open(os.path.join(run, run_lock.LOCK_FILE)))["pid"] == os.getpid()
  finally:
    run_lock.release(run)


def test_lock_of_another_host_is_respected_with_a_hint(tmp_path):
  run = str(tmp_path / "run")
  runs.prepare_run_dir(run, "nerf", RECORD)
  _write_lock(run, pid=1234, host="another-node")
  with pytest.raises(Exception) as error:
    runs.prepare_run_dir(run, "nerf", RECORD, lock=True)
  assert "another-node" in str(error.value) and run_lock.LOCK_FILE in str(error.value)


def test_trainers_release_the_lock_when_they_fail(tmp_path):
  """A trainer that stops with an error after taking the lock leaves no lock behind."""
  import dataclasses  # pylint: disable=g-import-not-at-top
  from msnerf_jax.data.scene import load_scene  # pylint: disable=g-import-not-at-top
  from msnerf_jax.core.errors import UserError  # pylint: disable=g-import-not-at-top
  from msnerf_jax.train import nerf  # pylint: disable=g-import-not-at-top
  scene_dir = write_blender_scene(str(tmp_path / "scene"), n_train=2, n_val=1, size=8)
  scene, data = load_scene(config_lib.DataConfig(path=scene_dir))
  no_training_views = dataclasses.replace(scene, splits={"val": scene.splits["val"]})
  run = str(tmp_path / "run")
  with pytest.raises(UserError, match="no 'train' split"):
    nerf.train(no_training_views, config_lib.NerfConfig(net_depth=2, net_width=16), data, run,
               n_devices=1, progress=False)
  assert os.path.exists(os.path.join(run, runs.RUN_FILE))  # it got past the lock
  assert not os.path.exists(os.path.join(run, run_lock.LOCK_FILE))
