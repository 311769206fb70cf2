"""AdaIN primitives: statistics, adain/alpha, blending, style vectors, colour preservation."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from msnerf_jax.style import adain
from msnerf_jax.style import vectors as styles_lib
from msnerf_jax.style import transfer as stylize
from msnerf_jax.models import vgg


def _feats(key, shape=(2, 6, 5, 8), scale=1.0, shift=0.0):
  return jax.random.normal(key, shape) * scale + shift


def test_channel_stats_unbiased_plus_eps():
  x = _feats(jax.random.PRNGKey(0))
  mean, std = adain.channel_stats(x)
  flat = np.asarray(x).reshape(2, -1, 8)
  np.testing.assert_allclose(mean, flat.mean(1), atol=1e-6)
  np.testing.assert_allclose(std, flat.std(1, ddof=1) + adain.EPS, atol=1e-6)
  # A constant map gives std eps (no division by zero downstream).
  _, flat_std = adain.channel_stats(jnp.ones((1, 4, 4, 3)))
  np.testing.assert_allclose(flat_std, adain.EPS, rtol=1e-6)
  assert np.all(np.isfinite(adain.adain(jnp.ones((1, 4, 4, 3)), x[:1, ..., :3])))


def test_adain_transfers_statistics_and_alpha():
  c = _feats(jax.random.PRNGKey(1), scale=3.0, shift=2.0)
  s = _feats(jax.random.PRNGKey(2), (2, 9, 7, 8), scale=0.5, shift=-1.0)
  out = jax.jit(adain.adain)(c, s)
  assert out.shape == c.shape
  om, ostd = adain.channel_stats(out)
  sm, sstd = adain.channel_stats(s)
  np.testing.assert_allclose(om, sm, atol=1e-5)
  np.testing.assert_allclose(ostd, sstd, atol=1e-5)
  np.testing.assert_allclose(adain.adain(c, s, alpha=0.0), c, atol=1e-5)
  # alpha blends the statistics = the paper's alpha * AdaIN(c, s) + (1 - alpha) * c.
  half = jax.jit(adain.adain)(c, s, 0.3)
  np.testing.assert_allclose(half, 0.3 * out + 0.7 * c, atol=1e-4)
  # Style batch 1 broadcasts over the content batch.
  assert adain.adain(c, s[:1]).shape == c.shape


def test_blend_equals_feature_interpolation():
  c = _feats(jax.random.PRNGKey(3))[:1]
  styles = [_feats(jax.random.PRNGKey(k), (1, 5, 5, 8), scale=k, shift=k) for k in (4, 5, 6)]
  stats = [adain.channel_stats(s) for s in styles]
  means = jnp.concatenate([m for m, _ in stats])
  stds = jnp.concatenate([s for _, s in stats])
  w = jnp.array([0.2, 0.5, 0.3])
  mean, std = jax.jit(adain.blend_stats)(means, stds, w * 10)  # weights are normalised
  blended = adain.adain_from_stats(c, mean, std)
  expected = sum(wk * adain.adain(c, s) for wk, s in zip(w, styles))
  np.testing.assert_allclose(blended, expected, atol=1e-4)
  one_hot = adain.blend_stats(means, stds, jnp.array([0.0, 1.0, 0.0]))
  np.testing.assert_allclose(adain.adain_from_stats(c, *one_hot), adain.adain(c, styles[1]), atol=1e-4)
  v = jax.random.normal(jax.random.PRNGKey(7), (2, 1024))
  np.testing.assert_allclose(styles_lib.blend(v[0], v[1], 0.75), 0.25 * v[0] + 0.75 * v[1], atol=1e-5)


def test_content_stats_give_every_image_the_same_map():
  c = _feats(jax.random.PRNGKey(5), scale=2.0, shift=1.0)
  s_mean, s_std = adain.channel_stats(_feats(jax.random.PRNGKey(6), (1, 5, 5, 8)))
  own = adain.channel_stats(c[:1])
  # An image's own statistics given explicitly are plain AdaIN.
  np.testing.assert_allclose(adain.adain_from_stats(c[:1], s_mean, s_std, 1.0, own),
                             adain.adain_from_stats(c[:1], s_mean, s_std), atol=1e-5)
  # Shared statistics: one affine map per channel for the whole batch, so one feature value
  # lands on one output value in every image (not so with per-image statistics).
  shared = (jnp.full((1, 8), 0.5), jnp.full((1, 8), 2.0))
  out = adain.adain_from_stats(c, s_mean, s_std, 1.0, shared)
  np.testing.assert_allclose(out, (c - 0.5) / 2.0 * s_std[:, None, None] + s_mean[:, None, None],
                             atol=1e-5)
  with pytest.raises(AssertionError):
    adain.adain_from_stats(c, s_mean, s_std, 1.0, (shared[0][:, :3], shared[1][:, :3]))


def test_scene_content_stats_pool_every_position_of_every_view(enc):
  views = [np.asarray(jax.random.uniform(jax.random.PRNGKey(i), (12, 20, 3))) for i in (7, 8)]
  mean, std = stylize.scene_content_stats(enc, views, scale=2)
  assert mean.shape == std.shape == (1, 512) and mean.dtype == np.float32
  # The same as the statistics of both views' relu4_1 maps (of the enlarged, padded views)
  # put side by side.
  feats = [np.asarray(adain.encode(enc, jnp.asarray(stylize.pad_to_multiple(
      stylize.images_lib.resize(v, 24, 40))[None]))["relu4_1"]) for v in views]
  flat = np.concatenate([f.reshape(-1, 512) for f in feats]).astype(np.float64)
  np.testing.assert_allclose(mean[0], flat.mean(0), rtol=1e-4, atol=1e-5)
  np.testing.assert_allclose(std[0], flat.std(0, ddof=1) + adain.EPS, rtol=1e-3, atol=1e-5)
  with pytest.raises(stylize.UserError, match="no views"):
    stylize.scene_content_stats(enc, [])


@pytest.fixture(scope="module")
def enc():
  return vgg.load_vgg_params()


def test_style_vector(enc):
  image = jax.random.uniform(jax.random.PRNGKey(4), (32, 48, 3))
  v = adain.style_vector_jit(enc, image)
  assert v.shape == (1024,) and v.dtype == jnp.float32
  feats = adain.encode(enc, image[None])["relu4_1"]
  assert feats.shape == (1, 4, 6, 512)
  mean, std = adain.channel_stats(feats)
  np.testing.assert_allclose(v[:512], mean[0], rtol=1e-5, atol=1e-5)
  np.testing.assert_allclose(v[512:], std[0], rtol=1e-5, atol=1e-5)
  m2, s2 = v[None, :512], v[None, 512:]  # the vector splits back into the statistics
  assert m2.shape == s2.shape == (1, 512)
  other = adain.style_vector(enc, jnp.flip(image, 0) ** 2)
  assert not np.allclose(v, other)  # depends on the image
  with pytest.raises(AssertionError):
    adain.style_vector(enc, jnp.zeros((2, 32, 32, 3)))  # one image only


def test_style_loss(enc):
  a = adain.style_stats(enc, jax.random.uniform(jax.random.PRNGKey(5), (1, 32, 32, 3)))
  b = adain.style_stats(enc, jax.random.uniform(jax.random.PRNGKey(6), (1, 32, 32, 3)) ** 3)
  assert set(a) == set(vgg.STYLE_LAYERS)
  assert float(adain.style_loss(a, a)) == 0.0
  ab = float(adain.style_loss(a, b))
  assert ab > 0.0
  np.testing.assert_allclose(ab, float(adain.style_loss(b, a)), rtol=1e-6)


def test_match_color_matches_content_mean_and_covariance():
  rng = np.random.default_rng(0)
  style = rng.random((20, 30, 3)).astype(np.float32) * np.array([1.0, 0.3, 0.1], np.float32)
  content = (0.3 + 0.2 * rng.random((16, 16, 3))).astype(np.float32)
  content[..., 2] = 0.5 * content[..., 0] + 0.1
  out = np.asarray(jax.jit(stylize.match_color)(jnp.asarray(style), jnp.asarray(content)))
  assert out.shape == style.shape
  np.testing.assert_allclose(out.reshape(-1, 3).mean(0), content.reshape(-1, 3).mean(0), atol=2e-3)
  np.testing.assert_allclose(np.cov(out.reshape(-1, 3).T), np.cov(content.reshape(-1, 3).T), atol=2e-3)


def test_colour_map_weighted_by_opacity_moves_the_scene_not_its_background():
  """A dark object on a white background, mapped to a blue-and-white style: weighted by the
  opacity, the object's own pixels get the style's mean and covariance (the white around it
  does not count); unweighted, the white background takes the style's light colours and the
  object ends up darker than any of them."""
  rng = np.random.default_rng(1)
  photo = np.ones((24, 24, 3), np.float32)
  alpha = np.zeros((24, 24), np.float32)
  alpha[6:18, 6:18] = 1.0
  photo[6:18, 6:18] = 0.1 + 0.2 * rng.random((12, 12, 3))
  style = np.stack([0.2 + 0.8 * rng.random((32, 32)), 0.5 + 0.5 * rng.random((32, 32)),
                    np.full((32, 32), 0.95)], -1).astype(np.float32)
  weighted = stylize.apply_colour_map(jnp.asarray(photo), *stylize.colour_map(
      jnp.asarray(photo), jnp.asarray(style), source_weights=jnp.asarray(alpha)))
  plain = stylize.apply_colour_map(jnp.asarray(photo), *stylize.colour_map(
      jnp.asarray(photo), jnp.asarray(style)))
  inside = np.asarray(weighted)[6:18, 6:18].reshape(-1, 3)
  np.testing.assert_allclose(inside.mean(0), style.reshape(-1, 3).mean(0), atol=0.03)
  np.testing.assert_allclose(np.cov(inside.T, bias=True), np.cov(style.reshape(-1, 3).T),
                             atol=0.01)
  assert np.asarray(plain)[6:18, 6:18].mean() < inside.mean() - 0.1
  # All weights alike: the unweighted map, up to its n - 1 in the covariance.
  ones = stylize.colour_map(jnp.asarray(photo), jnp.asarray(style),
                            source_weights=jnp.ones((24, 24)))
  for a, b in zip(ones, stylize.colour_map(jnp.asarray(photo), jnp.asarray(style))):
    np.testing.assert_allclose(a, b, rtol=5e-3, atol=1e-4)


def test_cover_crop_and_padding():
  image = np.zeros((100, 50, 3), np.float32)
  image[:, 20:30] = 1.0  # a vertical stripe in the middle
  out = stylize.cover_crop(image, 40, 80)
  assert out.shape == (40, 80, 3)
  # Width scaled x1.6: the stripe stays centred.
  assert out[20, 40, 0] > 0.9 and out[20, 5, 0] < 0.1
  assert stylize.cover_crop(image, 10, 10).shape == (10, 10, 3)
  assert stylize.pad_to_multiple(np.zeros((37, 45, 3))).shape == (40, 48, 3)
