"""Shared fixtures: the real data folder (MSNERF_DATA) and small synthetic scenes; XLA's
compile settings for the whole run."""

import json
import os
import shutil
import tempfile
import time

import numpy as np
import pytest
from PIL import Image

REPO = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
DATA = os.environ.get("MSNERF_DATA", os.path.join(REPO, "..", "shared", "data"))


# Tests run tiny models: their time is XLA compiling, not running. LLVM's lowest optimisation
# level compiles about 2x faster and, for these sizes, runs no slower (the demo's tiny end to
# end run: 121 s -> 69 s; the distortion, shift-loss and bake tests: 147 s -> 110 s, on the
# 2-core CI box). Set before anything imports JAX; the processes the tests start inherit it
# (those that add devices append to it), so what a test compares was compiled the same way.
os.environ["XLA_FLAGS"] = " ".join(
    [os.environ.get("XLA_FLAGS", ""), "--xla_backend_optimization_level=0"]).strip()
# And many tests compile the same programs (the tiny NeRF, heads and decoder steps of several
# files, the command line's renders): one persistent compilation cache for the run, shared
# by both workers and every process they start, in a folder of its own (each run compiles
# what it tests; folders of runs over an hour old are removed).
if "JAX_COMPILATION_CACHE_DIR" not in os.environ:
  _CACHES = os.path.join(tempfile.gettempdir(), "msnerf-test-jax-cache")
  os.makedirs(_CACHES, exist_ok=True)
  for _old in os.listdir(_CACHES):
    if time.time() - os.path.getmtime(os.path.join(_CACHES, _old)) > 3600:
      shutil.rmtree(os.path.join(_CACHES, _old), ignore_errors=True)
  os.environ["JAX_COMPILATION_CACHE_DIR"] = os.path.join(_CACHES, f"run-{os.getpid()}")
  os.environ["JAX_PERSISTENT_CACHE_MIN_COMPILE_TIME_SECS"] = "0.3"


def data_path(*parts):
  path = os.path.join(DATA, *parts)
  if not os.path.exists(path):
    pytest.skip(f"{path} not available (set MSNERF_DATA)")
  return path


@pytest.fixture
def lego():
  return data_path("nerf_synthetic", "lego")


@pytest.fixture
def fern():
  return data_path("nerf_llff_data", "fern")


def write_blender_scene(folder, n_train=4, n_val=2, size=16, rng=None):
  """A tiny valid Blender-format scene of RGBA PNGs with cameras on a circle."""
  from msnerf_jax.data.blender import pose_spherical  # pylint: disable=g-import-not-at-top
  rng = rng or np.random.default_rng(0)
  os.makedirs(folder, exist_ok=True)
  for split, n in (("train", n_train), ("val", n_val)):
    os.makedirs(os.path.join(folder, split), exist_ok=True)
    frames = []
    for i in range(n):
      rgba = (rng.random((size, size, 4)) * 255).astype(np.uint8)
      Image.fromarray(rgba, "RGBA").save(os.path.join(folder, split, f"r_{i}.png"))
      pose = pose_spherical(360.0 * i / n + (7 if split == "val" else 0), -30.0, 4.0)
      frames.append({"file_path": f"./{split}/r_{i}", "transform_matrix": pose.tolist()})
    with open(os.path.join(folder, f"transforms_{split}.json"), "w") as f:
      json.dump({"camera_angle_x": 0.69, "frames": frames}, f)
  return folder


@pytest.fixture
def tiny_blender(tmp_path):
  return write_blender_scene(str(tmp_path / "scene"))


def fake_decoder(path):
  """An AdaIN run folder with an untrained decoder: enough to exercise the plumbing."""
  # pylint: disable=g-import-not-at-top
  import jax
  from msnerf_jax.core import checkpoint
  from msnerf_jax.core import config as config_lib
  from msnerf_jax.kinds import runs
  from msnerf_jax.models import decoder
  runs.prepare_run_dir(str(path), "adain",
                             {"config": config_lib.to_dict(config_lib.AdainConfig())})
  ckpts = checkpoint.Checkpoints(str(path))
  ckpts.save(1, {"params": decoder.init_decoder(jax.random.PRNGKey(0)), "step": np.asarray(1)})
  ckpts.close()
  return str(path)


def untrained_nerf_run(run_dir, data, config, step=2):
  """A NeRF run folder as `nerf train` leaves it, with untrained params (no step compiled)."""
  # pylint: disable=g-import-not-at-top
  from msnerf_jax.core import checkpoint
  from msnerf_jax.core import config as config_lib
  from msnerf_jax.kinds import runs
  from msnerf_jax.train import nerf
  from msnerf_jax.train import state as state_lib
  runs.prepare_run_dir(run_dir, "nerf", {"config": config_lib.to_dict(config),
                                               "data": config_lib.to_dict(data)})
  ckpts = checkpoint.Checkpoints(run_dir)
  ckpts.save(step, state_lib.checkpoint_tree(nerf.init_state(config)))
  ckpts.close()
  return run_dir


def trainer_env(request, fallback_cache_dir, **extra):
  """The environment of `python -m msnerf_jax` subprocesses in tests: CPU JAX with a
  persistent compilation cache (pytest's cache folder, else `fallback_cache_dir`)."""
  cache = getattr(request.config, "cache", None)
  cache_dir = str(cache.mkdir("jax-compilation-cache")) if cache is not None else str(
      fallback_cache_dir)
  return dict(os.environ, JAX_PLATFORMS="cpu", JAX_COMPILATION_CACHE_DIR=cache_dir,
              JAX_PERSISTENT_CACHE_MIN_COMPILE_TIME_SECS="0",
              JAX_PERSISTENT_CACHE_MIN_ENTRY_SIZE_BYTES="0", **extra)


def flat_params(run):
  """[(key path, array)] of a run folder's parameters, to compare two runs bit for bit."""
  # pylint: disable=g-import-not-at-top
  import jax
  import msnerf_jax
  return [(jax.tree_util.keystr(p), np.asarray(v))
          for p, v in jax.tree_util.tree_leaves_with_path(msnerf_jax.load_run(run).params)]
