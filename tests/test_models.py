"""The NeRF MLP: the `trunk` contract and the reference architecture's size."""

import jax
import jax.numpy as jnp
import numpy as np

from msnerf_jax.core.config import nerf_preset
from msnerf_jax.models.nerf import init_nerf_params, mlp_flops_per_sample, nerf_mlp


def count(tree):
  return sum(x.size for x in jax.tree_util.tree_leaves(tree))


def test_paper_preset_has_reference_layout_and_size():
  config = nerf_preset("paper", "blender")
  params = init_nerf_params(config, jax.random.PRNGKey(0))
  assert set(params) == {"coarse", "fine"}
  for net in params.values():
    assert set(net) == {"trunk", "rgb"}
    assert set(net["trunk"]) == {*(f"point_{i}" for i in range(8)), "density", "feature", "view"}
    assert net["trunk"]["point_5"]["kernel"].shape == (63 + 256, 256)  # skip after layer 4
    assert net["trunk"]["view"]["kernel"].shape == (256 + 27, 128)
    assert net["rgb"]["kernel"].shape == (128, 3)
    # The reference PyTorch NeRF (use_viewdirs, 8x256) has 595,844 parameters.
    assert count(net) == 595_844
  assert mlp_flops_per_sample(config) == 2 * (595_844 - 256 * 8 - 1 - 256 - 128 - 3)


def test_per_ray_viewdirs_equal_per_sample_viewdirs():
  config = nerf_preset("cpu", "blender")
  model = nerf_mlp(config)
  params = init_nerf_params(config, jax.random.PRNGKey(1))["fine"]
  pts = jax.random.normal(jax.random.PRNGKey(2), (4, 5, 3))
  d = jax.random.normal(jax.random.PRNGKey(3), (4, 1, 3))
  rgb1, s1 = model.apply({"params": params}, pts, d)
  rgb2, s2 = model.apply({"params": params}, pts, jnp.broadcast_to(d, pts.shape))
  np.testing.assert_allclose(rgb1, rgb2, atol=1e-6)
  np.testing.assert_allclose(s1, s2, atol=1e-6)
  assert rgb1.shape == (4, 5, 3) and s1.shape == (4, 5)
  assert jnp.all((rgb1 >= 0) & (rgb1 <= 1))
