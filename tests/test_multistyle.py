"""Multi-style NeRF: the frozen trunk, the shared-sample step, sweeps, interpolation, the CLI and
its bad input, on a tiny synthetic scene with an untrained (random) AdaIN decoder."""

import json
import os
import subprocess
import sys
import textwrap

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from PIL import Image

from msnerf_jax import cli, load_run
from msnerf_jax.kinds import multistyle as multistyle_kind
from msnerf_jax.kinds import stylized_scenes
from msnerf_jax.core import checkpoint
from msnerf_jax.kinds import runs
from msnerf_jax.kinds import views
from msnerf_jax.core.config import DataConfig, override
from msnerf_jax.data.scene import load_scene
from msnerf_jax.data.stylized import load_stylized
from msnerf_jax.models.multistyle import ConcatDense, MultiStyleMLP, MultistyleField
from msnerf_jax.models.nerf import NerfTrunk
from msnerf_jax.train import multistyle, nerf

from conftest import fake_decoder, write_blender_scene
from test_train_nerf import TINY

TESTS = os.path.dirname(os.path.abspath(__file__))


def leaves_with_paths(tree):
  return [(jax.tree_util.keystr(p), np.asarray(v))
          for p, v in jax.tree_util.tree_leaves_with_path(tree)]


def write_style(path, colour, size=(40, 24)):
  rng = np.random.default_rng(sum(colour))
  noise = rng.integers(0, 60, (size[1], size[0], 3))
  Image.fromarray(np.clip(np.asarray(colour) + noise, 0, 255).astype(np.uint8)).save(path)
  return str(path)


@pytest.fixture(scope="module")
def world(tmp_path_factory):
  """A scene, a NeRF run on it, two style images and the stylized dataset (via the CLI)."""
  root = tmp_path_factory.mktemp("ms")
  scene_dir = write_blender_scene(str(root / "scene"), n_train=4, n_val=2, size=16)
  scene, data = load_scene(DataConfig(path=scene_dir))
  nerf_run = str(root / "nerf")
  nerf.train(scene, override(TINY, steps=4), data, nerf_run, progress=False)
  styles = [write_style(root / "red.png", (200, 30, 30)), write_style(root / "blue.png", (20, 40, 200))]
  dec = fake_decoder(root / "decoder")
  stylized = str(root / "stylized")
  assert cli.main(["stylize-scene", "--data", scene_dir, "--decoder", dec, "--styles", *styles,
                   "--include-original", "--out", stylized]) == 0
  return {"root": root, "scene_dir": scene_dir, "scene": scene, "nerf": nerf_run,
          "styles": styles, "decoder": dec, "stylized": stylized}


def _train(world, density_aware):
  run = str(world["root"] / f"ms_{density_aware}")
  argv = ["multistyle", "train", "--nerf", world["nerf"], "--stylized", world["stylized"],
          "--out", run, "--steps", "3", "--batch-rays", "32", "--checkpoint-every", "3"]
  # The density-aware run also gets extra head layers (their training and freezing is tested).
  extra = ["--density-aware", "--rgb-extra-layers", "1", "--density-extra-layers", "1"]
  assert cli.main(argv + (extra if density_aware else [])) == 0
  return run


@pytest.fixture(scope="module")
def trained_standard(world):
  return _train(world, False)


@pytest.fixture(scope="module")
def trained_density(world):
  return _train(world, True)


@pytest.fixture(params=["standard", "density"])
def trained(request):
  """Each multi-style variant, trained 3 steps (once per module)."""
  return request.getfixturevalue(f"trained_{request.param}")


# ----------------------------------------------------------------------------- the model


def test_concat_dense_is_one_dense_on_the_concatenation():
  layer = ConcatDense(features=5, x_dim=3, code_dim=4)
  x, code = jnp.arange(6.0).reshape(2, 3) / 5, jnp.ones((1, 4)) * 0.3
  params = layer.init(jax.random.PRNGKey(0), x, jnp.zeros((1, 5)))
  params = layer.init(jax.random.PRNGKey(0), x, layer.apply(params, code, method="project_code"))
  projected = layer.apply(params, code, method="project_code")
  got = layer.apply(params, x, projected)
  p = params["params"]
  want = jnp.concatenate([x, jnp.broadcast_to(code, (2, 4))], -1) @ p["kernel"] + p["bias"]
  np.testing.assert_allclose(got, want, rtol=1e-6, atol=1e-6)


@pytest.mark.parametrize("density_aware", [False, True])
def test_heads_run_per_style_and_density_is_shared_unless_density_aware(density_aware):
  trunk = NerfTrunk(depth=2, width=16, skip_layer=0, pos_freqs=2, dir_freqs=1)
  model = MultiStyleMLP(trunk=trunk, density_aware=density_aware, style_dim=8,
                        style_hidden=(8, 8))
  points = jax.random.normal(jax.random.PRNGKey(0), (5, 7, 3))
  viewdirs = jnp.ones((5, 1, 3)) / np.sqrt(3)
  styles = jax.random.normal(jax.random.PRNGKey(1), (3, 8))
  full = lambda m, p, d, s: m(p, d, m.codes(s))
  params = model.init(jax.random.PRNGKey(2), points, viewdirs, styles, method=full)
  rgb, sigma = model.apply(params, points, viewdirs, styles, method=full)
  assert rgb.shape == (3, 5, 7, 3)
  assert sigma.shape == ((3, 5, 7) if density_aware else (5, 7))
  assert set(params["params"]) >= {"trunk", "style_rgb", "rgb_hidden", "rgb_out"}
  assert ("style_density" in params["params"]) == density_aware
  # Style 1 alone gives the same colours as style 1 within the batch of three.
  rgb1, _ = model.apply(params, points, viewdirs, styles[1:2], method=full)
  np.testing.assert_allclose(rgb1[0], rgb[1], atol=1e-6)
  assert float(jnp.max(jnp.abs(rgb[0] - rgb[2]))) > 1e-4  # styles differ


# ----------------------------------------------------------------------------- dataset and training


def test_stylized_dataset_layout_and_continuation(world, capsys):
  data = load_stylized(world["stylized"])
  assert data.names == ["red", "blue", "original"]
  assert data.images.shape == (3, 6, 16, 16, 3) and data.images.dtype == np.uint8
  assert data.vectors.shape == (3, 1024) and np.all(np.isfinite(data.vectors))
  assert not np.allclose(data.vectors[0], data.vectors[1])
  scene = world["scene"]
  np.testing.assert_array_equal(data.images[2], np.round(scene.images * 255).astype(np.uint8))
  # Interrupt: one image of "blue" lost and the style not marked done -> only it is redone.
  manifest_path = os.path.join(world["stylized"], "manifest.json")
  manifest = json.load(open(manifest_path))
  target = os.path.join(world["stylized"], "blue", "0003.png")
  before = open(target, "rb").read()
  os.remove(target)
  manifest["done"] = ["red"]
  json.dump(manifest, open(manifest_path, "w"))
  capsys.readouterr()
  assert cli.main(["stylize-scene", "--data", world["scene_dir"], "--decoder", world["decoder"],
                   "--styles", *world["styles"], "--include-original",
                   "--out", world["stylized"]]) == 0
  assert "1 written" in capsys.readouterr().out
  assert open(target, "rb").read() == before  # deterministic
  assert json.load(open(manifest_path))["done"] == ["red", "blue", "original"]


def test_stylize_scale_stylizes_enlarged_views_and_is_recorded(world, tmp_path, capsys):
  from msnerf_jax.style import transfer as stylize  # pylint: disable=g-import-not-at-top
  from msnerf_jax.data import images  # pylint: disable=g-import-not-at-top
  from msnerf_jax.models import vgg  # pylint: disable=g-import-not-at-top
  out = str(tmp_path / "fine")
  argv = ["stylize-scene", "--data", world["scene_dir"], "--decoder", world["decoder"],
          "--styles", world["styles"][0], "--out", out]
  assert cli.main(argv + ["--stylize-scale", "2"]) == 0
  data, plain = load_stylized(out), load_stylized(world["stylized"])
  assert json.load(open(os.path.join(out, "manifest.json")))["stylize_scale"] == 2
  assert data.images.shape == (1, 6, 16, 16, 3)
  # Each view is the 32x32 stylization of the enlarged view, box-averaged back to 16x16.
  view = world["scene"].images[3]
  decoder = stylized_scenes.load_decoder(world["decoder"])
  picture = images.read_image(world["styles"][0])
  big = stylize.stylize_image(decoder, vgg.load_vgg_params(), images.resize(view, 32, 32),
                              [picture])
  a = world["scene"].alphas[3][..., None] / 255.0  # Blender views keep their white background
  want = big.reshape(16, 2, 16, 2, 3).mean(axis=(1, 3)) * a + (1 - a)
  np.testing.assert_allclose(data.images[0, 3] / 255.0, want, atol=1.5 / 255)
  assert np.abs(data.images[0].astype(int) - plain.images[0].astype(int)).mean() > 1
  # Continuing the dataset at another scale is refused; a scale below 1 writes nothing.
  capsys.readouterr()
  _one_line_error(capsys, argv, "stylize_scale")
  bad = str(tmp_path / "bad")
  _one_line_error(capsys, argv[:-1] + [bad, "--stylize-scale", "0"], "--stylize-scale 0")
  assert not os.path.exists(bad)
  # A manifest holding a scale that is not a whole number is refused, naming the file.
  manifest_path = os.path.join(out, "manifest.json")
  manifest = json.load(open(manifest_path))
  manifest["stylize_scale"] = "4"
  json.dump(manifest, open(manifest_path, "w"))
  _one_line_error(capsys, ["multistyle", "train", "--nerf", world["nerf"], "--stylized", out,
                           "--out", str(tmp_path / "run")], "manifest.json", "stylize_scale")
  # A manifest written before the option existed reads as scale 1 (and can be continued).
  manifest_path = os.path.join(world["stylized"], "manifest.json")
  manifest = json.load(open(manifest_path))
  manifest.pop("stylize_scale")
  json.dump(manifest, open(manifest_path, "w"))
  assert cli.main(["stylize-scene", "--data", world["scene_dir"], "--decoder", world["decoder"],
                   "--styles", *world["styles"], "--include-original",
                   "--out", world["stylized"]]) == 0
  assert json.load(open(manifest_path))["stylize_scale"] == 1


def test_scene_stats_normalise_every_view_by_the_training_views(world, tmp_path, capsys):
  from msnerf_jax.style import transfer as stylize  # pylint: disable=g-import-not-at-top
  from msnerf_jax.data import images  # pylint: disable=g-import-not-at-top
  from msnerf_jax.models import vgg  # pylint: disable=g-import-not-at-top
  out = str(tmp_path / "scene")
  argv = ["stylize-scene", "--data", world["scene_dir"], "--decoder", world["decoder"],
          "--styles", world["styles"][0], "--stylize-scale", "2", "--out", out]
  assert cli.main(argv + ["--scene-stats"]) == 0
  assert json.load(open(os.path.join(out, "manifest.json")))["content_stats"] == "scene"
  scene, encoder = world["scene"], vgg.load_vgg_params()
  mean, std = stylize.scene_content_stats(encoder, scene.images[scene.split("train")], 2)
  saved = np.load(os.path.join(out, "content_stats.npy"))
  np.testing.assert_allclose(saved, np.concatenate([mean, std]), rtol=1e-6)
  # A val view (not among the views the statistics come from) is stylized with them.
  decoder, picture = stylized_scenes.load_decoder(world["decoder"]), images.read_image(world["styles"][0])
  view, a = scene.images[5], scene.alphas[5][..., None] / 255.0
  want = stylize.stylize_image(decoder, encoder, view, [picture], scale=2,
                               content_stats=(mean, std)) * a + (1 - a)
  got = load_stylized(out).images[0, 5] / 255.0
  np.testing.assert_allclose(got, want, atol=1.5 / 255)
  own = stylize.stylize_image(decoder, encoder, view, [picture], scale=2) * a + (1 - a)
  assert np.abs(got - own).mean() > 2 / 255
  # Continuing with per-view statistics is refused; so are unusable saved statistics.
  _one_line_error(capsys, argv, "content_stats")
  manifest_path = os.path.join(out, "manifest.json")
  manifest = json.load(open(manifest_path))
  manifest["done"] = []
  json.dump(manifest, open(manifest_path, "w"))
  missing = os.path.join(out, "red", "0002.png")
  os.remove(missing)
  np.save(os.path.join(out, "content_stats.npy"), np.concatenate([mean, -std]))
  _one_line_error(capsys, argv + ["--scene-stats"], "content_stats.npy", "standard deviation")
  assert not os.path.exists(missing)


def test_trunk_is_frozen_and_heads_train(world, trained):
  run, nerf_run = load_run(trained), load_run(world["nerf"])
  assert run.kind == "multistyle" and run.step == 3
  extra = {"rgb_extra_0", "density_extra_0"} if run.config.density_aware else set()
  assert {k for k in run.params["fine"] if "_extra_" in k} == extra
  for net in ("coarse", "fine"):
    got, want = leaves_with_paths(run.params[net]["trunk"]), leaves_with_paths(
        nerf_run.params[net]["trunk"])
    assert [p for p, _ in got] == [p for p, _ in want] and got
    for (path, a), (_, b) in zip(got, want):
      assert a.dtype == b.dtype and np.array_equal(a.view(np.uint32), b.view(np.uint32)), path
  initial = multistyle.init_state(run.config, nerf_run.params).params
  trainable, _ = multistyle.split_frozen(run.params)
  start, _ = multistyle.split_frozen(initial)
  for (path, a), (_, b) in zip(leaves_with_paths(trainable), leaves_with_paths(start)):
    assert not np.array_equal(a, np.asarray(b)), f"{path} did not change"
  # The checkpointed optimizer state holds nothing for the trunk.
  ckpts = checkpoint.Checkpoints(trained)
  raw = ckpts.restore()
  ckpts.close()
  opt_paths = [p for p, _ in leaves_with_paths(raw["opt_state"])]
  assert opt_paths and not any("trunk" in p for p in opt_paths)


def test_sweep_equals_separate_renders_and_interpolation_endpoints(world, trained):
  from msnerf_jax.style.vectors import blend  # pylint: disable=g-import-not-at-top
  run, scene = load_run(trained), world["scene"]
  vectors = multistyle_kind.style_vectors(run)
  a, b = vectors["red"], vectors["blue"]
  styles = np.stack([a, b, blend(a, b, 0.3)])
  c2w = scene.c2w[4]
  sweep = views.render_styles(scene, run.params, run.config, c2w, styles, chunk=64)
  for k in range(3):
    one = views.render_styles(scene, run.params, run.config, c2w, styles[k:k + 1], chunk=64)
    for key in ("rgb", "depth", "accumulation"):
      np.testing.assert_allclose(sweep[key][k], one[key][0], rtol=1e-4, atol=1e-5)
  assert np.array_equal(blend(a, b, 0.0), a) and np.array_equal(blend(a, b, 1.0), b)
  at0 = views.render_styles(scene, run.params, run.config, c2w, blend(a, b, 0.0), chunk=64)
  at1 = views.render_styles(scene, run.params, run.config, c2w, blend(a, b, 1.0), chunk=64)
  ends = views.render_styles(scene, run.params, run.config, c2w, np.stack([a, b]), chunk=64)
  # Same style vectors, same batch shape: bit-identical images at both ends.
  single_a = views.render_styles(scene, run.params, run.config, c2w, a, chunk=64)
  single_b = views.render_styles(scene, run.params, run.config, c2w, b, chunk=64)
  assert np.array_equal(at0["rgb"], single_a["rgb"]) and np.array_equal(at1["rgb"], single_b["rgb"])
  np.testing.assert_allclose(ends["rgb"][0], single_a["rgb"][0], atol=1e-5)
  assert float(np.abs(single_a["rgb"] - single_b["rgb"]).max()) > 1e-3


def test_eval_and_render_cli(trained_density, tmp_path, capsys):
  trained = trained_density
  assert cli.main(["multistyle", "eval", "--run", trained, "--chunk", "64"]) == 0
  out = capsys.readouterr().out
  for name in ("red", "blue", "original", "mean PSNR"):
    assert name in out
  metrics = json.load(open(os.path.join(trained, "eval_val", "metrics.json")))
  assert len(metrics["views"]) == 2 * 3
  assert os.path.exists(os.path.join(trained, "eval_val", "targets_vs_renders.png"))
  unseen = write_style(tmp_path / "green.png", (20, 200, 20))
  stem = str(tmp_path / "video")
  assert cli.main(["render", "--run", trained, "--out", stem, "--style", unseen, "--frames", "3",
                   "--grid-steps", "3", "--grid-views", "2", "--chunk", "64"]) == 0
  for suffix in (".mp4", ".gif", "_morph.mp4", "_morph.gif", "_grid.png"):
    assert os.path.getsize(stem + suffix) > 0, suffix
  grid = np.asarray(Image.open(stem + "_grid.png"))
  assert grid.shape[:2] == (2 * 16 + 2, 3 * 16 + 2 * 2)
  assert cli.main(["render", "--run", trained, "--out", stem + "2", "--style", "red",
                   "--strength", "0.5", "--frames", "2", "--morph", "red", "original",
                   "--chunk", "64"]) == 0
  assert "strength 0.5" in capsys.readouterr().out


# ----------------------------------------------------------------------------- bad input


def _one_line_error(capsys, argv, *needles):
  capsys.readouterr()
  assert cli.main(argv) == 2
  err = capsys.readouterr().err
  assert "Traceback" not in err, err
  err = err.replace("\r", "\n").strip().splitlines()[-1]  # after any progress bars
  assert err.startswith("msnerf: error:"), err
  for needle in needles:
    assert needle in err, err
  return err


def test_dataset_of_another_size_or_scene_is_refused(world, tmp_path, capsys):
  other = str(tmp_path / "small")
  assert cli.main(["stylize-scene", "--data", world["scene_dir"], "--decoder", world["decoder"],
                   "--styles", world["styles"][0], "--downscale", "2", "--out", other]) == 0
  out = str(tmp_path / "run")
  _one_line_error(capsys, ["multistyle", "train", "--nerf", world["nerf"], "--stylized", other,
                           "--out", out, "--steps", "1"], "8x8", "16x16")
  assert not os.path.exists(out)
  moved = str(tmp_path / "moved")
  scene2 = write_blender_scene(str(tmp_path / "scene2"), n_train=4, n_val=2, size=16,
                               rng=np.random.default_rng(1))
  meta = json.load(open(os.path.join(scene2, "transforms_train.json")))
  meta["frames"][0]["transform_matrix"][0][3] += 0.5
  json.dump(meta, open(os.path.join(scene2, "transforms_train.json"), "w"))
  assert cli.main(["stylize-scene", "--data", scene2, "--decoder", world["decoder"],
                   "--styles", world["styles"][0], "--out", moved]) == 0
  _one_line_error(capsys, ["multistyle", "train", "--nerf", world["nerf"], "--stylized", moved,
                           "--out", out, "--steps", "1"], "poses")


def test_nerf_run_of_another_architecture_is_refused(world, tmp_path, capsys):
  import shutil  # pylint: disable=g-import-not-at-top
  bad = str(tmp_path / "nerf")
  shutil.copytree(world["nerf"], bad)
  run_json = os.path.join(bad, "run.json")
  record = json.load(open(run_json))
  record["config"]["net_width"] = 64
  json.dump(record, open(run_json, "w"))
  _one_line_error(capsys, ["multistyle", "train", "--nerf", bad, "--stylized", world["stylized"],
                           "--out", str(tmp_path / "run"), "--steps", "1"],
                  "another architecture")


def test_negative_extra_layers_are_refused(world, tmp_path, capsys):
  out = str(tmp_path / "run")
  _one_line_error(capsys, ["multistyle", "train", "--nerf", world["nerf"], "--stylized",
                           world["stylized"], "--out", out, "--rgb-extra-layers", "-1"],
                  "--rgb-extra-layers -1")
  assert not os.path.exists(out)


def test_bad_style_loss_settings_are_refused(world, tmp_path, capsys):
  out = str(tmp_path / "run")
  base = ["multistyle", "train", "--nerf", world["nerf"], "--stylized", world["stylized"],
          "--out", out, "--steps", "1"]
  _one_line_error(capsys, base + ["--style-weight", "-1"], "--style-weight -1.0")
  _one_line_error(capsys, base + ["--style-weight", "1", "--style-patch", "8"], "--style-patch 8",
                  "16")
  _one_line_error(capsys, base + ["--style-weight", "1", "--style-patch", "17"], "style patch 17")
  assert not os.path.exists(out)


def test_unreadable_style_writes_nothing(world, tmp_path, capsys):
  broken = tmp_path / "broken.png"
  broken.write_bytes(open(world["styles"][0], "rb").read()[:40])
  out = str(tmp_path / "ds")
  _one_line_error(capsys, ["stylize-scene", "--data", world["scene_dir"], "--decoder",
                           world["decoder"], "--styles", world["styles"][0], str(broken),
                           "--out", out], "broken.png")
  assert not os.path.exists(out)


def test_unknown_style_name_at_render(trained_standard, tmp_path, capsys):
  trained = trained_standard
  _one_line_error(capsys, ["render", "--run", trained, "--out", str(tmp_path / "v"),
                           "--style", "nope"], "nope", "red")


# ----------------------------------------------------------------------------- devices


TWO_DEVICES = textwrap.dedent("""
    import os, sys
    os.environ["XLA_FLAGS"] = (os.environ.get("XLA_FLAGS", "")
                               + " --xla_force_host_platform_device_count=2")
    import jax, jax.numpy as jnp, numpy as np
    sys.path.insert(0, {tests!r})
    from msnerf_jax import load_run
    from msnerf_jax.data.scene import load_scene
    from msnerf_jax.data.stylized import load_stylized
    from msnerf_jax.core.config import DataConfig, MultistyleConfig
    from msnerf_jax.core.parallel import data_parallel
    from msnerf_jax.train import multistyle as ms
    assert jax.local_device_count() == 2
    nerf_run = load_run({nerf!r})
    data = load_stylized({stylized!r}, progress=False)
    scene, _ = load_scene(DataConfig(path={scene!r}))
    config = MultistyleConfig(nerf=nerf_run.config, batch_rays=32, style_hidden=32, style_hidden2=16,
                              density_aware={density_aware}, style_weight={style_weight},
                              style_patch=16, style_patches=2)
    encoder = None
    if config.style_weight > 0:
      from msnerf_jax.models import vgg
      encoder = vgg.load_vgg_params()
    images = jnp.asarray(np.moveaxis(data.images[:, :4], 0, 3))
    batch = ms.sample_batch(jax.random.PRNGKey(3), images, jnp.asarray(scene.c2w[:4]),
                            jnp.asarray(scene.K), config, scene)
    fresh = lambda: ms.init_state(config, nerf_run.params)
    assert ("patches" in batch) == (config.style_weight > 0)
    one, s1 = ms.compile_train_step(config, data.vectors, True, data_parallel(1), encoder)(
        fresh(), batch)
    dp = data_parallel(2)
    two, s2 = dp.to_host(ms.compile_train_step(config, data.vectors, True, dp, encoder)(
        dp.put_state(fresh()), dp.put_batch(batch)))
    start = fresh().params
    leaves = jax.tree_util.tree_leaves
    worst = max(float(np.max(np.abs(np.asarray(a) - np.asarray(b))))
                for a, b in zip(leaves(one.params), leaves(two.params)))
    moved = max(float(np.max(np.abs(np.asarray(a) - np.asarray(b))))
                for a, b in zip(leaves(one.params), leaves(start)))
    print("worst", worst, "moved", moved)
    assert moved > 1e-4 and worst < 1e-3 * moved, (worst, moved)
    assert abs(float(s1["loss"]) - float(s2["loss"])) < 1e-6
    if config.style_weight > 0:
      assert float(s1["style"]) > 0
      assert abs(float(s1["style"]) - float(s2["style"])) < 1e-4 * float(s1["style"])
""")


@pytest.mark.slow  # the NeRF trainer's two-device test stays in the default suite
@pytest.mark.parametrize("density_aware, style_weight", [(True, 0.0), (False, 0.01)])
def test_two_devices_give_the_same_update_as_one(world, density_aware, style_weight):
  code = TWO_DEVICES.format(tests=TESTS, nerf=world["nerf"], stylized=world["stylized"],
                            scene=world["scene_dir"], density_aware=density_aware,
                            style_weight=style_weight)
  result = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                          timeout=300)
  assert result.returncode == 0, result.stderr[-3000:]


def test_patches_are_whole_pixel_blocks_of_one_view_in_every_style(world):
  data = load_stylized(world["stylized"], progress=False)
  scene = world["scene"]
  config = multistyle.MultistyleConfig(nerf=load_run(world["nerf"]).config, style_weight=1.0,
                                       style_patch=5, style_patches=3)
  images = np.moveaxis(data.images[:, :4], 0, 3)  # [N, H, W, M, 3]
  patches = multistyle.sample_patches(jax.random.PRNGKey(0), jnp.asarray(images),
                                      jnp.asarray(scene.c2w[:4]), jnp.asarray(scene.K), config,
                                      scene)
  assert patches["rgb"].shape == (3, 5, 5, len(data.names), 3)
  assert patches["rays"]["origins"].shape == (3, 25, 3)
  assert patches["random"]["u_fine"].shape == (3, 25, config.nerf.n_fine)
  for p in range(3):
    rgb, directions = np.asarray(patches["rgb"][p]), np.asarray(patches["rays"]["directions"][p])
    found = [(v, r, c) for v in range(4) for r in range(12) for c in range(12)
             if np.array_equal(images[v, r:r + 5, c:c + 5], rgb) and np.allclose(
                 np.asarray(scene.camera_rays(scene.c2w[v])["directions"])[r:r + 5, c:c + 5]
                 .reshape(25, 3), directions, atol=1e-6)]
    assert found, f"patch {p} is not a 5x5 block of one view (same pixels and rays)"


@pytest.mark.slow
def test_style_loss_pulls_the_heads_and_resumes_bit_identically(world, tmp_path):
  data = load_stylized(world["stylized"], progress=False)
  nerf_run = load_run(world["nerf"])
  config = multistyle.MultistyleConfig(nerf=nerf_run.config, batch_rays=32, style_hidden=32,
                                       style_hidden2=16, style_weight=1.0, style_patch=16)
  from msnerf_jax.models import vgg  # pylint: disable=g-import-not-at-top
  encoder = vgg.load_vgg_params()
  scene = world["scene"]
  batch = multistyle.sample_batch(
      jax.random.PRNGKey(1), jnp.asarray(np.moveaxis(data.images[:, :4], 0, 3)),
      jnp.asarray(scene.c2w[:4]), jnp.asarray(scene.K), config, scene)
  trainable, frozen = multistyle.split_frozen(multistyle.init_state(config, nerf_run.params).params)
  field = MultistyleField(config)

  def style_only(heads):
    return multistyle.patch_style_loss(field, multistyle.merge(heads, frozen), batch["patches"],
                                       jnp.asarray(data.vectors), encoder, config, True)

  value, grads = jax.value_and_grad(style_only)(trainable)
  assert np.isfinite(float(value)) and float(value) > 0
  # The style loss reaches every head of the fine network that renders the patches.
  for path, g in leaves_with_paths(grads["fine"]):
    assert np.any(g != 0), f"no style gradient for fine {path}"
  # Training with it: a run stopped after 2 steps and resumed to 4 equals 4 steps at once.
  argv = ["multistyle", "train", "--nerf", world["nerf"], "--stylized", world["stylized"],
          "--batch-rays", "32", "--checkpoint-every", "2", "--style-weight", "0.5",
          "--style-patch", "16"]
  split, whole = str(tmp_path / "split"), str(tmp_path / "whole")
  assert cli.main(argv + ["--out", split, "--steps", "2"]) == 0
  assert cli.main(argv + ["--out", split, "--steps", "4"]) == 0
  assert cli.main(argv + ["--out", whole, "--steps", "4"]) == 0
  a, b = load_run(split), load_run(whole)
  assert a.step == b.step == 4 and a.config.style_weight == 0.5
  for (path, x), (_, y) in zip(leaves_with_paths(a.params), leaves_with_paths(b.params)):
    assert np.array_equal(x.view(np.uint32), y.view(np.uint32)), path


@pytest.fixture(scope="module")
def single_red(world):
  """A NeRF trained 4 steps on the 'red' views of the stylized dataset (the baseline)."""
  from msnerf_jax.data.stylized import style_views  # pylint: disable=g-import-not-at-top
  run = str(world["root"] / "single_red")
  scene, data = load_scene(DataConfig(path=world["scene_dir"]))
  style = {"stylized": world["stylized"], "name": "red"}
  nerf.train(style_views(world["stylized"], "red", scene), override(TINY, steps=4),
             data, run, progress=False, style=style)
  return run


def test_single_style_nerf_trains_on_the_style_views(world, single_red):
  run = load_run(single_red)
  scene, _ = runs.scene_of(run)
  assert run.kind == "nerf" and run.record["style"]["name"] == "red"
  for i in (0, 5):
    view = np.asarray(Image.open(os.path.join(world["stylized"], "red", f"{i:04d}.png")))
    np.testing.assert_array_equal(np.round(scene.images[i] * 255).astype(np.uint8), view[..., :3])
  np.testing.assert_array_equal(scene.c2w, world["scene"].c2w)
  assert float(np.abs(scene.images - world["scene"].images).max()) > 0.1


def test_evaluate_cli_writes_tables(trained_standard, trained_density, single_red, tmp_path,
                                    capsys):
  out = str(tmp_path / "eval")
  assert cli.main(["evaluate", "--run", trained_standard, trained_density, "--single-style",
                   single_red, "--frames", "9", "--chunk", "64", "--out", out]) == 0
  rows = json.load(open(os.path.join(out, "results.json")))
  assert [(r["style"], r["method"]) for r in rows] == [
      ("red", "multistyle"), ("red", "multistyle-density"), ("red", "nerf-single-style"),
      ("red", "adain-per-frame"), ("blue", "multistyle"), ("blue", "multistyle-density"),
      ("blue", "adain-per-frame")]
  for row in rows:
    for key in ("rmse_k1", "rmse_k7", "lpips_k1", "style_adain", "style_gram"):
      assert np.isfinite(row[key]) and row[key] >= 0, (key, row)
  # The three 3D methods differ from each other (different models), not only from AdaIN.
  assert len({round(r["style_adain"], 6) for r in rows[:3]}) == 3
  assert open(os.path.join(out, "results.md")).read().startswith("| method")
  assert os.path.getsize(os.path.join(out, "frames.png")) > 0
  printed = capsys.readouterr().out
  assert "adain-per-frame" in printed and "nerf-single-style" in printed


def test_single_style_bad_input(world, trained_standard, tmp_path, capsys):
  out = str(tmp_path / "run")
  base = ["nerf", "train", "--data", world["scene_dir"], "--out", out, "--steps", "1"]
  _one_line_error(capsys, base + ["--stylized", world["stylized"]], "--style")
  _one_line_error(capsys, base + ["--stylized", world["stylized"], "--style", "green"],
                  "green", "red, blue, original")
  assert not os.path.exists(out)
  _one_line_error(capsys, ["evaluate", "--run", trained_standard, "--single-style", world["nerf"],
                           "--out", str(tmp_path / "e")], world["nerf"], "single-style")
  _one_line_error(capsys, ["evaluate", "--run", world["nerf"], "--out", str(tmp_path / "e")],
                  "not a 'multistyle' run")
