"""The fast trunk: hash encoding, occupancy grid, packed rendering, and their training."""

import dataclasses
import os
import subprocess
import sys
import textwrap

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import msnerf_jax
from msnerf_jax.nerf import occupancy
from msnerf_jax.kinds import multistyle as multistyle_kind
from msnerf_jax.nerf import render as render_lib
from msnerf_jax.core.config import DataConfig, NerfConfig, nerf_preset, override
from msnerf_jax.data.scene import load_scene
from msnerf_jax.core.errors import UserError
from msnerf_jax.nerf.hash_encoding import hash_encode, level_resolutions
from msnerf_jax.models.nerf import NerfField, init_nerf_params
from msnerf_jax.train import nerf
from msnerf_jax.nerf.volume_rendering import volume_render, volume_render_packed

# A small fast-preset config for the tiny synthetic scene (16x16 views, box of half side 1.5).
TINY_FAST = override(
    nerf_preset("fast", "blender"), net_width=16, hash_levels=4, hash_features=2,
    hash_table_size=2 ** 10, hash_min_res=4, hash_max_res=32, scene_box=1.5,
    grid_resolution=8, march_steps=32, samples_per_ray=32, grid_every=2, grid_warmup=4,
    batch_rays=64, steps=6, checkpoint_every=2, render_chunk=64, lr_decay_steps=100)


def leaves(tree):
  return jax.tree_util.tree_leaves(tree)


# ----------------------------------------------------------------------------- hash encoding


def test_level_resolutions_are_geometric_from_coarsest_to_finest():
  res = level_resolutions(16, 16, 512)
  assert res[0] == 16 and res[-1] == 512 and len(res) == 16
  assert all(b > a for a, b in zip(res, res[1:]))
  assert level_resolutions(1, 8, 64) == (8,)


@pytest.mark.parametrize("resolution", [3, 40])  # a dense level and a hashed one (T = 256)
def test_interpolation_is_exact_at_grid_vertices(resolution):
  table_size = 256
  assert ((resolution + 1) ** 3 <= table_size) == (resolution == 3)
  tables = jax.random.normal(jax.random.PRNGKey(0), (1, table_size, 2))
  rng = np.random.default_rng(0)
  vertices = rng.integers(0, resolution + 1, (50, 3))
  got = hash_encode(tables, jnp.asarray(vertices / resolution, jnp.float32), (resolution,))
  # The vertex's own row, computed here from the definition.
  if resolution == 3:
    rows = vertices[:, 0] + vertices[:, 1] * 4 + vertices[:, 2] * 16
  else:
    v = vertices.astype(np.uint64)
    rows = (v[:, 0] ^ (v[:, 1] * 2654435761) ^ (v[:, 2] * 805459861)) % (2 ** 32) % table_size
  np.testing.assert_allclose(got, np.asarray(tables)[0, rows.astype(np.int64)], rtol=1e-5,
                             atol=1e-6)


def test_hash_encoding_gradients_agree_with_finite_differences():
  res = (4, 9, 30)
  tables = jax.random.normal(jax.random.PRNGKey(1), (3, 512, 2))
  x = jax.random.uniform(jax.random.PRNGKey(2), (20, 3), minval=0.05, maxval=0.95)
  probe = jax.random.normal(jax.random.PRNGKey(3), (20, 6))
  f = lambda t, p: jnp.sum(hash_encode(t, p, res) * probe)
  g_tables, g_x = jax.grad(f, argnums=(0, 1))(tables, x)
  rng = np.random.default_rng(4)
  used = np.argwhere(np.abs(np.asarray(g_tables)) > 1e-3)
  for idx in used[rng.choice(len(used), 8, replace=False)]:
    e = np.zeros(tables.shape, np.float32)
    e[tuple(idx)] = 0.5
    fd = (f(tables + e, x) - f(tables - e, x)) / 1.0  # linear in the tables: exact
    np.testing.assert_allclose(g_tables[tuple(idx)], fd, rtol=1e-3, atol=1e-4)
  # Position: trilinear interpolation is smooth inside a cell; probe coordinates whose
  # finite difference stays inside one cell at every level.
  frac = np.stack([np.asarray(x) * r % 1.0 for r in res])  # [levels, 20, 3]
  inner = np.argwhere(np.all((frac > 0.1) & (frac < 0.9), 0))
  assert len(inner) >= 5
  for i, k in inner[:8]:
    e = np.zeros(x.shape, np.float32)
    e[i, k] = 1e-3
    fd = (f(tables, x + e) - f(tables, x - e)) / 2e-3
    np.testing.assert_allclose(g_x[i, k], fd, rtol=2e-2, atol=2e-2)


# ----------------------------------------------------------------------------- occupancy grid


def ray_batch(n=24, seed=0, bound=1.0):
  rng = np.random.default_rng(seed)
  origins = rng.normal(size=(n, 3))
  origins = 3.0 * bound * origins / np.linalg.norm(origins, axis=-1, keepdims=True)
  targets = rng.uniform(-0.6 * bound, 0.6 * bound, (n, 3))
  directions = targets - origins
  return {"origins": jnp.asarray(origins, jnp.float32),
          "directions": jnp.asarray(directions, jnp.float32),
          "viewdirs": jnp.asarray(directions / np.linalg.norm(directions, axis=-1,
                                                              keepdims=True), jnp.float32),
          "near": jnp.full((n,), 0.1), "far": jnp.full((n,), 3.0)}


def test_an_all_occupied_grid_samples_and_renders_as_dense_sampling():
  config = dataclasses.replace(NerfConfig(), scene_box=1.0, march_steps=16)
  rays = ray_batch()
  n, steps = rays["origins"].shape[0], config.march_steps
  full = jnp.ones((4, 4, 4), bool)
  samples = jax.jit(occupancy.march, static_argnums=(2, 3))(rays, full, config, n * steps)
  t0, t1 = occupancy.box_interval(rays, config.scene_box)
  dt = (t1 - t0) / steps
  dense = t0[:, None] + (jnp.arange(steps) + 0.5) * dt[:, None]  # [R, N]
  assert bool(jnp.all(t1 > t0)) and bool(jnp.all(samples["valid"]))
  assert bool(jnp.all(samples["complete"]))
  np.testing.assert_array_equal(samples["ray"], np.repeat(np.arange(n), steps))
  np.testing.assert_allclose(samples["t"].reshape(n, steps), dense, rtol=1e-6)
  # Compositing the packed samples = volume_render of the same samples ray by ray (the last
  # sample has no density, so volume_render's open-ended last interval does not matter).
  rng = np.random.default_rng(1)
  sigma = jnp.asarray(rng.uniform(0, 4, (n, steps)), jnp.float32).at[:, -1].set(0.0)
  rgb = jnp.asarray(rng.uniform(0, 1, (n, steps, 3)), jnp.float32)
  packed = jax.jit(volume_render_packed, static_argnums=(3, 4))(
      rgb.reshape(-1, 3), sigma.reshape(-1), samples, n, True)
  ref = jax.jit(volume_render, static_argnums=4)(rgb, sigma, dense, rays["directions"], True)
  for k in ("rgb", "accumulation", "depth"):
    np.testing.assert_allclose(packed[k], ref[k], rtol=2e-5, atol=2e-5)


def test_the_grid_never_drops_a_sample_in_an_occupied_cell():
  # Density 10 in the cube [-0.5, 0.5]^3, whose faces are cell faces of the 8^3 grid over
  # [-1, 1]^3, and nothing elsewhere.
  config = dataclasses.replace(NerfConfig(), scene_box=1.0, march_steps=200, grid_resolution=8)
  inside = lambda p: jnp.all(jnp.abs(p) < 0.5, -1)
  grid = occupancy.update_grid(occupancy.init_grid(8), lambda p: 10.0 * inside(p),
                               jax.random.PRNGKey(0), config, True)
  occupied = occupancy.occupied(grid, config.grid_threshold)
  assert int(occupied.sum()) == 4 ** 3  # exactly the cube's cells
  rays = ray_batch(64, seed=2)
  samples = {k: np.asarray(v) for k, v in occupancy.march(rays, occupied, config, 64 * 200).items()}
  assert samples["complete"].all()
  t0, t1 = (np.asarray(v) for v in occupancy.box_interval(rays, 1.0))
  dt = (t1 - t0) / 200
  ray, valid = samples["ray"][samples["valid"]], samples["valid"]
  step = np.round((samples["t"][valid] - t0[ray]) / dt[ray] - 0.5).astype(int)
  kept = np.zeros((64, 200), bool)
  kept[ray, step] = True
  t = t0[:, None] + (np.arange(200) + 0.5) * dt[:, None]
  points = (np.asarray(rays["origins"])[:, None]
            + np.asarray(rays["directions"])[:, None] * t[..., None])
  in_cube = np.all(np.abs(points) < 0.5, -1)
  assert in_cube.sum() > 500  # the rays do cross it
  assert np.all(kept[in_cube])  # nothing inside dropped
  assert kept.sum() < 0.5 * (t1 > t0).sum() * 200  # and most empty space skipped


def test_a_budget_overflow_is_reported_and_render_image_budgets_every_ray():
  config = dataclasses.replace(TINY_FAST, scene_box=1.0)
  params = init_nerf_params(config, jax.random.PRNGKey(0))  # all cells unknown: occupied
  rays = ray_batch(40, seed=3)
  small = dataclasses.replace(config, samples_per_ray=2)
  out = jax.jit(render_lib.render_rays, static_argnums=(0, 3))(NerfField(small), params, rays,
                                                               small)["fine"]
  assert not bool(jnp.all(out["complete"])) and bool(out["complete"][0])
  # render_image counts what each call needs first: with a small samples_per_ray and small
  # chunks it renders what one call with room for everything renders.
  image = render_lib.render_image(NerfField(small), params, rays, small, chunk=24)
  whole = render_lib.render_image(NerfField(config), params, rays, config, chunk=64)
  for k in ("rgb", "accumulation", "depth"):
    np.testing.assert_allclose(image[k], whole[k], rtol=1e-5, atol=1e-5)


# ----------------------------------------------------------------------------- training


def test_the_grid_is_frozen_from_the_optimizer():
  state = nerf.init_state(TINY_FAST)
  labels = [type(s).__name__ for s in leaves(state.opt_state)]
  n_train = sum(x.size for x in leaves(state.params["fine"]))
  n_state = sum(x.size for x in leaves(state.opt_state) if hasattr(x, "size") and x.ndim > 0)
  assert n_state == 2 * n_train, (n_state, n_train, labels)  # Adam's two moments, no grid


@pytest.mark.slow
def test_fast_resume_gives_the_same_parameters_as_one_run(tiny_blender, tmp_path):
  scene, data = load_scene(DataConfig(path=tiny_blender))
  nerf.train(scene, TINY_FAST, data, str(tmp_path / "full"), progress=False)
  nerf.train(scene, override(TINY_FAST, steps=4), data, str(tmp_path / "split"),
             progress=False)
  assert nerf.train(scene, TINY_FAST, data, str(tmp_path / "split"),
                    progress=False)["resumed_from"] == 4
  full = msnerf_jax.load_run(str(tmp_path / "full"))
  split = msnerf_jax.load_run(str(tmp_path / "split"))
  for a, b in zip(leaves(full.params), leaves(split.params)):
    np.testing.assert_array_equal(a, b)


TWO_DEVICES = textwrap.dedent("""
    import os, sys
    os.environ["XLA_FLAGS"] = (os.environ.get("XLA_FLAGS", "")
                               + " --xla_force_host_platform_device_count=2")
    import dataclasses, jax, numpy as np, jax.numpy as jnp
    from msnerf_jax.core.config import DataConfig
    from msnerf_jax.data.scene import load_scene
    from msnerf_jax.core.parallel import data_parallel
    from msnerf_jax.train import nerf
    sys.path.insert(0, {tests!r})
    from test_fast_trunk import TINY_FAST
    scene, _ = load_scene(DataConfig(path={scene!r}))
    config = TINY_FAST
    def run(dp):
      state = dp.put_state(nerf.init_state(config))
      step = nerf.compile_train_step(config, True, dp)
      for i in range(5):  # crosses grid refreshes (every 2 steps, all cells, then a quarter)
        batch = nerf.sample_batch(jax.random.PRNGKey(i), jnp.asarray(scene.images),
                                  jnp.asarray(scene.c2w), jnp.asarray(scene.K), config, False,
                                  False, (scene.height, scene.width, scene.focal), 2.0, 6.0,
                                  jnp.asarray(scene.alphas))
        state, stats = step(state, dp.put_batch(batch))
      return dp.to_host(state), dp.to_host(stats)
    one, s1 = run(data_parallel(1))
    two, s2 = run(data_parallel(2))
    assert float(s1["complete"]) == float(s2["complete"]) == 1.0
    start = nerf.init_state(config)
    moved = max(float(np.max(np.abs(np.asarray(a) - np.asarray(b))))
                for a, b in zip(jax.tree_util.tree_leaves(one.params["fine"]),
                                jax.tree_util.tree_leaves(start.params["fine"])))
    worst = max(float(np.max(np.abs(np.asarray(a) - np.asarray(b))))
                for a, b in zip(jax.tree_util.tree_leaves(one.params["fine"]),
                                jax.tree_util.tree_leaves(two.params["fine"])))
    grid = float(np.max(np.abs(one.params["occupancy"] - two.params["occupancy"])))
    print("worst", worst, "moved", moved, "grid", grid)
    assert moved > 1e-4 and worst < 1e-3 * moved, (worst, moved)
    assert grid <= 1e-3 * float(np.max(one.params["occupancy"])), grid
""")


@pytest.mark.slow  # 30-50 s (two compilations in a subprocess); the default suite is at 10 min
def test_two_devices_give_the_same_fast_steps_as_one(tiny_blender):
  tests = os.path.dirname(os.path.abspath(__file__))
  result = subprocess.run([sys.executable, "-c", TWO_DEVICES.format(tests=tests,
                                                                     scene=tiny_blender)],
                          capture_output=True, text=True, timeout=600)
  assert result.returncode == 0, result.stdout + result.stderr[-3000:]
  assert "worst" in result.stdout


# ----------------------------------------------------------------------------- bad settings


@pytest.mark.parametrize("change, message", [
    ({"trunk": "hash", "hash_table_size": 1000}, "--hash-table-size 1000: must be a power of two"),
    ({"trunk": "hash", "hash_min_res": 64, "hash_max_res": 32},
     "--hash-max-res 32: finest resolution below the coarsest"),
    ({"trunk": "hash", "hash_levels": 0}, "--hash-levels 0: must be >= 1"),
    ({"trunk": "voxels"}, "--trunk voxels: unknown trunk"),
    ({"sampler": "grid", "raw_noise_std": 1.0}, "--raw-noise-std 1.0: the occupancy-grid"),
])
def test_a_config_that_cannot_work_is_named(change, message):
  with pytest.raises(UserError, match=message):
    dataclasses.replace(NerfConfig(), **change).validate()


# ----------------------------------------------------------------------------- multi-style


@pytest.fixture(scope="module")
def fast_world(tmp_path_factory):
  """A NeRF run with the hash trunk and grid sampler, a stylized dataset of its scene and a
  multi-style run on it (3 steps, via the CLI)."""
  from msnerf_jax import cli  # pylint: disable=g-import-not-at-top
  from conftest import fake_decoder, write_blender_scene  # pylint: disable=g-import-not-at-top
  from test_multistyle import write_style  # pylint: disable=g-import-not-at-top
  root = tmp_path_factory.mktemp("fast")
  scene_dir = write_blender_scene(str(root / "scene"), n_train=4, n_val=2, size=16)
  scene, data = load_scene(DataConfig(path=scene_dir))
  nerf_run = str(root / "nerf")
  # 64 wide: the style heads get 32 units (with 8, all of them may start out dead for both
  # styles on an untrained trunk, and render the styles alike).
  summary = nerf.train(scene, override(TINY_FAST, steps=20, checkpoint_every=20, net_width=64),
                       data, nerf_run, progress=False)
  assert summary["steps"] == 20
  styles = [write_style(root / "red.png", (200, 30, 30)),
            write_style(root / "blue.png", (20, 40, 200))]
  stylized = str(root / "stylized")
  assert cli.main(["stylize-scene", "--data", scene_dir, "--decoder",
                   fake_decoder(root / "decoder"), "--styles", *styles, "--out", stylized]) == 0
  run = str(root / "ms")
  assert cli.main(["multistyle", "train", "--nerf", nerf_run, "--stylized", stylized, "--out",
                   run, "--steps", "3", "--batch-rays", "32", "--checkpoint-every", "3"]) == 0
  return {"root": root, "scene": scene, "nerf": nerf_run, "stylized": stylized, "run": run}


def test_fast_training_lowers_the_loss_and_carves_the_grid(fast_world):
  run, scene = msnerf_jax.load_run(fast_world["nerf"]), fast_world["scene"]
  assert set(run.params) == {"fine", "occupancy"} and "tables" in run.params["fine"]["trunk"]
  assert run.config.scene_box == 1.5  # resolved from the Blender scene
  assert float(run.params["occupancy"].min()) >= 0  # every cell estimated after the warm-up
  fixed = nerf.sample_batch(jax.random.PRNGKey(0), jnp.asarray(scene.images[:4]),
                            jnp.asarray(scene.c2w[:4]), jnp.asarray(scene.K), run.config, False,
                            False, (scene.height, scene.width, scene.focal), 2.0, 6.0)
  loss = jax.jit(nerf.loss_fn, static_argnums=(2, 3))
  first = loss(nerf.init_state(run.config).params, fixed, run.config, True)[1]
  last = loss(jax.tree_util.tree_map(jnp.asarray, run.params), fixed, run.config, True)[1]
  assert float(last["loss"]) < 0.8 * float(first["loss"]), (first, last)
  assert float(last["complete"]) == 1.0


def test_multistyle_on_the_hash_trunk_keeps_trunk_and_grid_bit_identical(fast_world):
  from msnerf_jax.core import checkpoint  # pylint: disable=g-import-not-at-top
  run, nerf_run = msnerf_jax.load_run(fast_world["run"]), msnerf_jax.load_run(fast_world["nerf"])
  assert set(run.params) == {"fine", "occupancy"}
  frozen = {"trunk": run.params["fine"]["trunk"], "grid": run.params["occupancy"]}
  source = {"trunk": nerf_run.params["fine"]["trunk"], "grid": nerf_run.params["occupancy"]}
  assert "tables" in frozen["trunk"]
  for a, b in zip(leaves(frozen), leaves(source)):
    assert np.array_equal(np.asarray(a).view(np.uint32), np.asarray(b).view(np.uint32))
  ckpts = checkpoint.Checkpoints(fast_world["run"])
  raw = ckpts.restore()
  ckpts.close()
  paths = [jax.tree_util.keystr(p) for p, _ in jax.tree_util.tree_leaves_with_path(raw["opt_state"])]
  assert paths and not any("trunk" in p or "occupancy" in p for p in paths)


def test_multistyle_sweep_on_the_grid_equals_single_renders(fast_world):
  from msnerf_jax.kinds import views
  run = msnerf_jax.load_run(fast_world["run"])
  vectors = multistyle_kind.style_vectors(run)
  styles = np.stack([vectors["red"], vectors["blue"]])
  c2w = fast_world["scene"].c2w[4]
  sweep = views.render_styles(fast_world["scene"], run.params, run.config, c2w, styles, chunk=64)
  for k in range(2):
    one = views.render_styles(fast_world["scene"], run.params, run.config, c2w,
                              styles[k:k + 1], chunk=64)
    for key in ("rgb", "depth", "accumulation"):
      np.testing.assert_allclose(sweep[key][k], one[key][0], rtol=1e-4, atol=1e-5)
  assert float(np.abs(sweep["rgb"][0] - sweep["rgb"][1]).max()) > 1e-3


def test_a_multistyle_run_pointed_at_a_nerf_run_of_another_trunk_is_refused(fast_world, capsys):
  from msnerf_jax import cli  # pylint: disable=g-import-not-at-top
  from test_train_nerf import TINY  # pylint: disable=g-import-not-at-top
  scene, data = load_scene(DataConfig(path=str(fast_world["root"] / "scene")))
  mlp_run = str(fast_world["root"] / "nerf_mlp")
  nerf.train(scene, override(TINY, steps=2), data, mlp_run, progress=False)
  before = sorted(os.listdir(fast_world["run"]))
  assert cli.main(["multistyle", "train", "--nerf", mlp_run, "--stylized",
                   fast_world["stylized"], "--out", fast_world["run"], "--steps", "3",
                   "--batch-rays", "32", "--checkpoint-every", "3"]) == 2
  err = capsys.readouterr().err.strip().splitlines()[-1]
  assert err.startswith("msnerf: error:") and "trunk" in err, err
  assert sorted(os.listdir(fast_world["run"])) == before
  assert cli.main(["multistyle", "train", "--nerf", fast_world["nerf"], "--stylized",
                   fast_world["stylized"], "--out", str(fast_world["root"] / "ms_da"),
                   "--density-aware", "--steps", "1"]) == 2
  err = capsys.readouterr().err.strip().splitlines()[-1]
  assert "density-aware" in err and "occupancy grid" in err, err
  assert not os.path.exists(fast_world["root"] / "ms_da")


def test_segmented_rendering_with_early_termination_equals_one_pass(fast_world):
  run = msnerf_jax.load_run(fast_world["nerf"])
  scene = fast_world["scene"]
  rays = scene.camera_rays(scene.c2w[4])
  one_pass = dataclasses.replace(run.config, march_segments=1)
  # A denser field than 6 steps of training give (density x e^3), so rays turn opaque.
  trunk = run.params["fine"]["trunk"]
  density = {**trunk["density"], "bias": trunk["density"]["bias"] + 3.0}
  params = {**run.params, "fine": {**run.params["fine"], "trunk": {**trunk, "density": density}}}
  a = render_lib.render_image(NerfField(run.config), params, rays, run.config, True, chunk=64)
  b = render_lib.render_image(NerfField(one_pass), params, rays, one_pass, True, chunk=64)
  assert a["accumulation"].max() > 0.99  # some rays do turn opaque
  for k in ("rgb", "accumulation", "depth"):
    np.testing.assert_allclose(a[k], b[k], atol=3e-4)


# ----------------------------------------------------------------------------- baked scenes


def _bake(run, resolution=8, components=64):
  from msnerf_jax.nerf import baked  # pylint: disable=g-import-not-at-top
  field = NerfField(run.config)
  geometry = jax.jit(lambda x: field.geometry(run.params["fine"], x))
  return baked.bake(geometry, run.params["occupancy"], run.config, resolution, components)


def test_a_baked_scene_renders_what_the_exact_renderer_does(fast_world):
  from msnerf_jax.nerf import baked  # pylint: disable=g-import-not-at-top
  run, scene = msnerf_jax.load_run(fast_world["nerf"]), fast_world["scene"]
  field = NerfField(run.config)
  rays = scene.camera_rays(scene.c2w[4])
  exact = render_lib.render_image(field, run.params, rays, run.config, True, chunk=64)
  fine = baked.render_baked_image(_bake(run), field, run.params, rays, run.config, True, 64)
  coarse = baked.render_baked_image(_bake(run, 1, 2), field, run.params, rays, run.config,
                                    True, 64)
  assert fine["rgb"].shape == exact["rgb"].shape == (16, 16, 3)
  assert exact["accumulation"].max() > 0.2  # the view shows something
  error = lambda out: float(np.abs(out["rgb"] - exact["rgb"]).mean())
  # Fine bricks and every principal component: the exact render to within 1/255 on average;
  # one vertex a cell and 2 of 64 components is visibly worse.
  assert error(fine) < 1 / 255, error(fine)
  assert error(coarse) > 3 * error(fine), (error(coarse), error(fine))
  np.testing.assert_allclose(fine["accumulation"], exact["accumulation"], atol=0.02)


def test_a_baked_multistyle_sweep_equals_its_single_styles_and_the_exact_sweep(fast_world):
  from msnerf_jax.models.multistyle import MultistyleField  # pylint: disable=g-import-not-at-top
  from msnerf_jax.nerf import baked  # pylint: disable=g-import-not-at-top
  run, scene = msnerf_jax.load_run(fast_world["run"]), fast_world["scene"]
  vectors = multistyle_kind.style_vectors(run)
  styles = jnp.asarray(np.stack([vectors["red"], vectors["blue"]]))
  rays = scene.camera_rays(scene.c2w[4])
  bake = _bake(msnerf_jax.load_run(fast_world["nerf"]))
  field = MultistyleField(run.config)
  sweep = baked.render_baked_image(bake, field, run.params, rays, run.config.nerf, True, 64,
                                   styles)
  exact = render_lib.render_image(field, run.params, rays, run.config.nerf, True, chunk=64,
                                  styles=styles)
  assert sweep["rgb"].shape == (2, 16, 16, 3) and sweep["depth"].shape == (2, 16, 16)
  assert float(np.abs(sweep["rgb"] - exact["rgb"]).mean()) < 1 / 255
  assert float(np.abs(sweep["rgb"][0] - sweep["rgb"][1]).max()) > 1e-3
  for k in range(2):
    one = baked.render_baked_image(bake, field, run.params, rays, run.config.nerf, True, 64,
                                   styles[k:k + 1])
    np.testing.assert_allclose(sweep["rgb"][k], one["rgb"][0], rtol=1e-4, atol=1e-5)


def test_baking_is_deterministic_and_one_compilation_serves_every_image_size(fast_world):
  from msnerf_jax.nerf import baked  # pylint: disable=g-import-not-at-top
  run, scene = msnerf_jax.load_run(fast_world["nerf"]), fast_world["scene"]
  first, second = _bake(run, 4, 8), _bake(run, 4, 8)
  for a, b in zip(leaves(first), leaves(second)):
    assert np.array_equal(np.asarray(a), np.asarray(b))
  field = NerfField(run.config)
  calls = (baked._geometry_call, baked._shade_call)  # pylint: disable=protected-access
  before = [call._cache_size() for call in calls]  # pylint: disable=protected-access
  for size in (5, 16, 23):  # windows of three sizes, 1 to 9 calls of 64 rays
    rays = scene.bundle(*msnerf_jax.get_rays(size, size, scene.K * size / 16, scene.c2w[4]))
    out = baked.render_baked_image(first, field, run.params, rays, run.config, True, 64,
                                   shade_chunk=128)
    assert out["rgb"].shape == (size, size, 3)
  after = [call._cache_size() for call in calls]  # pylint: disable=protected-access
  assert [a - b for a, b in zip(after, before)] == [1, 1]


def test_a_runs_bake_is_saved_reused_rebaked_when_the_run_changed_and_bad_files_named(
    fast_world, tmp_path, capsys):
  import shutil  # pylint: disable=g-import-not-at-top
  from msnerf_jax import cli  # pylint: disable=g-import-not-at-top
  from msnerf_jax.kinds import baked as baked_run  # pylint: disable=g-import-not-at-top
  run_dir = str(tmp_path / "nerf")
  shutil.copytree(fast_world["nerf"], run_dir)
  run = msnerf_jax.load_run(run_dir)
  lines = []
  first = baked_run.baked_scene(run, lines.append)
  path = os.path.join(run_dir, baked_run.BAKED_FILE)
  assert os.path.exists(path) and len(lines) == 1 and "baked" in lines[0]
  data = open(path, "rb").read()
  again = baked_run.baked_scene(run, lines.append)  # reused: nothing baked, nothing written
  assert len(lines) == 1 and open(path, "rb").read() == data
  for a, b in zip(leaves(first), leaves(again)):
    assert np.array_equal(np.asarray(a), np.asarray(b))
  os.remove(path)  # baking again gives the same file
  baked_run.baked_scene(run, lines.append)
  assert open(path, "rb").read() == data
  # The run trained further (its trunk changed): baked again, said so.
  trunk = run.params["fine"]["trunk"]
  changed = dataclasses.replace(run, params={**run.params, "fine": {**run.params["fine"], "trunk": {
      **trunk, "density": {**trunk["density"], "bias": trunk["density"]["bias"] + 1.0}}}})
  baked_run.baked_scene(changed, lines.append)
  assert "another state" in lines[-2] and open(path, "rb").read() != data
  # Truncated or foreign files: one line, exit code 2, through the CLI.
  out = str(tmp_path / "video")
  for bad in (data[:len(data) // 2], b"not a bake", open(os.path.join(
      fast_world["nerf"], "run.json"), "rb").read()):
    with open(path, "wb") as f:
      f.write(bad)
    assert cli.main(["nerf", "render", "--run", run_dir, "--out", out, "--frames", "2",
                     "--fast"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith(f"msnerf: error: {path}: not a baked scene"), err
  os.remove(path)
  assert cli.main(["nerf", "render", "--run", run_dir, "--out", out, "--frames", "2",
                   "--fast"]) == 0
  assert os.path.exists(out + ".mp4") and os.path.exists(path)


def test_the_viewer_draws_a_fast_run_from_its_bake(fast_world, tmp_path):
  import shutil  # pylint: disable=g-import-not-at-top
  from msnerf_jax.data.images import to_uint8  # pylint: disable=g-import-not-at-top
  from msnerf_jax.kinds import baked as baked_run  # pylint: disable=g-import-not-at-top
  from msnerf_jax.viewer.frames import Frames, Request  # pylint: disable=g-import-not-at-top
  run_dir = str(tmp_path / "ms")
  shutil.copytree(fast_world["run"], run_dir)
  run, scene = msnerf_jax.load_run(run_dir), fast_world["scene"]
  fast = Frames(run, scene, report=lambda line: None)
  exact = Frames(run, scene, exact=True)
  assert fast.baked is not None and exact.baked is None
  assert os.path.exists(os.path.join(run_dir, baked_run.BAKED_FILE))
  assert fast.pixels["full"] == exact.pixels["full"]
  assert fast.pixels["low"] == 4 * exact.pixels["low"]  # previews of 1/4 of the pixels
  request = fast.start_request()
  for style in ("red", "blue"):
    request = Request(request.view, fast.styles[style])
    for level in ("low", "full"):
      frame = fast.render(request, level).astype(float)
      rays = scene.camera_rays(fast.camera(request.view, level))
      reference = to_uint8(render_lib.render_image(
          exact.field, run.params, rays, run.config.nerf, True,
          styles=jnp.asarray(request.style)[None])["rgb"][0]).astype(float)
      assert frame.shape == reference.shape
      assert np.abs(frame - reference).mean() < 6, (style, level)
