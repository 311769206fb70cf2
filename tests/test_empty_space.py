"""Empty space stays empty: random training backgrounds, the distortion loss, the opacity check."""

import dataclasses
import json
import os

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from PIL import Image

import msnerf_jax
from msnerf_jax.core import config as config_lib
from msnerf_jax.pipeline import demo
from msnerf_jax.eval import evaluate
from msnerf_jax.eval import metrics
from msnerf_jax.nerf import occupancy
from msnerf_jax.nerf import regularizers
from msnerf_jax.nerf import render as render_lib
from msnerf_jax.core.config import DataConfig, override
from msnerf_jax.data.scene import load_scene
from msnerf_jax.core.errors import UserError
from msnerf_jax.models.nerf import NerfField
from msnerf_jax.train import nerf
from test_cli_nerf import assert_one_line_error, msnerf
from test_train_nerf import TINY, leaves


def brute_distortion(w, z, near, far):
  s = np.clip((z - near) / (far - near), 0, 1)
  edges = np.append(s, 1.0)
  m = 0.5 * (edges[1:] + edges[:-1])
  inter = sum(w[i] * w[j] * abs(m[i] - m[j]) for i in range(len(w)) for j in range(len(w)))
  return inter + np.sum(w ** 2 * np.diff(edges)) / 3


def test_distortion_equals_the_double_sum():
  rng = np.random.default_rng(0)
  z = np.sort(rng.uniform(2, 6, (5, 12)), -1)
  w = rng.random((5, 12)) / 12
  got = regularizers.distortion(jnp.asarray(w), jnp.asarray(z), jnp.full(5, 2.0),
                                jnp.full(5, 6.0))
  want = [brute_distortion(w[r], z[r], 2.0, 6.0) for r in range(5)]
  np.testing.assert_allclose(np.asarray(got), want, rtol=1e-5)


def test_distortion_prefers_one_surface_to_fog():
  z = jnp.linspace(0.0, 1.0, 32)[None]
  surface = jnp.zeros((1, 32)).at[0, 20].set(1.0)
  fog = jnp.full((1, 32), 1.0 / 32)
  ones = jnp.ones(1)
  low = regularizers.distortion(surface, z, 0 * ones, ones)
  high = regularizers.distortion(fog, z, 0 * ones, ones)
  assert float(low[0]) < 0.1 * float(high[0])
  grad = jax.grad(lambda w: regularizers.distortion(w, z, 0 * ones, ones).sum())(fog)
  assert np.all(np.isfinite(np.asarray(grad)))


def _rays(n, near, far, seed=0):
  rng = np.random.default_rng(seed)
  origins = rng.uniform(-0.2, 0.2, (n, 3)) + np.array([0.0, 0.0, -3.0])
  directions = np.array([0.0, 0.0, 1.0]) + rng.uniform(-0.1, 0.1, (n, 3))
  return {"origins": jnp.asarray(origins, jnp.float32),
          "directions": jnp.asarray(directions, jnp.float32),
          "near": jnp.asarray(near, jnp.float32), "far": jnp.asarray(far, jnp.float32)}


def test_packed_distortion_of_every_step_equals_the_dense_loss():
  """With every cell occupied, march's steps tile each ray's [near, far] (inside the box),
  and the packed loss equals `distortion` of the same intervals ray by ray."""
  config = dataclasses.replace(config_lib.NerfConfig(), scene_box=10.0, march_steps=24)
  n, steps = 5, config.march_steps
  rays = _rays(n, np.linspace(0.5, 1.5, n), np.linspace(4.0, 6.0, n))
  samples = occupancy.march(rays, jnp.ones((4, 4, 4), bool), config, n * steps + 7,
                            u=jnp.full((n,), 0.3))
  assert bool(jnp.all(samples["complete"])) and int(jnp.sum(samples["valid"])) == n * steps
  weights = jnp.where(samples["valid"], jax.random.uniform(jax.random.PRNGKey(0),
                                                           samples["valid"].shape) / steps, 0.0)
  got = regularizers.distortion_packed(weights, samples["interval"], samples["ray"],
                                       rays["near"], rays["far"])
  lo = samples["interval"][: n * steps, 0].reshape(n, steps)  # each step's start: z_i.
  want = regularizers.distortion(weights[: n * steps].reshape(n, steps), lo, rays["near"],
                                 rays["far"])
  np.testing.assert_allclose(np.asarray(got), np.asarray(want), rtol=1e-5, atol=1e-7)


def test_packed_distortion_with_empty_cells_equals_the_double_sum():
  """Steps in empty cells are missing from the pack: the loss is the double sum over the
  steps that are there, each standing for its own interval (the gaps weigh nothing)."""
  config = dataclasses.replace(config_lib.NerfConfig(), scene_box=1.0, march_steps=40,
                               grid_resolution=8)
  n = 6
  rays = _rays(n, np.full(n, 2.0), np.full(n, 4.0), seed=1)
  grid = np.zeros((8, 8, 8), bool)
  grid[:, :, 1:3] = grid[:, :, 5:7] = True  # two slabs across the rays' path along z.
  samples = jax.tree_util.tree_map(np.asarray, occupancy.march(rays, jnp.asarray(grid), config,
                                                               n * 40))
  rng = np.random.default_rng(2)
  weights = np.where(samples["valid"], rng.random(samples["valid"].shape) / 10, 0.0)
  got = np.asarray(regularizers.distortion_packed(
      jnp.asarray(weights, jnp.float32), jnp.asarray(samples["interval"]),
      jnp.asarray(samples["ray"]), rays["near"], rays["far"]))
  for r in range(n):
    mine = samples["ray"] == r
    assert 2 <= mine.sum() < 40  # the ray crosses both slabs and skips the space between.
    s = (samples["interval"][mine] - 2.0) / 2.0
    m, width, w = s.mean(1), s[:, 1] - s[:, 0], weights[mine]
    want = np.sum(w[:, None] * w[None] * np.abs(m[:, None] - m[None])) + np.sum(w ** 2 * width) / 3
    np.testing.assert_allclose(got[r], want, rtol=1e-5)


@pytest.mark.slow  # 36 s; the packed loss's values and gradients stay in the default suite
def test_distortion_trains_with_the_grid_sampler(tiny_blender):
  """The fast preset accepts the distortion loss: it is in the step's stats, finite, and
  training with it leaves a fixed batch's weights less spread than training without it."""
  from test_fast_trunk import TINY_FAST  # pylint: disable=g-import-not-at-top
  scene, _ = load_scene(DataConfig(path=tiny_blender))
  base = dataclasses.replace(TINY_FAST, random_background=False)
  batch = _batch(scene, jax.random.PRNGKey(5), base, None)

  def spread(params):
    out = render_lib.render_rays(NerfField(base), params, batch["rays"],
                                 base, batch["random"], True)
    return float(nerf.distortion_loss(out, batch["rays"]))

  final = {}
  for weight in (0.0, 1.0):
    config = dataclasses.replace(base, distortion_weight=weight)
    config.validate()
    state = nerf.init_state(config)
    step = jax.jit(nerf.train_step, static_argnums=(2, 3))
    for _ in range(20):
      state, stats = step(state, batch, config, True)
    assert ("distortion" in stats) == (weight > 0)
    final[weight] = spread(state.params)
  assert np.isfinite(final[1.0]) and final[1.0] > 0
  assert final[1.0] < 0.7 * final[0.0], final


def test_mask_opacity_splits_by_ground_truth_alpha():
  alpha = np.array([[0, 0], [128, 255]], np.uint8)
  acc = np.array([[0.1, 0.3], [0.5, 0.9]])
  assert metrics.mask_opacity(acc, alpha) == pytest.approx({"background": 0.2, "object": 0.9})
  assert np.isnan(metrics.mask_opacity(acc, np.full((2, 2), 255, np.uint8))["background"])


def _batch(scene, key, config, alphas):
  return nerf.sample_batch(key, jnp.asarray(scene.images), jnp.asarray(scene.c2w),
                           jnp.asarray(scene.K), config, False, False,
                           (scene.height, scene.width, scene.focal), 2.0, 6.0, alphas)


def test_random_background_target_is_the_photo_over_that_colour(tiny_blender):
  scene, _ = load_scene(DataConfig(path=tiny_blender))
  config = dataclasses.replace(TINY, batch_rays=256, raw_noise_std=0.5)
  key = jax.random.PRNGKey(3)
  plain = _batch(scene, key, config, None)
  rand = _batch(scene, key, config, jnp.asarray(scene.alphas))
  # The other draws are those of a batch without backgrounds.
  for a, b in zip(leaves((plain["rays"], plain["random"])), leaves((rand["rays"], rand["random"]))):
    np.testing.assert_array_equal(a, b)
  bg = np.asarray(rand["background"])
  assert bg.shape == (256, 3) and 0 <= bg.min() and bg.max() <= 1 and bg.std() > 0.2
  # Recompute each target from the RGBA file: straight colour over the random colour.
  rgba = np.stack([np.asarray(Image.open(p), np.float32) / 255 for p in scene.image_paths])
  rgb, a = rgba[..., :3], rgba[..., 3:]
  want_white = rgb * a + (1 - a)
  for b in range(0, 256, 17):  # find each ray's pixel by its target over white
    match = np.argwhere(np.all(np.abs(want_white - np.asarray(plain["rgb"][b])) < 1e-6, -1))
    n, r, c = match[0]
    want = rgb[n, r, c] * a[n, r, c] + bg[b] * (1 - a[n, r, c])
    np.testing.assert_allclose(np.asarray(rand["rgb"][b]), want, atol=1e-5)
  # The render is composited over the same colours: a field with no density renders them.
  empty = lambda params, points, viewdirs: (jnp.zeros((*points.shape[:2], 3)),
                                            jnp.full(points.shape[:2], -1.0))
  out = render_lib.render_rays(empty, {"coarse": {}, "fine": {}}, rand["rays"], config,
                               None, True, rand["background"])  # no sigma noise
  np.testing.assert_allclose(np.asarray(out["fine"]["rgb"]), bg, atol=1e-6)


@pytest.mark.slow
def test_random_backgrounds_and_distortion_resume_bit_identically(tiny_blender, tmp_path):
  scene, data = load_scene(DataConfig(path=tiny_blender))
  config = dataclasses.replace(TINY, random_background=True, distortion_weight=0.01)
  nerf.train(scene, config, data, str(tmp_path / "full"), progress=False)
  nerf.train(scene, override(config, steps=4), data, str(tmp_path / "split"),
             progress=False)
  nerf.train(scene, config, data, str(tmp_path / "split"), progress=False)
  full = msnerf_jax.load_run(str(tmp_path / "full"))
  split = msnerf_jax.load_run(str(tmp_path / "split"))
  assert full.config == config
  for a, b in zip(leaves(full.params), leaves(split.params)):
    np.testing.assert_array_equal(a, b)
  white = str(tmp_path / "white")
  nerf.train(scene, dataclasses.replace(config, random_background=False), data, white,
             progress=False)
  assert any(np.any(a != b) for a, b in zip(leaves(full.params),
                                             leaves(msnerf_jax.load_run(white).params)))


@pytest.mark.slow  # two trainings (40 s); the target's compositing stays in the default suite
def test_random_backgrounds_keep_the_empty_region_empty(tmp_path):
  """The demo scene at 16x16: sky (alpha 0) around a textured object on a ground disc."""
  folder = demo.write_scene(str(tmp_path / "scene"), size=16, n_train=24, n_val=3,
                            progress=False)
  scene, data = load_scene(DataConfig(path=folder))
  config = override(TINY, net_width=48, steps=300, checkpoint_every=300, batch_rays=256,
                    lr_init=1e-2, lr_final=1e-3, n_fine=16)
  opacity = {}
  for random_background in (False, True):
    cfg = dataclasses.replace(config, random_background=random_background)
    run = str(tmp_path / f"run_{random_background}")
    nerf.train(scene, cfg, data, run, progress=False)
    _, mean, _ = evaluate.evaluate_nerf(scene, msnerf_jax.load_run(run).params, cfg, "val",
                                        progress=False)
    opacity[random_background] = mean
  print(opacity)
  clean = opacity[True]
  # Measured: white 0.44 on the sky (fog) and 0.999 on the object; random 0.05 and 0.90.
  assert clean["opacity_background"] < 0.1, opacity
  assert clean["opacity_object"] > 0.8, opacity
  assert clean["opacity_background"] < 0.25 * opacity[False]["opacity_background"], opacity


def test_scene_without_alpha_refuses_random_backgrounds(tiny_blender, tmp_path):
  scene, data = load_scene(DataConfig(path=tiny_blender))
  no_alpha = dataclasses.replace(scene, alphas=None, format="llff")
  run = str(tmp_path / "run")
  with pytest.raises(UserError, match="random backgrounds need images with an alpha"):
    nerf.train(no_alpha, dataclasses.replace(TINY, random_background=True), data, run,
               progress=False)
  assert not os.path.exists(run)


def test_presets_record_the_background_choice():
  assert config_lib.nerf_preset("cpu", "blender").random_background
  assert not config_lib.nerf_preset("cpu", "llff").random_background
  assert not config_lib.nerf_preset("paper", "blender").random_background  # reference
  assert config_lib.nerf_preset("paper", "blender", random_background=True).random_background
  # The fast preset: random backgrounds with alpha, the distortion loss without.
  fast_blender, fast_llff = (config_lib.nerf_preset("fast", f) for f in ("blender", "llff"))
  assert fast_blender.random_background and fast_blender.distortion_weight == 0.0
  assert not fast_llff.random_background and fast_llff.distortion_weight > 0
  fast_llff.validate()
  # A run.json saved before the fields existed loads with them off (what it was trained with).
  saved = config_lib.to_dict(TINY)
  del saved["random_background"], saved["distortion_weight"]
  loaded = config_lib.from_dict(config_lib.NerfConfig, saved)
  assert not loaded.random_background and loaded.distortion_weight == 0.0


@pytest.mark.integration
def test_cli_refuses_random_backgrounds_on_llff_and_bad_weights(fern, tiny_blender, tmp_path):
  run = str(tmp_path / "run")
  r = msnerf("nerf", "train", "--data", fern, "--out", run, "--random-background",
             "--steps", "1")
  assert_one_line_error(r, r"fern: random backgrounds need images with an alpha channel")
  assert not os.path.exists(run)
  r = msnerf("nerf", "train", "--data", tiny_blender, "--out", run, "--distortion-weight", "-1")
  assert_one_line_error(r, r"--distortion-weight -1.0: must be >= 0")
  assert not os.path.exists(run)


def test_cli_eval_reports_opacity_on_empty_space_and_object(tmp_path):
  folder = demo.write_scene(str(tmp_path / "scene"), size=16, n_train=4, n_val=2,
                            progress=False)
  run = str(tmp_path / "run")
  r = msnerf("nerf", "train", "--data", folder, "--out", run, "--preset", "cpu", "--steps", "2",
             "--batch-rays", "64", "--net-width", "16", "--n-coarse", "4", "--n-fine", "4")
  assert r.returncode == 0, r.stderr
  assert json.load(open(os.path.join(run, "run.json")))["config"]["random_background"] is True
  r = msnerf("nerf", "eval", "--run", run)
  assert r.returncode == 0, r.stderr
  assert "mean opacity" in r.stdout and "on empty space" in r.stdout
  mean = json.load(open(os.path.join(run, "eval_val", "metrics.json")))["mean"]
  assert 0 <= mean["opacity_background"] <= 1 and 0 <= mean["opacity_object"] <= 1
