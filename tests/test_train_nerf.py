"""NeRF training: the step learns, pmap over 2 devices = 1 device, resume, NaN guard, load_run."""

import dataclasses
import os
import subprocess
import sys
import textwrap

import jax
import numpy as np
import pytest

import msnerf_jax
from msnerf_jax.core.config import DataConfig, NerfConfig, override
from msnerf_jax.data.scene import load_scene
from msnerf_jax.core.errors import UserError
from msnerf_jax.core.parallel import data_parallel
from msnerf_jax.train import nerf

TINY = override(NerfConfig(), net_depth=2, net_width=32, skip_layer=0, pos_freqs=4, dir_freqs=2,
                n_coarse=8, n_fine=8, batch_rays=64, steps=6, lr_init=5e-3, lr_final=5e-4,
                lr_decay_steps=100, precrop_steps=2, checkpoint_every=2, render_chunk=128,
                mlp_chunk=64)


def leaves(tree):
  return jax.tree_util.tree_leaves(tree)


def test_training_lowers_the_loss(tiny_blender, tmp_path):
  scene, data = load_scene(DataConfig(path=tiny_blender))
  config = override(TINY, steps=30, checkpoint_every=30, raw_noise_std=0.0)
  state = nerf.init_state(config)
  step = nerf.compile_train_step(config, True, data_parallel(1))
  import jax.numpy as jnp  # pylint: disable=g-import-not-at-top
  images, c2w, K = (jnp.asarray(scene.images[:4]), jnp.asarray(scene.c2w[:4]),
                    jnp.asarray(scene.K))
  shape = (scene.height, scene.width, scene.focal)
  fixed = nerf.sample_batch(jax.random.PRNGKey(0), images, c2w, K, config, False, False, shape,
                            2.0, 6.0)
  _, first = nerf.loss_fn(state.params, fixed, config, True)
  for i in range(30):
    state, _ = step(state, nerf.sample_batch(jax.random.PRNGKey(i), images, c2w, K, config,
                                             False, False, shape, 2.0, 6.0))
  _, last = nerf.loss_fn(state.params, fixed, config, True)
  assert float(last["loss"]) < 0.8 * float(first["loss"])


@pytest.mark.slow
def test_resume_gives_the_same_parameters_as_one_run(tiny_blender, tmp_path):
  scene, data = load_scene(DataConfig(path=tiny_blender))
  nerf.train(scene, TINY, data, str(tmp_path / "full"), progress=False)
  part = override(TINY, steps=4)
  nerf.train(scene, part, data, str(tmp_path / "split"), progress=False)
  summary = nerf.train(scene, TINY, data, str(tmp_path / "split"), progress=False)
  assert summary["resumed_from"] == 4
  full = msnerf_jax.load_run(str(tmp_path / "full"))
  split = msnerf_jax.load_run(str(tmp_path / "split"))
  assert full.step == split.step == 6
  assert isinstance(full.config, NerfConfig) and full.config == TINY
  assert set(full.params) == {"coarse", "fine"} and "trunk" in full.params["coarse"]
  for a, b in zip(leaves(full.params), leaves(split.params)):
    np.testing.assert_array_equal(a, b)  # bit-identical on CPU


def test_run_dir_of_another_config_is_refused_and_kept(tiny_blender, tmp_path):
  scene, data = load_scene(DataConfig(path=tiny_blender))
  run = str(tmp_path / "run")
  nerf.train(scene, override(TINY, steps=2), data, run, progress=False)
  before = sorted(os.listdir(os.path.join(run, "checkpoints")))
  with pytest.raises(UserError, match="another config.*net_width"):
    nerf.train(scene, dataclasses.replace(TINY, net_width=16), data, run, progress=False)
  assert sorted(os.listdir(os.path.join(run, "checkpoints"))) == before


def test_run_json_from_before_a_config_field_existed_resumes(tmp_path):
  from msnerf_jax.core import config as config_lib  # pylint: disable=g-import-not-at-top
  from msnerf_jax.kinds import runs
  import json  # pylint: disable=g-import-not-at-top
  run = str(tmp_path / "run")
  full = config_lib.to_dict(override(config_lib.MultistyleConfig(), steps=5))
  runs.prepare_run_dir(run, "multistyle", {"config": full})
  path = os.path.join(run, "run.json")
  record = json.load(open(path))
  for key in ("style_weight", "style_patch", "style_patches"):
    del record["config"][key]  # as written by a version without the patch style loss
  json.dump(record, open(path, "w"))
  assert runs.prepare_run_dir(run, "multistyle", {"config": full}) is True
  record = json.load(open(path))
  assert record["config"]["style_patch"] == 32  # rewritten in full
  del record["config"]["style_weight"]
  json.dump(record, open(path, "w"))
  other = dict(full, style_weight=0.5)  # a field the old run had at its default: refused
  with pytest.raises(UserError, match="another config.*style_weight: saved 0.0, now 0.5"):
    runs.prepare_run_dir(run, "multistyle", {"config": other})


def test_run_json_from_before_the_optimisation_block_resumes(tmp_path):
  """A run.json written when the optimisation settings sat at the top of each config (and of
  its NeRF's) reads as the nested `optim` block, and resumes; a changed setting in it is
  still refused."""
  from msnerf_jax.core import config as config_lib  # pylint: disable=g-import-not-at-top
  from msnerf_jax.kinds import runs
  import json  # pylint: disable=g-import-not-at-top
  config = override(config_lib.MultistyleConfig(nerf=TINY), steps=5, lr_init=2e-3, seed=3)
  flat = config_lib.to_dict(config)
  for block in (flat, flat["nerf"]):
    block.update(block.pop("optim"))
  assert "steps" in flat and "optim" not in flat["nerf"]
  assert config_lib.from_dict(config_lib.MultistyleConfig, flat) == config
  run = str(tmp_path / "run")
  os.makedirs(run)
  with open(os.path.join(run, "run.json"), "w") as f:
    json.dump({"kind": "multistyle", "config": flat}, f)
  assert runs.prepare_run_dir(run, "multistyle", {"config": config_lib.to_dict(config)})
  assert json.load(open(os.path.join(run, "run.json")))["config"]["optim"]["seed"] == 3
  with pytest.raises(UserError, match=r"another config.*optim\.lr_init: saved 0.002, now 0.004"):
    runs.prepare_run_dir(run, "multistyle",
                         {"config": config_lib.to_dict(override(config, lr_init=4e-3))})


def test_nan_loss_stops_with_the_step_and_keeps_checkpoint(tiny_blender, tmp_path):
  scene, data = load_scene(DataConfig(path=tiny_blender))
  run = str(tmp_path / "run")
  nerf.train(scene, override(TINY, steps=2), data, run, progress=False)
  bad = dataclasses.replace(scene, images=np.full_like(scene.images, np.nan))
  with pytest.raises(UserError, match=r"loss became nan at step 3.*step 2"):
    nerf.train(bad, TINY, data, run, progress=False)
  assert msnerf_jax.load_run(run).step == 2


TWO_DEVICES = textwrap.dedent("""
    import os, sys
    os.environ["XLA_FLAGS"] = (os.environ.get("XLA_FLAGS", "")
                               + " --xla_force_host_platform_device_count=2")
    import jax, numpy as np
    from msnerf_jax.core.config import DataConfig
    from msnerf_jax.data.scene import load_scene
    from msnerf_jax.core.parallel import data_parallel
    from msnerf_jax.train import nerf
    sys.path.insert(0, {tests!r})
    from test_train_nerf import TINY
    import dataclasses
    config = dataclasses.replace(TINY, raw_noise_std=0.5, random_background=True,
                                 distortion_weight=0.01)  # randomness of every kind
    assert jax.local_device_count() == 2
    scene, _ = load_scene(DataConfig(path={scene!r}))
    import jax.numpy as jnp
    batch = nerf.sample_batch(jax.random.PRNGKey(7), jnp.asarray(scene.images), jnp.asarray(scene.c2w),
                              jnp.asarray(scene.K), config, False, False,
                              (scene.height, scene.width, scene.focal), 2.0, 6.0,
                              jnp.asarray(scene.alphas))
    assert "background" in batch
    state = nerf.init_state(config)
    one, s1 = nerf.compile_train_step(config, True, data_parallel(1))(nerf.init_state(config),
                                                                     batch)
    twos = dict()
    for mode in ("shard_map", "pmap"):
      dp = data_parallel(2, mode)
      out, s2 = nerf.compile_train_step(config, True, dp)(dp.put_state(nerf.init_state(config)),
                                                          dp.put_batch(batch))
      twos[mode] = dp.to_host((out, s2))
    two, s2 = twos["shard_map"]
    # shard_map and pmap run the same per-device program and the same two-way mean; XLA
    # compiles the two separately, which may round a few values differently (1 ulp seen).
    for a, b in zip(jax.tree_util.tree_leaves(twos["pmap"]),
                    jax.tree_util.tree_leaves(twos["shard_map"])):
      assert np.allclose(a, b, rtol=1e-6, atol=1e-7), np.max(np.abs(a - b))
    worst = max(float(np.max(np.abs(np.asarray(a) - np.asarray(b))))
                for a, b in zip(jax.tree_util.tree_leaves(one.params), jax.tree_util.tree_leaves(two.params)))
    moved = max(float(np.max(np.abs(np.asarray(a) - np.asarray(b))))
                for a, b in zip(jax.tree_util.tree_leaves(one.params), jax.tree_util.tree_leaves(state.params)))
    print("worst", worst, "moved", moved, "loss", float(s1["loss"]), float(s2["loss"]))
    assert moved > 1e-4, moved
    assert worst < 1e-3 * moved, (worst, moved)  # summation order only
    assert abs(float(s1["loss"]) - float(s2["loss"])) < 1e-6
""")


@pytest.mark.slow  # 61 s, three compilations; the default suite's multi-device check is
# test_distributed.py's (two processes of one device = one process of two devices)
def test_two_devices_give_the_same_update_as_one(tiny_blender):
  tests = os.path.dirname(os.path.abspath(__file__))
  code = TWO_DEVICES.format(tests=tests, scene=tiny_blender)
  result = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                          timeout=600)
  assert result.returncode == 0, result.stdout + result.stderr[-3000:]
  assert "worst" in result.stdout
