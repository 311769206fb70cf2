"""Several processes: two processes of one CPU device each (jax.distributed on 127.0.0.1,
gloo collectives) train exactly like one process of two devices, for the NeRF and the
multi-style trainer; a killed pair resumes; rendering splits over processes; bad process
settings end with one line and exit code 2."""

import os
import signal
import socket
import subprocess
import sys
import textwrap
import time

import numpy as np
import pytest

from conftest import flat_params
from test_kill import complete_checkpoints, start, trainer_inputs

TESTS = os.path.dirname(os.path.abspath(__file__))


def free_port():
  with socket.socket() as s:
    s.bind(("127.0.0.1", 0))
    return s.getsockname()[1]


@pytest.fixture(scope="module")
def inputs(tmp_path_factory, request):
  return trainer_inputs(tmp_path_factory.mktemp("dist"), request)


def command(trainer, inputs, out, steps, every):
  if trainer == "nerf":
    argv = ["nerf", "train", "--data", inputs["scene"], "--preset", "cpu", "--batch-rays", "64",
            "--net-depth", "2",
            "--net-width", "32", "--n-coarse", "8", "--n-fine", "8"]
  else:
    argv = ["multistyle", "train", "--nerf", inputs["nerf"], "--stylized", inputs["stylized"],
            "--batch-rays", "16"]
  return argv + ["--out", out, "--steps", str(steps), "--checkpoint-every", str(every)]


def env_with(inputs, devices):
  return dict(inputs["env"], XLA_FLAGS=os.environ.get("XLA_FLAGS", "")
              + f" --xla_force_host_platform_device_count={devices}")


def start_processes(argvs, env, log, timeout=60):
  """One process per argv, each with --coordinator on a free port and its --process-id."""
  port = free_port()
  return [start([*argv, "--coordinator", f"127.0.0.1:{port}", "--num-processes",
                 str(len(argvs)), "--process-id", str(i), "--coordinator-timeout",
                 str(timeout)], env, f"{log}{i}") for i, argv in enumerate(argvs)]


def wait_all(procs, timeout=300):
  codes = []
  deadline = time.time() + timeout
  for proc in procs:
    try:
      codes.append(proc.wait(timeout=max(1, deadline - time.time())))
    except subprocess.TimeoutExpired:
      for p in procs:
        os.killpg(p.pid, signal.SIGKILL)
      raise
  return codes


def err(log):
  with open(log + ".err", errors="replace") as f:
    return f.read()


def reference(trainer, inputs, steps, every):
  """The same run by one process with two devices (cached per trainer and length)."""
  run = str(inputs["root"] / f"ref_{trainer}_{steps}")
  if not os.path.exists(os.path.join(run, "checkpoints", str(steps))):
    log = str(inputs["root"] / f"ref_{trainer}_{steps}")
    code = wait_all([start(command(trainer, inputs, run, steps, every), env_with(inputs, 2),
                           log)])[0]
    assert code == 0, err(log)[-3000:]
  return run


def assert_same_params(run, ref):
  a, b = flat_params(run), flat_params(ref)
  assert [k for k, _ in a] == [k for k, _ in b]
  for (key, x), (_, y) in zip(a, b):
    assert np.array_equal(x, y), (key, float(np.max(np.abs(x - y))))


# The multi-style pair (about 40 s) is slow: it runs the same loop and process machinery as
# the NeRF's, which stays in the default suite (10 min).
@pytest.mark.parametrize("trainer", ["nerf", pytest.param("multistyle", marks=pytest.mark.slow)])
def test_two_processes_train_exactly_like_one_process_of_two_devices(trainer, inputs, tmp_path):
  ref = reference(trainer, inputs, 6, 3)
  run = str(tmp_path / "run")
  log = str(tmp_path / "p")
  argv = command(trainer, inputs, run, 6, 3)
  codes = wait_all(start_processes([argv, argv], env_with(inputs, 1), log))
  assert codes == [0, 0], err(log + "0")[-2000:] + err(log + "1")[-2000:]
  # Two devices in one process and one device in each of two processes: the same mean of
  # two per-device gradients (a sum of two numbers has one order), so bit for bit.
  assert_same_params(run, ref)
  assert sorted(os.listdir(os.path.join(run, "checkpoints"))) == ["3", "6"]
  # Process 0 alone shows progress and writes history; both end cleanly.
  assert "train:" in err(log + "0") and "train:" not in err(log + "1")
  with open(os.path.join(run, "history.jsonl")) as f:
    assert [line.count('"step"') for line in f] == [1]  # written once, not per process
  assert "device(s) of 2 processes" in open(log + "0.out").read()
  assert not os.path.exists(os.path.join(run, "trainer.lock"))


@pytest.mark.slow  # a minute; the two-process equality tests stay in the default suite
def test_a_killed_pair_resumes_from_the_last_checkpoint(inputs, tmp_path):
  steps, every = 300, 50
  ref = reference("nerf", inputs, steps, every)
  run = str(tmp_path / "run")
  argv = command("nerf", inputs, run, steps, every)
  env = env_with(inputs, 1)
  procs = start_processes([argv, argv], env, str(tmp_path / "first"))
  deadline = time.time() + 120
  while not os.path.isdir(os.path.join(run, "checkpoints", str(every))):
    assert time.time() < deadline and all(p.poll() is None for p in procs), \
        err(str(tmp_path / "first0"))[-2000:]
    time.sleep(0.01)
  os.killpg(procs[1].pid, signal.SIGKILL)  # one process dies; its partner cannot go on
  os.killpg(procs[0].pid, signal.SIGKILL)
  for p in procs:
    p.wait()
  saved = complete_checkpoints(run)
  assert saved and saved[-1] < steps, saved  # killed mid-run
  log = str(tmp_path / "again")
  codes = wait_all(start_processes([argv, argv], env, log))
  assert codes == [0, 0], err(log + "0")[-2000:] + err(log + "1")[-2000:]
  assert f"resumed from {saved[-1]}" in open(log + "0.out").read()
  assert_same_params(run, ref)


RENDER = textwrap.dedent("""
    import sys
    import numpy as np
    from msnerf_jax.core import distributed
    from msnerf_jax.core import parallel
    from msnerf_jax.kinds import runs
    from msnerf_jax.kinds.views import render_view
    port, pid, out = sys.argv[1], int(sys.argv[2]), sys.argv[3]
    distributed.initialize("127.0.0.1:" + port, 2, pid, timeout=60)
    run, scene = runs.load_run_and_scene({run!r}, "nerf")
    image = render_view(scene, run.params, run.config, 0, chunk=96, mesh=parallel.data_mesh())
    np.save(out, image["rgb"])
    single = render_view(scene, run.params, run.config, 0, chunk=192,
                         mesh=parallel.local_mesh())
    assert np.array_equal(image["rgb"], single["rgb"]), np.abs(image["rgb"] - single["rgb"]).max()
""")


def test_rendering_splits_over_processes_and_equals_one_device(inputs, tmp_path):
  """Two processes render one view together (96 rays each per call, 16x16 pixels: a padded
  last call); each gets the whole image, equal to its own one-device render."""
  port = free_port()
  code = RENDER.format(run=inputs["nerf"])
  procs = [subprocess.Popen([sys.executable, "-c", code, str(port), str(i),
                             str(tmp_path / f"{i}.npy")], env=env_with(inputs, 1),
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
           for i in range(2)]
  for p in procs:
    out, errors = p.communicate(timeout=300)
    assert p.returncode == 0, errors[-3000:]
  a, b = np.load(tmp_path / "0.npy"), np.load(tmp_path / "1.npy")
  assert a.shape == (16, 16, 3) and np.array_equal(a, b) and a.std() > 0


def one_line_error(log, *needles):
  text = err(log).strip().splitlines()
  assert len(text) == 1 and text[0].startswith("msnerf: error: "), text[-20:]
  for needle in needles:
    assert needle in text[0], text[0]


def test_bad_process_settings_end_with_one_line(inputs, tmp_path):
  """Settings refused before the processes meet: ids out of range, counts, an address."""
  env = env_with(inputs, 1)
  run = str(tmp_path / "run")
  argv = command("nerf", inputs, run, 2, 1)
  # Ids out of range, a count of 0, an id without a count, a malformed address.
  for extra, needle in [(["--num-processes", "2", "--process-id", "2"], "out of range 0..1"),
                        (["--num-processes", "0", "--process-id", "0"], "at least 1"),
                        (["--process-id", "0"], "--num-processes and --process-id")]:
    log = str(tmp_path / "range")
    coordinator = ["--coordinator", "127.0.0.1:1"] if "--num-processes" in extra else []
    assert wait_all([start([*argv, *coordinator, *extra], env, log)], 60) == [2]
    one_line_error(log, needle)
  log = str(tmp_path / "address")
  assert wait_all([start([*argv, "--coordinator", "localhost", "--num-processes", "2",
                          "--process-id", "0"], env, log)], 60) == [2]
  one_line_error(log, "expected HOST:PORT")
  assert not os.path.exists(run)


@pytest.mark.slow  # 25 s of processes waiting for each other; the settings above stay
def test_processes_that_cannot_meet_or_agree_end_with_one_line(inputs, tmp_path):
  """A coordinator nobody listens on, a process alone, two of one id, settings that differ,
  pmap across processes: every process stops with one line, nothing is written."""
  env = env_with(inputs, 1)
  run = str(tmp_path / "run")
  argv = command("nerf", inputs, run, 2, 1)
  port = free_port()
  # A coordinator nobody listens on: process 1 gives up after the timeout.
  log = str(tmp_path / "unreachable")
  proc = start([*argv, "--coordinator", f"127.0.0.1:{port}", "--num-processes", "2",
                "--process-id", "1", "--coordinator-timeout", "2"], env, log)
  assert wait_all([proc], 60) == [2]
  one_line_error(log, f"127.0.0.1:{port}", "could not be reached within 2 s")
  # Process 0 alone: process 1 never joins.
  log = str(tmp_path / "alone")
  proc = start([*argv, "--coordinator", f"127.0.0.1:{port}", "--num-processes", "2",
                "--process-id", "0", "--coordinator-timeout", "2"], env, log)
  assert wait_all([proc], 60) == [2]
  one_line_error(log, "process 1 of 2 did not join within 2 s")
  # Twice the same id.
  log = str(tmp_path / "twice")
  port = free_port()
  procs = [start([*argv, "--coordinator", f"127.0.0.1:{port}", "--num-processes", "3",
                  "--process-id", str(pid), "--coordinator-timeout", "30"], env, f"{log}{i}")
           for i, pid in enumerate((0, 1, 1))]
  assert wait_all(procs, 120) == [2, 2, 2]
  for i in range(3):
    one_line_error(f"{log}{i}", "two processes were started with --process-id 1")
  # Settings that differ between the processes: every process stops, nothing is written.
  log = str(tmp_path / "differ")
  other = command("nerf", inputs, run, 2, 1) + ["--seed", "5"]
  assert wait_all(start_processes([argv, other], env, log)) == [2, 2]
  one_line_error(log + "0", "settings of process 1 differ from process 0's")
  one_line_error(log + "1", "settings of process 1 differ from process 0's")
  assert not os.path.exists(run)
  # --parallel pmap is one process's.
  log = str(tmp_path / "pmap")
  assert wait_all(start_processes([argv + ["--parallel", "pmap"]] * 2, env, log)) == [2, 2]
  one_line_error(log + "1", "--parallel pmap runs within one process")
  assert not os.path.exists(run)


def test_device_counts_and_modes_that_cannot_work_are_one_line(tiny_blender, tmp_path, capsys):
  from msnerf_jax import cli  # pylint: disable=g-import-not-at-top
  from msnerf_jax.core import parallel  # pylint: disable=g-import-not-at-top
  from msnerf_jax.core.errors import UserError  # pylint: disable=g-import-not-at-top
  import jax  # pylint: disable=g-import-not-at-top
  have = jax.local_device_count()
  with pytest.raises(UserError, match=f"{have + 1} devices asked for; this machine has {have}"):
    parallel.data_parallel(have + 1)
  with pytest.raises(UserError, match="parallel mode 'vmap'"):
    parallel.data_parallel(1, "vmap")
  run = tmp_path / "run"
  assert cli.main(["nerf", "train", "--data", tiny_blender, "--out", str(run), "--steps", "1",
                   "--devices", str(have + 1)]) == 2
  err_lines = capsys.readouterr().err.strip().splitlines()
  assert err_lines == [f"msnerf: error: {have + 1} devices asked for; this machine has "
                       f"{have} (cpu)"]
  assert not run.exists()
