"""The one renderer: chunked and padded renders equal one unchunked call, for a plain field and
a conditioned (style) field; a render of one style vmaps over style vectors like the sweep."""

import dataclasses

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from msnerf_jax.nerf import rays as rays_lib
from msnerf_jax.nerf import render
from msnerf_jax.core.config import MultistyleConfig
from msnerf_jax.models.multistyle import MultistyleField, init_multistyle_params
from msnerf_jax.models.nerf import NerfField, init_nerf_params
from test_train_nerf import TINY

# Results agree up to float summation order (matmuls of other sizes): rtol 1e-4.
CONFIG = dataclasses.replace(TINY, mlp_chunk=0)


def image_rays(h=7, w=9):
  """A [h, w] image of rays looking at the origin from z = 4."""
  K = np.array([[8.0, 0, w / 2], [0, 8.0, h / 2], [0, 0, 1]], np.float32)
  c2w = np.array([[1, 0, 0, 0.1], [0, 1, 0, -0.1], [0, 0, 1, 4.0]], np.float32)
  origins, directions = rays_lib.get_rays(h, w, K, c2w)
  return rays_lib.ray_bundle(origins, directions, 2.0, 6.0)


def flat(rays, n=None):
  """[H, W] rays -> the first n (all) of them as [n]."""
  return jax.tree_util.tree_map(lambda x: x.reshape(-1, *x.shape[2:])[:n], rays)


def nerf_setup():
  params = init_nerf_params(CONFIG, jax.random.PRNGKey(0))
  return NerfField(CONFIG), params


def style_setup(density_aware):
  config = MultistyleConfig(nerf=CONFIG, density_aware=density_aware, style_dim=16,
                            style_hidden=16, style_hidden2=8)
  params = init_multistyle_params(config, jax.random.PRNGKey(1),
                                  init_nerf_params(CONFIG, jax.random.PRNGKey(0)))
  styles = jax.random.normal(jax.random.PRNGKey(2), (3, 16))
  return MultistyleField(config), params, styles


def test_chunked_padded_image_equals_one_call():
  field, params = nerf_setup()
  rays = image_rays()  # 63 rays: chunks of 10 leave a padded last chunk.
  whole = jax.jit(lambda p, r: render.render_rays(field, p, r, CONFIG, None, True))(
      params, flat(rays))["fine"]
  image = render.render_image(field, params, rays, CONFIG, True, chunk=10)
  for k in render.IMAGE_OUTPUTS:
    assert image[k].shape == rays["origins"].shape[:-1] + whole[k].shape[1:]
    np.testing.assert_allclose(image[k].reshape(whole[k].shape), whole[k], rtol=1e-4,
                               atol=1e-5)


@pytest.mark.slow  # 15 s; the conditioned test below also runs the field in chunks (mlp_chunk=32)
def test_mlp_chunks_equal_one_field_call():
  field, params = nerf_setup()
  rays = flat(image_rays(), 60)
  randomness = render.draw_randomness(jax.random.PRNGKey(3), 60, CONFIG)
  one = render.render_rays(field, params, rays, CONFIG, randomness, True)
  chunked = render.render_rays(field, params, rays, dataclasses.replace(CONFIG, mlp_chunk=64),
                               randomness, True)
  for a, b in zip(jax.tree_util.tree_leaves(one), jax.tree_util.tree_leaves(chunked)):
    np.testing.assert_allclose(a, b, rtol=1e-4, atol=1e-5)


@pytest.mark.parametrize("density_aware", [False, True])
def test_conditioned_chunked_padded_image_equals_one_call(density_aware):
  field, params, styles = style_setup(density_aware)
  rays = image_rays()
  config = dataclasses.replace(CONFIG, mlp_chunk=32)  # the field in chunks of rays too
  whole = jax.jit(lambda p, r, s: render.render_rays(field, p, r, config, None, True,
                                                     conditioning=s))(
      params, flat(rays), styles)["fine"]
  image = render.render_image(field, params, rays, config, True, chunk=10, styles=styles)
  # Density-aware: each style's fine samples follow its own coarse weights, and the
  # inverse cdf turns their last-bit differences into slightly moved samples.
  tol = 5e-3 if density_aware else 1e-5
  for k in render.IMAGE_OUTPUTS:
    assert image[k].shape[:3] == (3, *rays["origins"].shape[:-1])
    np.testing.assert_allclose(image[k].reshape(whole[k].shape), whole[k], rtol=1e-4,
                               atol=tol)


@pytest.mark.parametrize("per_point_set", [False, True])
def test_conditioned_field_with_chunk_zero_is_one_call(per_point_set):
  """mlp_chunk 0 means one field call, also with M style codes: no loop over the rays in the
  program (a chunk of 1 once mapped over the rays one by one, 20x slower on the hash trunk),
  and the same values as chunks of whole rays."""
  from msnerf_jax.nerf.field_samples import field_in_chunks  # pylint: disable=g-import-not-at-top
  field, params, styles = style_setup(False)
  codes = field.codes(params["fine"], styles)
  rng = np.random.default_rng(0)
  shape = (3, 12, 4, 3) if per_point_set else (12, 4, 3)
  points = jnp.asarray(rng.uniform(-1, 1, shape), jnp.float32)
  viewdirs = jnp.asarray(rng.normal(size=(12, 1, 3)), jnp.float32)
  call = lambda chunk: lambda p: field_in_chunks(field, p["fine"], points, viewdirs, codes, chunk)
  program = str(jax.make_jaxpr(call(0))(params))
  assert "while" not in program and "scan" not in program
  assert "scan" in str(jax.make_jaxpr(call(8))(params))  # chunks: a loop (lax.map)
  for a, b in zip(call(0)(params), call(8)(params)):
    np.testing.assert_allclose(a, b, rtol=1e-5, atol=1e-6)


@pytest.mark.parametrize("density_aware", [False, True])
def test_one_style_render_vmaps_to_the_sweep(density_aware):
  field, params, styles = style_setup(density_aware)
  rays = flat(image_rays())
  one = lambda s: render.render_rays(field, params, rays, CONFIG, None, True,
                                     conditioning=s[None])["fine"]["rgb"][0]
  vmapped = jax.jit(jax.vmap(one))(styles)  # [M, R, 3]
  sweep = jax.jit(lambda s: render.render_rays(field, params, rays, CONFIG, None, True,
                                               conditioning=s)["fine"]["rgb"])(styles)
  assert vmapped.shape == sweep.shape == (3, rays["origins"].shape[0], 3)
  np.testing.assert_allclose(vmapped, sweep, rtol=1e-4, atol=1e-5)
  assert float(jnp.abs(sweep[0] - sweep[1]).max()) > 1e-4  # the styles do differ


def test_render_rays_styles_is_the_conditioned_render():
  field, params, styles = style_setup(False)
  rays = flat(image_rays(), 20)
  a = render.render_rays_styles(field, params, rays, styles, CONFIG, None, True)
  b = render.render_rays(field, params, rays, CONFIG, None, True, conditioning=styles)
  for x, y in zip(jax.tree_util.tree_leaves(a), jax.tree_util.tree_leaves(b)):
    np.testing.assert_array_equal(x, y)


def test_a_runs_own_config_renders_like_its_nerf_config():
  """render_rays_styles with a MultistyleConfig (what `load_run` gives a researcher) samples
  by its `.nerf`, as with the NerfConfig itself."""
  from msnerf_jax.core.config import MultistyleConfig  # pylint: disable=g-import-not-at-top
  field, params, styles = style_setup(False)
  rays = flat(image_rays(), 20)
  a = render.render_rays_styles(field, params, rays, styles, MultistyleConfig(nerf=CONFIG))
  b = render.render_rays_styles(field, params, rays, styles, CONFIG)
  for x, y in zip(jax.tree_util.tree_leaves(a), jax.tree_util.tree_leaves(b)):
    np.testing.assert_array_equal(x, y)
