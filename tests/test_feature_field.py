"""The VGG feature field (AdaIN in 3D): the stylization is affine and commutes with
compositing, the NeRF stays frozen, sweeps equal single renders, training resumes bit for
bit, and bad input gets one line."""

import dataclasses
import functools
import json
import os
import subprocess
import sys
import textwrap

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import msnerf_jax
from msnerf_jax import cli
from msnerf_jax.kinds import features as feature_kind
from msnerf_jax.kinds import stylized_scenes
from msnerf_jax.kinds import runs
from msnerf_jax.core.config import DataConfig, FeatureConfig, override
from msnerf_jax.data.scene import load_scene
from msnerf_jax.core.errors import UserError
from msnerf_jax.style.features import (cell_grid, pooled_stats, style_vector_of_stats,
                                     stylize_features)
from msnerf_jax.train import feature_targets, features
from msnerf_jax.train import nerf

from conftest import fake_decoder, write_blender_scene
from test_fast_trunk import TINY_FAST
from test_multistyle import write_style
from test_train_nerf import TINY

# A small field: 4 levels of 2^10 entries, an 8-channel feature.
TINY_FEATURES = override(FeatureConfig(), dim=8, width=16, hash_levels=4,
                         hash_table_size=2 ** 10, hash_min_res=4, hash_max_res=32, top_k=4,
                         stylize_scale=2, rays_per_cell=2, batch_cells=8, steps=4,
                         checkpoint_every=2, lr_init=1e-2)


def leaves(tree):
  return jax.tree_util.tree_leaves(tree)


# ----------------------------------------------------------------------------- pure parts


def test_stylizing_the_composite_equals_compositing_the_stylized_samples():
  rng = np.random.default_rng(0)
  c = 16
  samples = jnp.asarray(rng.normal(size=(5, 7, c)), jnp.float32)  # [rays, samples, C]
  weights = jnp.asarray(rng.uniform(0, 0.2, size=(5, 7)), jnp.float32)  # sums below 1
  content = (jnp.asarray(rng.normal(size=c), jnp.float32),
             jnp.asarray(rng.uniform(0.5, 2, size=c), jnp.float32))
  style = (jnp.asarray(rng.normal(size=c), jnp.float32),
           jnp.asarray(rng.uniform(0.5, 2, size=c), jnp.float32))
  for alpha in (1.0, 0.4):
    per_sample = stylize_features(samples, jnp.ones((5, 7)), content, style, alpha)
    composited_after = jnp.sum(weights[..., None] * per_sample, 1)
    composite = jnp.sum(weights[..., None] * samples, 1)
    before = stylize_features(composite, jnp.sum(weights, 1), content, style, alpha)
    np.testing.assert_allclose(before, composited_after, atol=1e-5)
  # alpha = 0: the features themselves.
  np.testing.assert_allclose(stylize_features(samples, jnp.ones((5, 7)), content, style, 0.0),
                             samples, atol=1e-5)


def test_a_style_sweep_under_vmap_equals_single_stylizations():
  rng = np.random.default_rng(1)
  f = jnp.asarray(rng.normal(size=(3, 4, 8)), jnp.float32)
  acc = jnp.asarray(rng.uniform(size=(3, 4)), jnp.float32)
  content = (jnp.zeros(8), jnp.ones(8))
  means = jnp.asarray(rng.normal(size=(5, 8)), jnp.float32)
  stds = jnp.asarray(rng.uniform(0.5, 2, size=(5, 8)), jnp.float32)
  sweep = jax.jit(jax.vmap(lambda m, s: stylize_features(f, acc, content, (m, s))))(means, stds)
  for k in range(5):
    np.testing.assert_allclose(sweep[k], stylize_features(f, acc, content, (means[k], stds[k])),
                               atol=1e-6)


def test_cells_average_rays_inside_their_8x8_block_of_the_enlarged_view():
  rows, cols = cell_grid(10, 12, 4, per_side=2)
  assert rows.shape == (5, 6, 4) == cols.shape  # ceil(40 / 8) x ceil(48 / 8) cells
  # Cell (1, 2) covers the enlarged view's pixels [8, 16) x [16, 24), i.e. the view's
  # [2, 4) x [4, 6) in edge coordinates: its rays' centre is at pixel (2.5, 4.5).
  assert np.allclose(rows[1, 2].mean() + 0.5, 3.0) and np.allclose(cols[1, 2].mean() + 0.5, 5.0)
  assert rows[1, 2].min() > 2 - 0.5 and rows[1, 2].max() < 4 - 0.5


def test_pooled_stats_are_those_of_all_positions():
  rng = np.random.default_rng(2)
  maps = [rng.normal(size=(3, 4, 6)), rng.normal(size=(2, 5, 6)) + 1.0]
  mean, std = pooled_stats(maps)
  flat = np.concatenate([m.reshape(-1, 6) for m in maps])
  np.testing.assert_allclose(mean, flat.mean(0), rtol=1e-5)
  np.testing.assert_allclose(std, flat.std(0, ddof=1) + 1e-8, rtol=1e-5)


# ----------------------------------------------------------------------------- training


@pytest.fixture(scope="module")
def feature_world(tmp_path_factory):
  """A tiny scene, an MLP NeRF run (6 steps) and a fast one, a fake decoder, and a feature
  run on the MLP NeRF trained through the CLI."""
  root = tmp_path_factory.mktemp("features")
  scene_dir = write_blender_scene(str(root / "scene"), n_train=4, n_val=2, size=16)
  scene, data = load_scene(DataConfig(path=scene_dir))
  nerf_run = str(root / "nerf")
  nerf.train(scene, TINY, data, nerf_run, progress=False)
  decoder = fake_decoder(root / "decoder")
  run = str(root / "ff")
  assert cli.main(["features", "train", "--nerf", nerf_run, "--decoder", decoder, "--out", run,
                   "--stylize-scale", "2", "--steps", "4", "--batch-cells", "8",
                   "--checkpoint-every", "2", "--dim", "8", "--width", "16",
                   "--hash-levels", "4", "--hash-table-size", "1024", "--hash-min-res", "4",
                   "--hash-max-res", "32", "--top-k", "4", "--rays-per-cell", "2"]) == 0
  return {"root": root, "scene_dir": scene_dir, "scene": scene, "data": data, "nerf": nerf_run,
          "decoder": decoder, "run": run}


def test_the_nerf_is_bit_identical_and_has_no_optimizer_state(feature_world):
  from msnerf_jax.core import checkpoint  # pylint: disable=g-import-not-at-top
  run = msnerf_jax.load_run(feature_world["run"])
  source = msnerf_jax.load_run(feature_world["nerf"])
  assert run.kind == "features" and set(run.params) == {"nerf", "features"}
  for a, b in zip(leaves(run.params["nerf"]), leaves(source.params)):
    assert np.array_equal(np.asarray(a).view(np.uint32), np.asarray(b).view(np.uint32))
  start = features.init_params(run.config, source.params)["features"]
  assert any(not np.array_equal(a, b) for a, b in zip(leaves(run.params["features"]),
                                                       leaves(start)))
  ckpts = checkpoint.Checkpoints(feature_world["run"])
  raw = ckpts.restore()
  ckpts.close()
  paths = [jax.tree_util.keystr(p) for p, _ in jax.tree_util.tree_leaves_with_path(raw["opt_state"])]
  assert paths and all("nerf" not in p for p in paths)
  assert any("tables" in p for p in paths)


def test_targets_are_cached_and_the_content_stats_pooled_over_the_fields_renders(feature_world):
  run_dir = feature_world["run"]
  targets = np.load(os.path.join(run_dir, feature_targets.TARGETS))
  assert targets.shape == (4, 4, 4, 512) and targets.dtype == np.float16  # 16 px x 2 / 8
  encoded = np.load(os.path.join(run_dir, feature_kind.CONTENT_STATS))
  want = pooled_stats(list(targets.astype(np.float32)))
  np.testing.assert_allclose(encoded, np.stack(want), rtol=1e-4, atol=1e-5)
  # Stylizing normalises by the trained field's own renders of the training views.
  from msnerf_jax.kinds import views  # pylint: disable=g-import-not-at-top
  run, scene = msnerf_jax.load_run(run_dir), feature_world["scene"]
  mean, std = feature_kind.content_stats(run)
  maps = [views.render_feature_map(scene, run.params, run.config, int(i))["features"]
          for i in scene.split("train")]
  rendered = pooled_stats(maps)
  np.testing.assert_allclose(mean, rendered[0], rtol=1e-4, atol=1e-5)
  np.testing.assert_allclose(std, rendered[1], rtol=1e-4, atol=1e-5)
  assert not np.allclose(std, encoded[1], rtol=0.05)
  # Without them (a run from before they were written): the encoder's statistics.
  stale = dataclasses.replace(run, step=run.step + 1)
  np.testing.assert_allclose(np.stack(feature_kind.content_stats(stale)), encoded)


@pytest.mark.parametrize("sampler", ["hierarchical", "grid"])
def test_training_lowers_the_loss_on_a_fixed_batch(feature_world, sampler):
  scene = feature_world["scene"]
  if sampler == "grid":  # an untrained grid: every cell unknown, so every step is sampled.
    nerf_config, nerf_params = TINY_FAST, nerf.init_state(TINY_FAST).params
  else:
    source = msnerf_jax.load_run(feature_world["nerf"])
    nerf_config, nerf_params = source.config, source.params
  config = dataclasses.replace(TINY_FEATURES, nerf=nerf_config, scene_box=1.5, batch_cells=16)
  targets = jnp.asarray(np.load(os.path.join(feature_world["run"], feature_targets.TARGETS)))
  args = (jnp.asarray(scene.c2w[:4]), jnp.asarray(scene.K), config, False,
          (scene.height, scene.width, scene.focal), scene.near, scene.far)
  fixed = features.sample_batch(jax.random.PRNGKey(123), targets, *args)
  loss = jax.jit(features.loss_fn, static_argnums=3)
  state = features.init_state(config, nerf_params)
  first = float(loss(state.params["features"], state.params["nerf"], fixed, config)[0])
  step = jax.jit(functools.partial(features.train_step, config=config))
  for i in range(30):
    state, _ = step(state, features.sample_batch(jax.random.PRNGKey(i), targets, *args))
  last = float(loss(state.params["features"], state.params["nerf"], fixed, config)[0])
  assert last < 0.8 * first, (first, last)


@pytest.mark.parametrize("target", ["photo", pytest.param("encoder", marks=pytest.mark.slow)])
def test_the_decodability_loss_paints_patches_of_cells_and_trains_the_field_alone(
    feature_world, target):
  from msnerf_jax.style import transfer as stylize  # pylint: disable=g-import-not-at-top
  scene = feature_world["scene"]
  source = msnerf_jax.load_run(feature_world["nerf"])
  decoder = stylized_scenes.load_decoder(feature_world["decoder"])
  config = dataclasses.replace(TINY_FEATURES, nerf=source.config, scene_box=1.5,
                               decode_weight=1.0, decode_target=target, decode_patches=2,
                               decode_cells=3)
  targets = jnp.asarray(np.load(os.path.join(feature_world["run"], feature_targets.TARGETS)))
  views = scene.images[scene.split("train")]
  big = np.stack([stylize.enlarged(v, 2) for v in views])  # [4, 32, 32, 3]
  args = (jnp.asarray(scene.c2w[:4]), jnp.asarray(scene.K), config, False,
          (scene.height, scene.width, scene.focal), scene.near, scene.far, None,
          jnp.asarray(big, jnp.float16))
  batch = features.sample_batch(jax.random.PRNGKey(5), targets, *args)
  assert batch["patch_rays"]["origins"].shape[0] == 2 * 9 * config.rays_per_cell
  # Each patch is 3 x 3 whole cells (8 x 8 pixels each) of one enlarged training view: its
  # pixels, or its encoder's cells.
  if target == "photo":
    assert batch["pixels"].shape == (2, 24, 24, 3) and "patch_targets" not in batch
    for patch in np.asarray(batch["pixels"], np.float32):
      assert any(np.array_equal(patch, v[8 * r:8 * r + 24, 8 * c:8 * c + 24]
                                .astype(np.float16).astype(np.float32))
                 for v in big for r in range(2) for c in range(2))
  else:
    assert batch["patch_targets"].shape == (2, 3, 3, 512) and "pixels" not in batch
    for patch in np.asarray(batch["patch_targets"]):
      assert any(np.array_equal(patch, t[r:r + 3, c:c + 3])
                 for t in np.asarray(targets) for r in range(2) for c in range(2))
  state = features.init_state(config, source.params)
  loss = jax.jit(features.loss_fn, static_argnums=(3, 5))
  off = dataclasses.replace(config, decode_weight=0.0)
  first = loss(state.params["features"], state.params["nerf"], batch, config, decoder.params,
               decoder.config.upsample)[1]
  plain = loss(state.params["features"], state.params["nerf"], batch, off)[1]
  assert float(first["mse"]) == float(plain["mse"]) and "decode" not in plain
  np.testing.assert_allclose(float(first["loss"]), float(first["mse"] + first["decode"]),
                             rtol=1e-6)
  step = jax.jit(functools.partial(features.train_step, config=config,
                                   upsample=decoder.config.upsample))
  nerf_before = [np.asarray(x).copy() for x in leaves(state.params["nerf"])]
  for i in range(30):
    state, _ = step(state, features.sample_batch(jax.random.PRNGKey(i), targets, *args),
                    decoder.params)
  last = loss(state.params["features"], state.params["nerf"], batch, config, decoder.params,
              decoder.config.upsample)[1]
  assert float(last["decode"]) < 0.8 * float(first["decode"]), (first, last)
  for a, b in zip(leaves(state.params["nerf"]), nerf_before):
    assert np.array_equal(np.asarray(a), b)


def test_a_k_style_sweep_equals_k_single_renders_and_alpha_0_decodes_the_features(
    feature_world):
  from msnerf_jax.kinds import views
  from msnerf_jax.style.features import decode_styles  # pylint: disable=g-import-not-at-top
  run = msnerf_jax.load_run(feature_world["run"])
  scene = feature_world["scene"]
  decoder = stylized_scenes.load_decoder(feature_world["decoder"])
  stats = feature_kind.content_stats(run)
  rng = np.random.default_rng(3)
  styles = np.concatenate([rng.uniform(0, 2, (3, 512)), rng.uniform(0.5, 2, (3, 512))], 1)
  camera = scene.c2w[4]
  sweep = views.render_feature_styles(scene, run.params, run.config, camera, decoder, stats,
                                      styles)
  assert sweep.shape == (3, 16, 16, 3)
  for k in range(3):
    one = views.render_feature_styles(scene, run.params, run.config, camera, decoder, stats,
                                      styles[k:k + 1])
    np.testing.assert_allclose(sweep[k], one[0], atol=1e-5)
  assert float(np.abs(sweep[0] - sweep[1]).max()) > 1e-4
  # The scene's own statistics as the style: the decoder's picture of the plain features.
  fmap = views.render_feature_map(scene, run.params, run.config, camera)
  plain = decode_styles(decoder, fmap["features"], np.ones((4, 4)), stats, stats[0][None],
                        stats[1][None], 0.0, 16, 16, 2)
  original = views.render_feature_styles(scene, run.params, run.config, camera, decoder, stats,
                                         style_vector_of_stats(stats))
  np.testing.assert_allclose(original, plain, atol=1e-5)


def test_frames_averaged_over_four_cell_grids_follow_half_cell_shifts_exactly(feature_world):
  """The decoder pins its strokes to the relu4_1 cell grid, which stays with the camera: a
  view moved by half a cell is painted from other features, not the same ones moved. On
  the four grids {0, 4}^2 (enlarged pixels) the moved view's grids are the first view's
  grids moved (one of them by a whole cell, to which the decoder is equivariant), so away
  from the borders its frame is the first frame moved, which one grid is not."""
  # pylint: disable=g-import-not-at-top
  from msnerf_jax.nerf import cameras
  from msnerf_jax.kinds import views
  run = msnerf_jax.load_run(feature_world["run"])
  scene = feature_world["scene"]
  decoder = stylized_scenes.load_decoder(feature_world["decoder"])
  stats = feature_kind.content_stats(run)
  style = np.concatenate([np.full(512, 0.5), np.full(512, 1.5)]).astype(np.float32)
  size, shift = 64, 2  # half a cell: 4 pixels of the view enlarged 2x.
  K = scene.K.copy()
  K[:2, 2] *= size / 16
  moved_K = K.copy()
  moved_K[0, 2] += shift  # the picture moves `shift` pixels right.
  frames = {}
  for grids in (1, 4):
    frames[grids] = [views.render_feature_styles(
        scene, run.params, run.config, cameras.Camera(scene.c2w[4], k, size, size), decoder,
        stats, style[None], grids=grids)[0] for k in (K, moved_K)]
  inner = lambda f: f[20:-20, 20:-20]  # 5 cells: the decoder's reach is under 4.
  diff = {g: float(np.abs(inner(b[:, shift:]) - inner(a[:, :-shift])).max())
          for g, (a, b) in frames.items()}
  assert diff[4] < 1e-5 < 1e-3 < diff[1], diff


def test_msnerf_render_paints_a_feature_run_in_any_style_image(feature_world, tmp_path):
  style = write_style(tmp_path / "red.png", (200, 30, 30))
  out = str(tmp_path / "video")
  assert cli.main(["render", "--run", feature_world["run"], "--out", out, "--style", style,
                   "--frames", "2", "--morph", style, "original", "--grid-steps", "2",
                   "--grid-views", "1"]) == 0
  assert os.path.getsize(out + ".mp4") > 0 and os.path.exists(out + "_grid.png")


def test_stylize_scene_from_features_writes_the_fields_renders_as_a_stylized_dataset(
    feature_world, tmp_path, capsys):
  from msnerf_jax.kinds import views
  # pylint: disable=g-import-not-at-top
  from msnerf_jax.data.images import read_image
  from msnerf_jax.data.stylized import load_stylized
  from msnerf_jax.style.vectors import style_vector_of
  from msnerf_jax.models.vgg import load_vgg_params
  style = write_style(tmp_path / "red.png", (200, 30, 30))
  out = str(tmp_path / "stylized")
  assert cli.main(["stylize-scene", "--from-features", feature_world["run"], "--styles", style,
                   "--alphas", "0.5", "--include-original", "--out", out]) == 0
  data = load_stylized(out, progress=False)
  scene, run = feature_world["scene"], msnerf_jax.load_run(feature_world["run"])
  manifest = json.load(open(os.path.join(out, "manifest.json")))
  assert manifest["features"] == os.path.abspath(feature_world["run"])
  assert manifest["stylize_scale"] == 2 and manifest["content_stats"] == "scene"
  # View 5 in the red style at strength 0.5: the field's render of that camera, with half the
  # style's statistics and half the scene's, on the photo's white background.
  stats = feature_kind.content_stats(run)
  # The style picture as per-frame AdaIN crops it for the painted size (32 x 32 here).
  red = style_vector_of(load_vgg_params(), read_image(style), (32, 32))
  vector = 0.5 * style_vector_of_stats(stats) + 0.5 * np.asarray(red)
  want = views.render_feature_styles(scene, run.params, run.config, 5,
                                     stylized_scenes.load_decoder(feature_world["decoder"]), stats,
                                     vector[None])[0]
  a = scene.alphas[5][..., None] / 255.0
  want = want * a + (1 - a)
  np.testing.assert_allclose(data.images[0, 5] / 255.0, want, atol=1.5 / 255)
  np.testing.assert_allclose(data.images[1] / 255.0, scene.images, atol=0.6 / 255)  # original
  # The scene is the feature run's: giving one too is refused, and nothing is written.
  assert cli.main(["stylize-scene", "--from-features", feature_world["run"], "--data",
                   feature_world["scene_dir"], "--styles", style, "--out",
                   str(tmp_path / "other")]) == 2
  assert "--data: --from-features takes the scene" in capsys.readouterr().err
  assert cli.main(["stylize-scene", "--styles", style, "--out", str(tmp_path / "other")]) == 2
  assert "--data: required (or --from-features FEATURE_RUN)" in capsys.readouterr().err
  assert not os.path.exists(tmp_path / "other")


@pytest.mark.slow  # 30 s; the trainers' resume machinery (loop.fit) is tested by the NeRF's
def test_feature_resume_is_bit_identical(feature_world, tmp_path):
  nerf_run, decoder = feature_world["nerf"], feature_world["decoder"]
  full, split = str(tmp_path / "full"), str(tmp_path / "split")
  features.train(TINY_FEATURES, nerf_run, decoder, full, progress=False)
  features.train(override(TINY_FEATURES, steps=2), nerf_run, decoder, split,
                 progress=False)
  assert features.train(TINY_FEATURES, nerf_run, decoder, split,
                        progress=False)["resumed_from"] == 2
  a, b = msnerf_jax.load_run(full), msnerf_jax.load_run(split)
  for x, y in zip(leaves(a.params), leaves(b.params)):
    np.testing.assert_array_equal(x, y)


TWO_DEVICES = textwrap.dedent("""
    import os, sys
    os.environ["XLA_FLAGS"] = (os.environ.get("XLA_FLAGS", "")
                               + " --xla_force_host_platform_device_count=2")
    import dataclasses, jax, numpy as np, jax.numpy as jnp
    import msnerf_jax
    from msnerf_jax.core.config import DataConfig
    from msnerf_jax.data.scene import load_scene
    from msnerf_jax.style import transfer as stylize
    from msnerf_jax.kinds import stylized_scenes
    from msnerf_jax.core.parallel import data_parallel
    from msnerf_jax.train import features
    sys.path.insert(0, {tests!r})
    from test_feature_field import TINY_FEATURES
    scene, _ = load_scene(DataConfig(path={scene!r}))
    source = msnerf_jax.load_run({nerf!r})
    config = dataclasses.replace(TINY_FEATURES, nerf=source.config, scene_box=1.5,
                                 decode_weight={decode_weight!r}, decode_cells=3)
    decoder = stylized_scenes.load_decoder({decoder!r})
    targets = jnp.asarray(np.load({targets!r}))
    pixels = jnp.asarray(np.stack([stylize.enlarged(v, 2) for v in scene.images[:4]]),
                         jnp.float16)
    def run(dp):
      state = dp.put_state(features.init_state(config, source.params))
      step = features.compile_train_step(config, dp, decoder)
      for i in range(4):
        batch = features.sample_batch(jax.random.PRNGKey(i), targets, jnp.asarray(scene.c2w[:4]),
                                      jnp.asarray(scene.K), config, False,
                                      (scene.height, scene.width, scene.focal), 2.0, 6.0,
                                      None, pixels)
        state, stats = step(state, dp.put_batch(batch))
      return dp.to_host(state)
    one, two = run(data_parallel(1)), run(data_parallel(2))
    start = features.init_state(config, source.params).params["features"]
    diff = lambda a, b: max(float(np.max(np.abs(np.asarray(x) - np.asarray(y))))
                            for x, y in zip(jax.tree_util.tree_leaves(a), jax.tree_util.tree_leaves(b)))
    moved, worst = diff(one.params["features"], start), diff(one.params["features"], two.params["features"])
    print("worst", worst, "moved", moved)
    assert moved > 1e-4 and worst < 1e-3 * moved, (worst, moved)
    assert diff(one.params["nerf"], two.params["nerf"]) == 0.0
""")


@pytest.mark.slow  # a subprocess with two compilations
@pytest.mark.parametrize("decode_weight", [0.0, 1.0])
def test_two_devices_give_the_same_feature_steps_as_one(feature_world, decode_weight):
  tests = os.path.dirname(os.path.abspath(__file__))
  code = TWO_DEVICES.format(tests=tests, scene=feature_world["scene_dir"],
                            nerf=feature_world["nerf"], decoder=feature_world["decoder"],
                            decode_weight=decode_weight,
                            targets=os.path.join(feature_world["run"], feature_targets.TARGETS))
  result = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                          timeout=600)
  assert result.returncode == 0, result.stdout + result.stderr[-3000:]


# ----------------------------------------------------------------------------- bad input


def test_a_feature_run_pointed_at_another_nerf_run_is_refused(feature_world, tmp_path, capsys):
  scene, data = feature_world["scene"], feature_world["data"]
  other = str(tmp_path / "other_nerf")
  nerf.train(scene, override(TINY, steps=2), data, other, progress=False)
  run = feature_world["run"]
  before = {f: os.path.getmtime(os.path.join(run, f)) for f in os.listdir(run)}
  assert cli.main(["features", "train", "--nerf", other, "--decoder", feature_world["decoder"],
                   "--out", run, "--config", run]) == 2
  err = capsys.readouterr().err.strip().splitlines()[-1]
  assert err.startswith("msnerf: error:") and "made on the NeRF run" in err, err
  assert {f: os.path.getmtime(os.path.join(run, f)) for f in os.listdir(run)} == before


def test_a_decodability_patch_wider_than_the_views_is_refused_before_writing(
    feature_world, tmp_path, capsys):
  run = str(tmp_path / "wide")
  assert cli.main(["features", "train", "--nerf", feature_world["nerf"], "--decoder",
                   feature_world["decoder"], "--out", run, "--stylize-scale", "2",
                   "--decode-weight", "1", "--decode-cells", "5"]) == 2
  err = capsys.readouterr().err.strip().splitlines()
  assert err == ["msnerf: error: --decode-cells 5: a patch wider than the views' 4 x 4 relu4_1 "
                 "cells"], err
  assert not os.path.exists(run)


@pytest.mark.parametrize("change, message", [
    ({"stylize_scale": 0}, "--stylize-scale 0: must be a whole number"),
    ({"stylize_scale": 1.5}, "--stylize-scale 1.5: must be a whole number"),
    ({"hash_table_size": 1000}, "--hash-table-size 1000: must be a power of two"),
    ({"dim": 0}, "--dim 0: must be >= 1"),
    ({"hash_min_res": 64}, "--hash-max-res 32: finest resolution below the coarsest"),
    ({"decode_weight": -1.0}, "--decode-weight -1.0: must be >= 0"),
    ({"decode_weight": 1.0, "decode_cells": 2}, "--decode-cells 2: must be >= 3"),
    ({"decode_weight": 1.0, "decode_target": "both"}, "--decode-target both: unknown"),
    ({"decode_weight": 1.0, "decode_patches": 0}, "--decode-patches 0: must be a positive"),
])
def test_a_feature_setting_that_cannot_work_is_named(change, message):
  from msnerf_jax.core.parallel import data_parallel  # pylint: disable=g-import-not-at-top
  with pytest.raises(UserError, match=message):
    features.check_config(dataclasses.replace(TINY_FEATURES, **change), data_parallel(1))


# ----------------------------------------------------------------------------- a decoder for the field


def _styles_folder(folder):
  os.makedirs(folder, exist_ok=True)
  for i, colour in enumerate(((200, 40, 30), (30, 60, 200), (20, 160, 40))):
    write_style(os.path.join(folder, f"s{i}.png"), colour, size=(48, 40))
  return str(folder)


def test_decoder_fine_tuned_on_a_feature_runs_maps_sees_them_as_its_views_are_painted(
    feature_world, tmp_path):
  """`adain train --content-features`: the cached maps are the run's renders of its training
  views normalised by its content statistics, so AdaIN of a crop towards a style is what
  stylize_features hands the decoder at render time; photo and feature crops share a batch
  (the loss is the mean of the two halves'); a resumed run ends bit-identical."""
  from msnerf_jax.style import adain  # pylint: disable=g-import-not-at-top
  from msnerf_jax.kinds import views
  from msnerf_jax.core.config import AdainConfig  # pylint: disable=g-import-not-at-top
  from msnerf_jax.models import vgg  # pylint: disable=g-import-not-at-top
  from msnerf_jax.train import adain as train_adain  # pylint: disable=g-import-not-at-top
  from msnerf_jax.train import adain_losses  # pylint: disable=g-import-not-at-top
  from msnerf_jax.train import adain_data  # pylint: disable=g-import-not-at-top
  styles = _styles_folder(tmp_path / "styles")
  config = AdainConfig(size=32, resize=40, batch=2, steps=4, sample_every=2, checkpoint_every=2,
                       lr=1e-4, init_from=feature_world["decoder"],
                       content_features=feature_world["run"], feature_share=1.0)
  quiet = dict(progress=False, log=lambda *_: None)
  straight = str(tmp_path / "straight")
  result = train_adain.train(config, [], styles, straight, **quiet)
  assert result.step == 4 and np.isfinite(result.metrics["loss"])
  assert os.path.exists(os.path.join(straight, "samples", "step_0000004.png"))
  maps, stats = adain_data.prepare_feature_maps(straight, config)
  run = msnerf_jax.load_run(feature_world["run"])
  scene = feature_world["scene"]
  assert maps.shape == (len(scene.split("train")), 4, 4, 512) and maps.dtype == np.float16
  mean, std = feature_kind.content_stats(run)
  np.testing.assert_array_equal(stats, np.stack([mean, std]))
  rendered = views.render_feature_map(scene, run.params, run.config, int(scene.split("train")[1]))
  np.testing.assert_allclose(maps[1], (rendered["features"] - mean) / std, rtol=2e-3, atol=2e-3)
  # The trainer's AdaIN of the normalised crops is the renderer's stylization of the map.
  enc = vgg.load_vgg_params()
  style = np.random.default_rng(3).random((1, 32, 32, 3)).astype(np.float32)
  s_mean, s_std = adain.channel_stats(adain.encode(enc, jnp.asarray(style))["relu4_1"])
  target = adain_losses.adain_targets(enc, None, jnp.asarray(maps[1:2], jnp.float32), s_mean, s_std)
  painted = stylize_features(jnp.asarray(maps[1], jnp.float32) * std + mean, jnp.ones((4, 4)),
                             (mean, std), (s_mean[0], s_std[0]))
  np.testing.assert_allclose(target[0], painted, rtol=1e-4, atol=1e-3)
  # Photos and feature crops in one batch: each loss is the mean of the two halves'.
  params = runs.load_run(straight).params
  photo = np.random.default_rng(4).random((1, 32, 32, 3)).astype(np.float32)
  styles2 = np.concatenate([style, style[:, ::-1]])
  feats = jnp.asarray(maps[:1], jnp.float32)
  shifted = dataclasses.replace(config, shift_weight=1.0, shift_source="features")
  shifts = np.array([[3, 4], [7, 1]], np.int32)
  _, both = adain_losses.losses(params, enc, photo, styles2, shifted, shifts, feats)
  _, first = adain_losses.losses(params, enc, photo, styles2[:1], shifted, shifts[:1])
  _, second = adain_losses.losses(params, enc, None, styles2[1:], shifted, shifts[1:], feats)
  for name in ("content", "style", "shift"):
    np.testing.assert_allclose(both[name], (first[name] + second[name]) / 2, rtol=1e-4)
  # Two steps, then resumed to four: the same decoder bit for bit.
  resumed = str(tmp_path / "resumed")
  train_adain.train(override(config, steps=2), [], styles, resumed, **quiet)
  train_adain.train(config, [], styles, resumed, **quiet)
  jax.tree_util.tree_map(np.testing.assert_array_equal, runs.load_run(resumed).params,
                         runs.load_run(straight).params)


@pytest.mark.parametrize("change, args, message", [
    ({"content_features": "NERF"}, [], "a 'nerf' run, not a 'features' run"),
    ({"feature_share": 0.5}, [], "--content: needed for the photo share of each batch"),
    ({"feature_share": 0.0}, [], "--feature-share 0.0: must be in (0, 1]"),
    ({"shift_weight": 1.0}, [], "--shift-source photo: feature crops have no pixels to move"),
    ({"size": 48}, [], "its views are 4 relu4_1 cells on their shorter side, --size 48 needs 6"),
    ({"content_features": ""}, [], "--content: give at least one content folder"),
])
def test_feature_content_that_cannot_work_is_refused_before_writing(feature_world, tmp_path,
                                                                    change, args, message):
  from msnerf_jax.core.config import AdainConfig  # pylint: disable=g-import-not-at-top
  from msnerf_jax.train import adain as train_adain  # pylint: disable=g-import-not-at-top
  styles = _styles_folder(tmp_path / "styles")
  change = {k: feature_world["nerf"] if v == "NERF" else v for k, v in change.items()}
  config = dataclasses.replace(
      AdainConfig(size=32, resize=40, batch=2, steps=2, content_features=feature_world["run"],
                  feature_share=1.0), **change)
  run = str(tmp_path / "run")
  with pytest.raises(UserError, match=message.replace("(", r"\(").replace(")", r"\)")):
    train_adain.train(config, args, styles, run, progress=False, log=lambda *_: None)
  assert not os.path.exists(run)


def test_bad_style_images_and_decoders_get_one_line(feature_world, tmp_path, capsys):
  from PIL import Image  # pylint: disable=g-import-not-at-top
  tiny = str(tmp_path / "tiny.png")
  Image.fromarray(np.zeros((1, 1, 3), np.uint8)).save(tiny)
  broken = str(tmp_path / "broken.jpg")
  with open(broken, "wb") as f:
    f.write(b"not an image")
  out = str(tmp_path / "v")
  for style, words in ((tiny, "16x16"), (broken, broken)):
    assert cli.main(["render", "--run", feature_world["run"], "--out", out, "--style", style,
                     "--frames", "1"]) == 2
    err = capsys.readouterr().err.strip().splitlines()[-1]
    assert err.startswith("msnerf: error:") and words in err, err
  assert cli.main(["render", "--run", feature_world["run"], "--out", out, "--frames", "1"]) == 2
  assert "--style" in capsys.readouterr().err
  # A decoder of another encoder: refused before anything is written.
  import json  # pylint: disable=g-import-not-at-top
  other = str(tmp_path / "decoder")
  fake_decoder(other)
  record = json.load(open(os.path.join(other, "run.json")))
  record["config"]["encoder"] = "vgg19-pytorch"
  json.dump(record, open(os.path.join(other, "run.json"), "w"))
  new = str(tmp_path / "ff_new")
  assert cli.main(["features", "train", "--nerf", feature_world["nerf"], "--decoder", other,
                   "--out", new, "--steps", "1"]) == 2
  assert "vgg19-pytorch" in capsys.readouterr().err
  assert not os.path.exists(new)
  assert not any(f.startswith("v") for f in os.listdir(tmp_path) if f != "decoder")


def test_evaluation_frames_of_a_feature_run_follow_its_style_and_white_background(
    feature_world, tmp_path):
  from msnerf_jax.eval import paths  # pylint: disable=g-import-not-at-top
  from msnerf_jax.models import vgg  # pylint: disable=g-import-not-at-top
  run = msnerf_jax.load_run(feature_world["run"])
  nerf_run = msnerf_jax.load_run(feature_world["nerf"])
  scene = feature_world["scene"]
  base = paths.nerf_path(scene, nerf_run.params, nerf_run.config, scene.render_poses[:2])
  encoder = vgg.load_vgg_params()
  red = np.tile(np.array([0.9, 0.1, 0.1], np.float32), (32, 32, 1))
  blue = np.tile(np.array([0.1, 0.1, 0.9], np.float32), (32, 32, 1))
  (frames, other), geometry = paths.feature_field_frames(
      run, scene, base, feature_world["nerf"], encoder, [red, blue], [1.0, 1.0])
  assert geometry is base and len(frames) == 2 and frames[0].shape == (16, 16, 3)
  assert float(np.abs(frames[0] - other[0]).max()) > 1e-4
  (alone,), _ = paths.feature_field_frames(run, scene, base, feature_world["nerf"], encoder,
                                              [blue], [1.0])
  np.testing.assert_allclose(alone[1], other[1], atol=1e-5)  # a sweep equals single styles
  # Where the NeRF is transparent the frame is white (Blender), as per-frame AdaIN's.
  clear = base[0]["accumulation"] < 1e-3
  if clear.any():
    np.testing.assert_allclose(frames[0][clear], 1.0, atol=2e-3)
  # Another NeRF run's field: its own geometry is rendered.
  _, own = paths.feature_field_frames(run, scene, base, str(tmp_path / "elsewhere"), encoder,
                                         [red], [1.0])
  assert own is not base
  np.testing.assert_allclose(own[0]["depth"], base[0]["depth"], atol=1e-5)
