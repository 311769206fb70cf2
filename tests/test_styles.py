"""Styles at render time (msnerf_jax.style.vectors): choosing, blending and morphing style vectors."""

import numpy as np
import pytest

from msnerf_jax.style import vectors as styles
from msnerf_jax.core.errors import UserError

RNG = np.random.default_rng(0)
VECTORS = {name: RNG.normal(size=1024).astype(np.float32) for name in ("a", "b", "original")}


def test_blend_and_sweep_hit_both_ends_exactly():
  a, b = VECTORS["a"], VECTORS["b"]
  assert np.array_equal(styles.blend(a, b, 0.0), a) and np.array_equal(styles.blend(a, b, 1.0), b)
  path = styles.sweep(a, b, 5)
  assert len(path) == 5 and np.array_equal(path[0], a) and np.array_equal(path[-1], b)
  np.testing.assert_allclose(path[2], (a + b) / 2, atol=1e-6)


def test_morph_loop_goes_through_every_style_and_back():
  vs = [VECTORS["a"], VECTORS["b"]]
  path = styles.morph_loop(vs, 8)
  assert len(path) == 8
  assert np.array_equal(path[0], vs[0]) and np.array_equal(path[4], vs[1])
  np.testing.assert_allclose(path[6], (vs[0] + vs[1]) / 2, atol=1e-6)  # on the way back


def test_main_style_by_name_blend_and_strength():
  cache = {}
  main, label = styles.choose_main_style(VECTORS, cache, "run")
  assert label == "a" and np.array_equal(main, VECTORS["a"])
  main, label = styles.choose_main_style(VECTORS, cache, "run", interp=("a", "b"), t=0.25)
  np.testing.assert_allclose(main, 0.75 * VECTORS["a"] + 0.25 * VECTORS["b"], atol=1e-6)
  assert label == "a -> b at t=0.25"
  main, label = styles.choose_main_style(VECTORS, cache, "run", style="b", strength=0.0)
  assert np.array_equal(main, VECTORS["original"]) and label == "b at strength 0"
  assert cache == {}  # no encoder loaded for training styles


def test_bad_style_choices_are_named():
  no_original = {k: v for k, v in VECTORS.items() if k != "original"}
  with pytest.raises(UserError, match="--strength: run has no 'original' style"):
    styles.choose_main_style(no_original, {}, "run", strength=0.5)
  with pytest.raises(UserError, match=r"--t 1.5: must be in \[0, 1\]"):
    styles.choose_main_style(VECTORS, {}, "run", interp=("a", "b"), t=1.5)
  with pytest.raises(UserError, match="style 'nope': neither a training style"):
    styles.resolve_style("nope", VECTORS, {})


def test_morph_ends_default_to_the_first_two_styles():
  names, ends = styles.morph_ends(VECTORS, {})
  assert names == ["a", "b"] and np.array_equal(ends[1], VECTORS["b"])
  assert styles.morph_ends({"a": VECTORS["a"]}, {}) == (None, None)
