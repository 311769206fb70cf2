"""Painted colour fields: the cached render, deferred back-propagation, the trainer's
promises (frozen NeRF, independent styles, resume, devices) and its bad input."""

import dataclasses
import os
import subprocess
import sys
import textwrap
import types

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from PIL import Image

import msnerf_jax
from msnerf_jax import cli
from msnerf_jax.core.config import MIN_CROP, DataConfig, PaintConfig, override
from msnerf_jax.data.scene import load_scene
from msnerf_jax.kinds import painted as painted_kind
from msnerf_jax.kinds.renderers import style_rendering
from msnerf_jax.models.nerf import NerfField
from msnerf_jax.models.painted_field import PaintedField, corners, trilinear
from msnerf_jax.nerf import render as render_lib
from msnerf_jax.nerf import sample_cache
from msnerf_jax.style import painting_loss
from msnerf_jax.train import nerf, paint, paint_data, paint_grid
from msnerf_jax.train.paint_coverage import nearest_seen, seen_vertices

from conftest import write_blender_scene
from test_fast_trunk import TINY_FAST
from test_multistyle import write_style
from test_train_nerf import TINY

TINY_PAINT = override(PaintConfig(), resolution=12, steps=4, init_steps=2, style_size=32,
                      checkpoint_every=2, path_views=3)
PAINT_ARGS = ["--resolution", "12", "--steps", "4", "--init-steps", "2", "--style-size", "32",
              "--checkpoint-every", "2", "--path-views", "3"]


def leaves(tree):
  return jax.tree_util.tree_leaves(tree)


def dense_paint(key, n_styles, resolution):
  """Random colour logits at every vertex of a resolution^3 grid (all painted)."""
  index = np.arange(resolution ** 3, dtype=np.int32).reshape((resolution,) * 3)
  return {"colours": jax.random.normal(key, (n_styles, resolution ** 3 + 1, 3)),
          "index": jnp.asarray(index)}


@pytest.fixture(scope="module")
def paint_world(tmp_path_factory):
  """A tiny scene (24 x 24), a fast NeRF and an MLP one (6 steps each), two styles, and a
  painted run on the fast NeRF made through the CLI."""
  root = tmp_path_factory.mktemp("paint")
  scene_dir = write_blender_scene(str(root / "scene"), n_train=4, n_val=2, size=24)
  scene, data = load_scene(DataConfig(path=scene_dir))
  runs = {}
  for name, config in (("fast", TINY_FAST), ("mlp", TINY)):
    runs[name] = str(root / name)
    nerf.train(scene, config, data, runs[name], progress=False)
  styles = [write_style(root / f"{n}.png", c) for n, c in (("red", (200, 40, 40)),
                                                            ("blue", (40, 40, 200)))]
  run = str(root / "painted")
  assert cli.main(["paint", "train", "--nerf", runs["fast"], "--styles", *styles, "--out", run]
                  + PAINT_ARGS) == 0
  return {"root": root, "scene_dir": scene_dir, "scene": scene, "nerfs": runs,
          "styles": styles, "run": run}


# ----------------------------------------------------------------------------- the cache


@pytest.mark.parametrize("sampler", ["fast", "mlp"])
def test_the_cached_render_equals_the_full_render(paint_world, sampler):
  scene, source = paint_world["scene"], msnerf_jax.load_run(paint_world["nerfs"][sampler])
  field = PaintedField(1.5)
  params = dense_paint(jax.random.PRNGKey(0), 2, 8)
  rays = scene.camera_rays(1)
  full = render_lib.render_feature_image(NerfField(source.config), field,
                                         {"nerf": source.params, "features": params}, rays,
                                         source.config, 4)
  top_k = 4 if sampler == "mlp" else 4096  # the grid sampler's cache: no cap here
  cache = sample_cache.view_samples(NerfField(source.config), source.params, rays,
                                    source.config, top_k=top_k, threshold=0.0)
  cached = sample_cache.cached_render(lambda p: field.colours(params, p),
                                      jax.tree_util.tree_map(jnp.asarray, cache))
  want = full["features"].reshape(-1, 2, 3).transpose(1, 0, 2)
  assert float(np.max(full["accumulation"])) > 0.05  # the view sees something
  np.testing.assert_allclose(np.asarray(cached), want, atol=1e-5)
  np.testing.assert_allclose(cache["accumulation"], full["accumulation"].reshape(-1), atol=1e-5)
  middle = float(np.median(cache["weights"]))
  kept = sample_cache.view_samples(NerfField(source.config), source.params, rays,
                                   source.config, top_k=4, threshold=middle)
  assert kept["weights"].size < cache["weights"].size and np.all(kept["weights"] > middle)


def test_a_capped_cache_keeps_each_pixels_heaviest_samples_and_its_opacity(paint_world):
  scene, source = paint_world["scene"], msnerf_jax.load_run(paint_world["nerfs"]["fast"])
  rays = scene.camera_rays(1)
  view = lambda k: sample_cache.view_samples(NerfField(source.config), source.params, rays,
                                             source.config, top_k=k, threshold=0.0)
  whole, capped = view(4096), view(2)
  counts = np.bincount(whole["pixel"])
  assert counts.max() > 2  # the cap binds on some pixels
  assert np.bincount(capped["pixel"]).max() <= 2 and capped["weights"].size < whole["weights"].size
  np.testing.assert_allclose(capped["accumulation"], whole["accumulation"], rtol=1e-5, atol=1e-7)
  assert np.all(np.diff(capped["pixel"]) >= 0)  # still pixel-major
  for pixel in np.flatnonzero(counts > 2)[:20]:
    mine, all_ = capped["pixel"] == pixel, whole["pixel"] == pixel
    heaviest = np.sort(whole["weights"][all_])[-2:]
    kept = np.sort(capped["weights"][mine])
    # the pixel's two heaviest samples, scaled to carry the whole pixel's weight
    np.testing.assert_allclose(kept, heaviest * whole["weights"][all_].sum() / heaviest.sum(),
                               rtol=1e-5)
    assert {tuple(p) for p in capped["points"][mine]} <= {tuple(p) for p in whole["points"][all_]}
  small = {"points": whole["points"][:5], "weights": whole["weights"][:5],
           "pixel": np.arange(5, dtype=np.int32)}
  assert sample_cache.cap_samples(small, 1, 5) is small  # nothing to cap: as it was


def test_packed_views_render_under_vmap_as_one_by_one(paint_world):
  source = msnerf_jax.load_run(paint_world["nerfs"]["fast"])
  scene = paint_world["scene"]
  views = [sample_cache.view_samples(NerfField(source.config), source.params,
                                     scene.camera_rays(i), source.config) for i in range(3)]
  packed = jax.tree_util.tree_map(jnp.asarray, sample_cache.pack_views(views, multiple=64))
  paint_params = dense_paint(jax.random.PRNGKey(1), 1, 8)
  colour = lambda p: jax.nn.sigmoid(trilinear(paint_params["colours"], paint_params["index"],
                                              p, 1.5))[0]
  white = jnp.ones(3)
  batched = jax.vmap(lambda v: sample_cache.cached_render(colour, v, white))(packed)
  for i, view in enumerate(views):
    one = sample_cache.cached_render(colour, jax.tree_util.tree_map(jnp.asarray, view), white)
    np.testing.assert_allclose(np.asarray(batched[i]), np.asarray(one), atol=1e-6)


def test_deferred_back_propagation_gives_the_direct_gradient(paint_world):
  source = msnerf_jax.load_run(paint_world["nerfs"]["fast"])
  scene = paint_world["scene"]
  cache = jax.tree_util.tree_map(jnp.asarray, sample_cache.view_samples(
      NerfField(source.config), source.params, scene.camera_rays(0), source.config,
      threshold=0.0))
  start = dense_paint(jax.random.PRNGKey(2), 1, 8)
  params, index = start["colours"], start["index"]
  target = jnp.asarray(scene.images[0]).reshape(-1, 3)
  loss = lambda image: jnp.mean(jnp.square(image[0] - target) * (1.0 + target))
  colours = lambda p, points: PaintedField(1.5).colours({"colours": p, "index": index}, points)
  bg = jnp.ones(3)
  direct = jax.grad(lambda p: loss(sample_cache.cached_render(
      lambda x: colours(p, x), cache, bg)))(params)
  assert cache["weights"].shape[0] > 100  # several chunks below
  value, deferred = jax.jit(lambda p: sample_cache.deferred_grad(loss, colours, p, cache, bg,
                                                                 chunk=64))(params)
  assert float(jnp.max(jnp.abs(direct))) > 1e-6
  np.testing.assert_allclose(deferred, direct, atol=1e-5)
  assert np.isfinite(float(value))


# ----------------------------------------------------------------------------- the losses


def test_nnfm_is_zero_on_the_styles_own_features_and_positive_elsewhere():
  rng = np.random.default_rng(0)
  style = jnp.asarray(rng.normal(size=(50, 16)), jnp.float32)
  unit = style / jnp.linalg.norm(style, axis=-1, keepdims=True)
  assert float(painting_loss.nnfm(3.0 * style[10:20], unit)) < 1e-6  # scale-free
  assert float(painting_loss.nnfm(jnp.asarray(rng.normal(size=(10, 16)), jnp.float32), unit)) > 0.1


# ----------------------------------------------------------------------------- the trainer


def test_the_nerf_is_bit_identical_and_has_no_optimizer_state(paint_world):
  from msnerf_jax.core import checkpoint  # pylint: disable=g-import-not-at-top
  run = msnerf_jax.load_run(paint_world["run"])
  source = msnerf_jax.load_run(paint_world["nerfs"]["fast"])
  assert run.kind == "painted" and set(run.params) == {"nerf", "paint"}
  index, colours = run.params["paint"]["index"], run.params["paint"]["colours"]
  assert index.shape == (12, 12, 12) and colours.shape[0] == 2 and colours.shape[2] == 3
  assert index.max() == colours.shape[1] - 1 or index.max() == colours.shape[1] - 2
  assert run.record["styles"] == ["red", "blue"]
  for a, b in zip(leaves(run.params["nerf"]), leaves(source.params)):
    assert np.array_equal(np.asarray(a).view(np.uint32), np.asarray(b).view(np.uint32))
  assert np.any(colours[:, :-1] != 0) and np.all(colours[:, -1] == 0)  # unpainted: untouched
  ckpts = checkpoint.Checkpoints(paint_world["run"])
  raw = ckpts.restore()
  ckpts.close()
  paths = [jax.tree_util.keystr(p) for p, _ in jax.tree_util.tree_leaves_with_path(raw["opt_state"])]
  assert paths and all("nerf" not in p for p in paths) and any("colours" in p for p in paths)
  assert all("index" not in p for p in paths)


@pytest.mark.slow  # a painting of its own (the default suite stays short)
def test_the_init_fit_moves_each_style_towards_its_colours(paint_world, tmp_path):
  """After the MSE fit to the colour-transferred photos, the red style renders redder than
  the blue one, and the blue one bluer."""
  run_dir = str(tmp_path / "init")
  paint.train(override(TINY_PAINT, steps=30, init_steps=30, lr_init=0.2, lr_final=0.1,
                       checkpoint_every=30),
              paint_world["nerfs"]["fast"], paint_world["styles"], run_dir, progress=False)
  run = msnerf_jax.load_run(run_dir)
  rgb = painted_kind.render_painted(paint_world["scene"], run.params, run.config, 0)["rgb"]
  acc = painted_kind.render_painted(paint_world["scene"], run.params, run.config, 0)["accumulation"]
  mask = acc > 0.5
  assert mask.sum() > 10
  red, blue = rgb[0][mask].mean(0), rgb[1][mask].mean(0)
  assert red[0] - red[2] > 0.1 and blue[2] - blue[0] > 0.1


def test_k_styles_render_in_one_call_as_k_single_styles_and_blend_as_colours(paint_world):
  run = msnerf_jax.load_run(paint_world["run"])
  scene = paint_world["scene"]
  both = painted_kind.render_painted(scene, run.params, run.config, 1)["rgb"]
  for m in range(2):
    single = {"nerf": run.params["nerf"],
              "paint": {**run.params["paint"], "colours": run.params["paint"]["colours"][m:m + 1]}}
    one = painted_kind.render_painted(scene, single, run.config, 1)["rgb"]
    np.testing.assert_allclose(one[0], both[m], atol=1e-6)
  table, size, render = style_rendering(run, scene)
  assert size is None and list(table) == ["red", "blue", "original"]
  half = 0.5 * table["red"] + 0.5 * table["blue"]
  out = render(1, [table["red"], half])
  np.testing.assert_allclose(out[0], both[0], atol=1e-6)
  np.testing.assert_allclose(out[1], 0.5 * (both[0] + both[1]), atol=1e-5)
  photo = render(1, [table["original"]])[0]  # the NeRF's own colours
  nerf_view = msnerf_jax.api.render_image(NerfField(run.config.nerf), run.params["nerf"],
                                          scene.camera_rays(1), run.config.nerf, True)["rgb"]
  np.testing.assert_allclose(photo, nerf_view, atol=1e-6)


@pytest.mark.slow  # a painting of its own (the default suite stays short)
def test_a_style_paints_the_same_in_a_run_of_one_style(paint_world, tmp_path):
  """Per-style grids: a style's colours in a run of M styles are those of a run of that
  style alone (its pairs come from its own name, its gradient from its own pairs)."""
  single = str(tmp_path / "single")
  paint.train(TINY_PAINT, paint_world["nerfs"]["fast"], paint_world["styles"][1:], single,
              progress=False)
  both = msnerf_jax.load_run(paint_world["run"]).params["paint"]["colours"]
  one = msnerf_jax.load_run(single).params["paint"]["colours"]
  # (to float rounding: VGG runs on a batch of 4 images there, of 2 here)
  np.testing.assert_allclose(one[0], both[1], atol=1e-4)


@pytest.mark.slow  # a painting of its own (the default suite stays short)
def test_a_resumed_painting_ends_bit_identical(paint_world, tmp_path):
  split = str(tmp_path / "split")
  nerf_run = paint_world["nerfs"]["fast"]
  paint.train(override(TINY_PAINT, steps=2), nerf_run, paint_world["styles"], split,
              progress=False)
  assert paint.train(TINY_PAINT, nerf_run, paint_world["styles"], split,
                     progress=False)["resumed_from"] == 2
  a = msnerf_jax.load_run(paint_world["run"]).params["paint"]["colours"]
  b = msnerf_jax.load_run(split).params["paint"]["colours"]
  np.testing.assert_array_equal(a, b)


TWO_DEVICES = textwrap.dedent("""
    import os, sys
    os.environ["XLA_FLAGS"] = (os.environ.get("XLA_FLAGS", "")
                               + " --xla_force_host_platform_device_count=2")
    import dataclasses, jax, numpy as np
    sys.path.insert(0, {tests!r})
    from test_paint import TINY_PAINT
    from msnerf_jax.train import paint
    import msnerf_jax
    grids = []
    for n, out in ((1, {one!r}), (2, {two!r})):
      paint.train(TINY_PAINT, {nerf!r}, {styles!r}, out, n_devices=n, progress=False)
      run = msnerf_jax.load_run(out)
      grids.append(run.params["paint"]["colours"])
    print("worst", float(np.max(np.abs(grids[0] - grids[1]))))
    # The same steps to float rounding (VGG sees 4 images on one device, 2 on each of two).
    assert float(np.max(np.abs(grids[0]))) > 0.01
    np.testing.assert_allclose(grids[0], grids[1], atol=1e-4)
""")


@pytest.mark.slow  # a subprocess with two compilations
def test_two_devices_paint_as_one(paint_world, tmp_path):
  code = TWO_DEVICES.format(tests=os.path.dirname(os.path.abspath(__file__)),
                            nerf=paint_world["nerfs"]["fast"], styles=paint_world["styles"],
                            one=str(tmp_path / "one"), two=str(tmp_path / "two"))
  result = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                          timeout=600)
  assert result.returncode == 0, result.stdout + result.stderr[-3000:]


def test_msnerf_render_writes_a_painted_runs_videos(paint_world, tmp_path):
  out = str(tmp_path / "video")
  assert cli.main(["render", "--run", paint_world["run"], "--out", out, "--style", "blue",
                   "--frames", "3", "--grid-views", "2"]) == 0
  assert os.path.getsize(out + ".mp4") > 0 and os.path.exists(out + "_grid.png")


# ----------------------------------------------------------------------------- bad input


def _animated(path):
  frames = [Image.new("RGB", (32, 32), c) for c in ((255, 0, 0), (0, 0, 255))]
  frames[0].save(path, save_all=True, append_images=frames[1:])
  return str(path)


@pytest.mark.parametrize("bad", ["missing", "folder", "tiny", "animated", "text", "none"])
def test_bad_styles_get_one_line_and_write_nothing(paint_world, tmp_path, capsys, bad):
  folder = tmp_path / "folder"
  folder.mkdir()
  tiny = tmp_path / "tiny.png"
  Image.new("RGB", (1, 1)).save(tiny)
  text = tmp_path / "text.jpg"
  text.write_text("not an image")
  style = {"missing": [str(tmp_path / "no.jpg")], "folder": [str(folder)],
           "tiny": [str(tiny)], "animated": [_animated(tmp_path / "anim.gif")],
           "text": [str(text)], "none": []}[bad]
  out = tmp_path / "out"
  assert cli.main(["paint", "train", "--nerf", paint_world["nerfs"]["fast"], "--styles",
                   *style, "--out", str(out)] + PAINT_ARGS) == 2
  err = capsys.readouterr().err.strip().splitlines()
  assert len(err) == 1 and err[0].startswith("msnerf: error: "), err
  want = {"missing": "no such file", "folder": "is a folder", "tiny": "need at least 16x16",
          "animated": "animated", "text": "not an image", "none": "--styles"}[bad]
  assert want in err[0]
  assert not out.exists()


def test_a_nerf_run_of_another_kind_is_refused(paint_world, tmp_path, capsys):
  out = tmp_path / "out"
  assert cli.main(["paint", "train", "--nerf", paint_world["run"], "--styles",
                   paint_world["styles"][0], "--out", str(out)] + PAINT_ARGS) == 2
  assert "a 'painted' run, not a 'nerf' run" in capsys.readouterr().err
  assert not out.exists()


def test_a_cache_from_another_nerf_run_is_refused(paint_world, tmp_path, capsys):
  out = tmp_path / "moved"
  assert cli.main(["paint", "train", "--nerf", paint_world["nerfs"]["fast"], "--styles",
                   *paint_world["styles"], "--out", str(out)] + PAINT_ARGS
                  + ["--steps", "2"]) == 0
  cache_path = os.path.join(str(out), paint_data.CACHE_FILE)
  with np.load(cache_path) as saved:
    cache = {k: saved[k] for k in saved.files}
  cache["nerf_run"] = np.array("/elsewhere/nerf@6")
  with open(cache_path, "wb") as f:
    np.savez(f, **cache)
  capsys.readouterr()
  before = {n: os.path.getmtime(os.path.join(str(out), n)) for n in os.listdir(out)}
  assert cli.main(["paint", "train", "--nerf", paint_world["nerfs"]["fast"], "--styles",
                   *paint_world["styles"], "--out", str(out)] + PAINT_ARGS) == 2
  err = capsys.readouterr().err
  assert "made from the NeRF run /elsewhere/nerf@6" in err and err.count("\n") == 1
  assert msnerf_jax.load_run(str(out)).step == 2
  assert {n: os.path.getmtime(os.path.join(str(out), n)) for n in os.listdir(out)
          if n in before and n != "trainer.lock"} == {n: t for n, t in before.items()
                                                      if n != "trainer.lock"}


# ----------------------------------------------------------------------------- coverage


def test_unseen_vertices_map_to_the_nearest_seen_one():
  index = np.full((5, 5, 5), 4, np.int32)  # four painted vertices in a row, V = 4
  index[0, 0, 0], index[0, 0, 1], index[0, 0, 3], index[0, 0, 4] = 0, 1, 2, 3
  seen = np.array([True, False, False, True, False])
  np.testing.assert_array_equal(nearest_seen(index, seen), [0, 0, 3, 3, 4])
  np.testing.assert_array_equal(nearest_seen(index, np.zeros(5, bool)), np.arange(5))


def test_a_painting_covers_its_camera_path_and_leaves_no_unseen_vertex_grey(paint_world):
  run = msnerf_jax.load_run(paint_world["run"])
  nerf_run = msnerf_jax.load_run(paint_world["nerfs"]["fast"])
  scene = paint_world["scene"]
  cache = paint_data.read_cache(os.path.join(paint_world["run"], paint_data.CACHE_FILE),
                                paint_data.cache_source(nerf_run))
  index = np.asarray(run.params["paint"]["index"])
  colours = np.asarray(run.params["paint"]["colours"])
  count, box = colours.shape[1] - 1, run.config.scene_box
  views, photos = paint_data.painting_views(cache, scene, nerf_run, run.config)
  n_train = len(scene.split("train"))
  assert len(photos) == n_train + run.config.path_views
  assert views["weights"].shape[0] == len(photos)
  for points, weights in zip(views["points"][n_train:], views["weights"][n_train:]):
    points = points[weights > 0]  # what a path camera's render keeps
    assert np.all(index.reshape(-1)[corners(points, index.shape[0], box, np)[0]] < count)
  seen = seen_vertices(views, index, count, box)
  assert seen.sum() >= seen_vertices(cache, index, count, box).sum()  # path views count
  unseen = np.nonzero(~seen[:-1])[0]
  assert 0 < len(unseen) < count  # the index's margin: vertices no view weighs
  source = nearest_seen(index, seen)
  assert seen[source[unseen]].all()
  np.testing.assert_array_equal(colours[:, unseen], colours[:, source[unseen]])


def test_a_painting_starts_at_the_weighted_mean_of_the_photo_colours_moved_to_each_style():
  index = np.arange(8, dtype=np.int32).reshape(2, 2, 2)  # one cell, 8 painted vertices
  point = np.zeros((1, 3), np.float32)  # the cell's centre: 1/8 to each vertex
  cache = {"points": np.stack([point, point]), "weights": np.array([[0.9], [0.3]], np.float32),
           "pixel": np.zeros((2, 1), np.int32)}
  photos = np.array([[1.0, 0.2, 0.0], [0.0, 0.2, 1.0]], np.float32).reshape(2, 1, 1, 3)
  swap = jnp.eye(3)[::-1]  # style 1 swaps red and blue
  maps = {"transform": jnp.stack([jnp.eye(3), swap]), "mu_s": jnp.zeros((2, 3)),
          "mu_t": jnp.zeros((2, 3))}
  fill, logits = paint_data.starting_colours(cache, photos, maps, index, 8, 1.0)
  np.testing.assert_array_equal(fill, np.arange(9))
  mean = np.array([0.75, 0.2, 0.25])  # 0.9 : 0.3 of the two views' pixel colours
  np.testing.assert_allclose(jax.nn.sigmoid(logits[0, :8]), np.tile(mean, (8, 1)), atol=1e-5)
  np.testing.assert_allclose(jax.nn.sigmoid(logits[1, :8]), np.tile(mean[::-1], (8, 1)),
                             atol=1e-5)
  np.testing.assert_array_equal(logits[:, 8], 0.0)  # the unpainted row stays grey


def test_a_paintings_start_reproduces_the_colour_transferred_photos(paint_world):
  run = msnerf_jax.load_run(paint_world["run"])
  nerf_run = msnerf_jax.load_run(paint_world["nerfs"]["fast"])
  scene, config = paint_world["scene"], run.config
  cache = paint_data.read_cache(os.path.join(paint_world["run"], paint_data.CACHE_FILE),
                                paint_data.cache_source(nerf_run))
  index = np.asarray(run.params["paint"]["index"])
  count = run.params["paint"]["colours"].shape[1] - 1
  styles = painted_kind.style_images(run)
  cache, photos = paint_data.painting_views(cache, scene, nerf_run, config)
  maps = paint_data.style_maps(scene, cache, photos, styles, config)
  fill, start = paint_data.starting_colours(cache, photos, maps, index, count,
                                            config.scene_box)
  consts = paint_data.constants(scene, cache, photos, styles, config, fill, maps)
  views = jnp.repeat(jnp.arange(len(photos)), 2)
  pairs = jnp.tile(jnp.arange(2), len(photos))
  targets = paint.photo_targets(consts, views, pairs, scene.white_background)
  error = lambda colours: float(jnp.mean(jnp.square(paint.render_pairs(
      {"colours": jnp.asarray(colours), "index": jnp.asarray(index)}, consts["cache"], views,
      pairs, config.scene_box, consts["background"]).reshape(targets.shape) - targets)))
  assert error(start) < 0.5 * error(np.zeros_like(start))  # far closer than grey


def test_the_grid_is_fitted_to_the_samples_weight_and_the_pixels_size():
  rng = np.random.default_rng(0)
  points = rng.uniform(-1.0, 1.0, (1, 2000, 3)).astype(np.float32)
  points[0, 0] = (3.0, 0.0, 0.0)  # far, but carrying a sliver of the weight
  weights = np.ones((1, 2000), np.float32)
  weights[0, 0] = 1e-4
  cache = {"points": points, "weights": weights}
  box = paint_grid.fitted_box(cache, limit=5.0)
  assert 0.95 * paint_grid.BOX_MARGIN < box <= paint_grid.BOX_MARGIN  # the far point is out
  weights[0, 0] = 10.0  # now it carries 0.5% of the weight: in
  assert paint_grid.fitted_box(cache, 5.0) == pytest.approx(3.0 * paint_grid.BOX_MARGIN)
  assert paint_grid.fitted_box(cache, limit=0.5) == 0.5
  # A 6 x 8 view of the plane z = 0, pixels 0.01 apart, two samples a pixel.
  rows, cols = np.mgrid[0:6, 0:8]
  centre = np.stack([cols * 0.01, rows * 0.01, np.zeros_like(rows)], -1).reshape(-1, 3)
  view = {"points": np.concatenate([centre, centre])[None].astype(np.float32),
          "weights": np.full((1, 96), 0.5, np.float32),
          "pixel": np.tile(np.arange(48), 2)[None], "accumulation": np.ones((1, 48))}
  assert paint_grid.pixel_footprint(view, width=8) == pytest.approx(0.01)
  assert paint_grid.fitted_resolution(1.0, 0.01) == 201
  assert paint_grid.fitted_resolution(1.0, 0.1) == paint_grid.MIN_RESOLUTION
  assert paint_grid.fitted_resolution(9.0, 0.01) == paint_grid.MAX_RESOLUTION


def test_a_fitted_grid_is_recorded_and_kept_when_the_run_resumes(paint_world, tmp_path, capsys):
  out = str(tmp_path / "fitted")
  args = ["paint", "train", "--nerf", paint_world["nerfs"]["fast"], "--styles",
          paint_world["styles"][0], "--out", out, "--init-steps", "1"]
  assert cli.main(args + ["--steps", "1"]) == 0
  run = msnerf_jax.load_run(out)
  nerf_box = msnerf_jax.load_run(paint_world["nerfs"]["fast"]).config.scene_box
  assert 0 < run.config.scene_box <= nerf_box
  assert paint_grid.MIN_RESOLUTION <= run.config.resolution <= paint_grid.MAX_RESOLUTION
  assert np.shape(run.params["paint"]["index"]) == (run.config.resolution,) * 3
  scene = paint_world["scene"]  # the style images at the views' longer side (MIN_CROP at least)
  assert run.config.style_size == max(scene.height, scene.width, MIN_CROP)
  assert paint_data.style_size(PaintConfig(), scene) == run.config.style_size
  big = types.SimpleNamespace(height=378, width=504)  # fern at factor 8
  assert paint_data.style_size(PaintConfig(), big) == paint_data.MAX_STYLE_SIZE
  assert paint_data.style_size(override(PaintConfig(), style_size=300), big) == 300
  side = run.config.style_size
  assert painted_kind.style_images(run).shape == (1, side, side, 3)
  assert cli.main(args + ["--steps", "2"]) == 0  # the same options resume it
  again = msnerf_jax.load_run(out)
  assert again.step == 2
  assert (again.config.scene_box, again.config.resolution, again.config.style_size) == (
      run.config.scene_box, run.config.resolution, run.config.style_size)
  capsys.readouterr()
  assert cli.main(args + ["--steps", "3", "--resolution", "12"]) == 2  # another grid: refused
  assert "another config" in capsys.readouterr().err


# ----------------------------------------------------------------------------- a new style


def test_each_vertex_takes_its_colour_from_one_key_view_never_an_average():
  from msnerf_jax.train.paint_add import lift_key_views  # pylint: disable=g-import-not-at-top
  index = np.arange(8, dtype=np.int32).reshape(2, 2, 2)  # one cell, 8 painted vertices
  point = np.zeros((1, 3), np.float32)  # the cell's centre: 1/8 to each vertex
  cache = {"points": np.stack([point, point]), "weights": np.array([[0.9], [0.3]], np.float32),
           "pixel": np.zeros((2, 1), np.int32)}
  red, blue = np.array([[1.0, 0.0, 0.0]]), np.array([[0.0, 0.0, 1.0]])
  out = lift_key_views(cache, [0, 1], np.stack([red, blue]), index, 8, 1.0)
  np.testing.assert_allclose(out["colours"][:8], np.repeat(red, 8, 0))  # the heavier view's
  assert out["seen"][:8].all() and not out["seen"][8]
  out = lift_key_views(cache, [1, 0], np.stack([blue, red]), index, 8, 1.0)  # order-free
  np.testing.assert_allclose(out["colours"][:8], np.repeat(red, 8, 0))


def test_vertices_no_key_view_sees_are_filled_from_painted_neighbours():
  from msnerf_jax.train.paint_add import fill_from_neighbours  # pylint: disable=g-import-not-at-top
  index = np.full((4, 4, 4), 3, np.int32)  # three painted vertices in a row, V = 3
  index[1, 1, 0], index[1, 1, 1], index[1, 1, 2] = 0, 1, 2
  colours = np.array([[1.0, 0, 0], [0.5, 0.5, 0.5], [0, 0, 1.0], [0.5, 0.5, 0.5]])
  seen = np.array([True, False, True, False])
  out = fill_from_neighbours(colours, seen, index)
  np.testing.assert_allclose(out[1], [0.5, 0.0, 0.5])  # the mean of its two neighbours
  np.testing.assert_allclose(out[[0, 2]], colours[[0, 2]])


def test_a_new_style_joins_the_run_and_leaves_the_others_bit_identical(paint_world, tmp_path):
  import shutil  # pylint: disable=g-import-not-at-top
  from conftest import fake_decoder  # pylint: disable=g-import-not-at-top
  run_dir = str(tmp_path / "painted")
  shutil.copytree(paint_world["run"], run_dir)
  before = msnerf_jax.load_run(run_dir)
  green = write_style(tmp_path / "green.png", (40, 200, 40))
  decoder = fake_decoder(tmp_path / "decoder")
  assert cli.main(["paint", "add", "--run", run_dir, "--style", green, "--decoder", decoder,
                   "--key-views", "0", "2", "--polish-steps", "2", "--no-progress"]) == 0
  after = msnerf_jax.load_run(run_dir)
  assert after.record["styles"] == ["red", "blue", "green"] and after.step == before.step + 1
  colours = after.params["paint"]["colours"]
  np.testing.assert_array_equal(colours[:2], before.params["paint"]["colours"])
  assert colours.shape[0] == 3 and np.any(colours[2, :-1] != 0)
  for a, b in zip(leaves(after.params["nerf"]), leaves(before.params["nerf"])):
    np.testing.assert_array_equal(a, b)
  table, _, render = style_rendering(after, paint_world["scene"])
  assert list(table) == ["red", "blue", "green", "original"]
  assert render(0, [table["green"]]).shape == (1, 24, 24, 3)
  assert painted_kind.style_images(after).shape[0] == 3


def test_key_views_of_a_white_background_scene_take_the_styles_colours_on_the_object(
    paint_world, tmp_path):
  # pylint: disable=g-import-not-at-top
  from conftest import fake_decoder
  from msnerf_jax.kinds.stylized_scenes import load_decoder
  from msnerf_jax.models import vgg
  from msnerf_jax.style.transfer import stylize_image
  from msnerf_jax.train.paint_add import stylized_key_views
  scene = paint_world["scene"]
  assert scene.white_background and scene.alphas is not None
  picture = paint_data.read_styles([write_style(tmp_path / "g.png", (40, 200, 40))], 32)[0]
  train, encoder = scene.split("train"), vgg.load_vgg_params()
  decoder = load_decoder(fake_decoder(tmp_path / "decoder"))
  views = stylized_key_views(scene, train, [0, 2], picture, decoder, encoder, 1)
  target = picture.reshape(-1, 3).mean(0)
  for view, out in zip([0, 2], views):
    alpha = scene.alphas[train[view]].astype(np.float32) / 255.0
    mean_of = lambda x: (x * alpha[..., None]).reshape(-1, 3).sum(0) / alpha.sum()
    plain = stylize_image(decoder, encoder, scene.images[train[view]], [picture])
    # The untrained decoder's output is nearly flat in two channels: the map stretches it and
    # clipping to [0, 1] keeps the mean from landing exactly; it comes 2x closer or more.
    assert (np.linalg.norm(mean_of(out) - target)
            < np.linalg.norm(mean_of(plain) - target) / 2)
    np.testing.assert_allclose(out[alpha == 0], 1.0)  # the background stays white


@pytest.mark.parametrize("bad", ["range", "same name"])
def test_a_bad_new_style_gets_one_line_and_writes_nothing(paint_world, tmp_path, capsys, bad):
  import shutil  # pylint: disable=g-import-not-at-top
  from conftest import fake_decoder  # pylint: disable=g-import-not-at-top
  run_dir = str(tmp_path / "painted")
  shutil.copytree(paint_world["run"], run_dir)
  decoder = fake_decoder(tmp_path / "decoder")
  style = paint_world["styles"][0] if bad == "same name" else write_style(
      tmp_path / "green.png", (40, 200, 40))
  stamp = {n: os.path.getmtime(os.path.join(run_dir, n)) for n in os.listdir(run_dir)}
  assert cli.main(["paint", "add", "--run", run_dir, "--style", style, "--decoder", decoder,
                   "--key-views", "0", "9", "--no-progress"]) == 2
  err = capsys.readouterr().err.strip().splitlines()
  assert len(err) == 1 and err[0].startswith("msnerf: error: ")
  assert ("out of range" if bad == "range" else "already has a style named 'red'") in err[0]
  assert {n: os.path.getmtime(os.path.join(run_dir, n)) for n in os.listdir(run_dir)} == stamp


@pytest.mark.slow  # a painting of its own (the default suite stays short)
def test_the_viewer_shows_painted_styles_and_their_blends(paint_world):
  # pylint: disable=g-import-not-at-top
  from msnerf_jax.viewer import probe as probe_lib
  from msnerf_jax.viewer import server as server_lib
  from msnerf_jax.data.images import to_uint8
  from test_viewer import _assert_same, _full_frame
  run = msnerf_jax.load_run(paint_world["run"])
  viewer = server_lib.open_viewer(paint_world["run"], port=0, log=lambda _: None)
  probe = probe_lib.Probe(viewer.url)
  try:
    frames = viewer.frames
    assert list(frames.styles) == ["red", "blue", "original"]
    view = frames.start_request().view
    probe.camera(view.wxyz, view.position, view.fov, 240, 240)
    probe.wait_for(lambda: "blend" in probe.components, 30, "controls")
    assert "upload a style image" not in probe.components  # painted styles only
    render = painted_kind.style_renderer(run, frames.scene)
    camera = frames.camera(view, "full")
    _assert_same(_full_frame(probe, viewer, 240, 240, 0),
                 to_uint8(render(camera, [frames.styles["red"]])[0]))
    n = probe.frame_count()
    probe.set("blend", 0.5)
    half = 0.5 * frames.styles["red"] + 0.5 * frames.styles["blue"]
    _assert_same(_full_frame(probe, viewer, 240, 240, n), to_uint8(render(camera, [half])[0]))
  finally:
    probe.close()
    viewer.stop()


def test_a_crop_renders_from_its_pixels_samples_as_the_whole_view_cropped(paint_world):
  run = msnerf_jax.load_run(paint_world["run"])
  scene = paint_world["scene"]
  config = dataclasses.replace(run.config, crop=16)
  nerf_run = msnerf_jax.load_run(paint_world["nerfs"]["fast"])
  cache = paint_data.read_cache(os.path.join(paint_world["run"], paint_data.CACHE_FILE),
                           paint_data.cache_source(nerf_run))
  styles = painted_kind.style_images(run)
  identity = np.arange(run.params["paint"]["colours"].shape[1])
  photos = np.asarray(scene.images[scene.split("train")], np.float32)
  consts = paint_data.constants(scene, cache, photos, styles, config, identity,
                                paint_data.style_maps(scene, cache, photos, styles, config))
  band = consts.pop("band")
  batch = {"view": jnp.array([0, 3, 1]), "style": jnp.array([1, 0, 1]),
           "top": jnp.array([0, 8, 5]), "left": jnp.array([8, 0, 3])}
  paint_params = jax.tree_util.tree_map(jnp.asarray, run.params["paint"])
  crops = paint.render_crops(paint_params, consts, batch, 16, band, config.scene_box)
  whole = paint.render_pairs(paint_params, consts["cache"], batch["view"], batch["style"],
                             config.scene_box, consts["background"]).reshape(-1, 24, 24, 3)
  for i in range(3):
    top, left = int(batch["top"][i]), int(batch["left"][i])
    np.testing.assert_allclose(crops[i], whole[i, top:top + 16, left:left + 16], atol=1e-6)
  # a band holds part of one row's samples, not the crop's rows'
  row_samples = int(np.max(np.diff(np.asarray(consts["pixel_start"])[:, ::24], axis=1)))
  assert band <= max(64, -(-row_samples // 64) * 64) and 16 * row_samples > band
