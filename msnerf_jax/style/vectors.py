"""Styles at render time: resolving a style (a training style's name or an image file),
blends of two styles, the strength control and morph paths, all on 1024-d style vectors.

No rendering here: these give the style vectors [1024] float32 a multi-style run renders.
"""

import os
from typing import Any, Dict, List, Mapping, Optional, Sequence, Tuple

import jax.numpy as jnp
import numpy as np

from msnerf_jax.data import images as images_lib
from msnerf_jax.data.stylized import ORIGINAL
from msnerf_jax.style import adain as adain_lib
from msnerf_jax.core.errors import UserError


def blend(a: np.ndarray, b: np.ndarray, t: float) -> np.ndarray:
  """(1 - t) a + t b of two style vectors [D]: t = 0 gives a and t = 1 gives b exactly."""
  return ((1.0 - t) * np.asarray(a, np.float32) + t * np.asarray(b, np.float32)).astype(np.float32)


def check_unit(name: str, value: Optional[float]) -> None:
  """UserError unless `value` (an option `name`, e.g. "--t") is None or in [0, 1]."""
  if value is not None and not 0.0 <= value <= 1.0:
    raise UserError(f"{name} {value}: must be in [0, 1]")


def resolve_style(spec: str, vectors: Mapping[str, np.ndarray],
                  encoder_cache: Dict[str, Any],
                  size: Optional[Tuple[int, int]] = None) -> np.ndarray:
  """A style vector [1024] from a training style's name or an image file.

  Args:
    spec: a key of `vectors`, or the path of any image (a style never trained on).
    vectors: training style name -> [1024].
    encoder_cache: a dict that keeps the VGG encoder between calls (loaded on first use).
    size: (height, width) an image is cover-cropped to first (style_vector_of): the size a
      feature run's decoder paints; None for a multi-style run's style vectors.
  Raises:
    UserError when `spec` is neither, or the image is smaller than 16x16.
  """
  if spec in vectors:
    return vectors[spec]
  if os.path.isfile(spec):
    from msnerf_jax.models import vgg  # pylint: disable=g-import-not-at-top
    if "encoder" not in encoder_cache:
      encoder_cache["encoder"] = vgg.load_vgg_params()
    image = images_lib.read_image(spec, max_side=1024)
    if min(image.shape[:2]) < 16:
      raise UserError(f"{spec}: style image is {image.shape[1]}x{image.shape[0]}, need at least "
                      "16x16")
    return style_vector_of(encoder_cache["encoder"], image, size)
  raise UserError(f"style {spec!r}: neither a training style ({', '.join(vectors)}) nor an "
                  "image file")


def at_strength(vectors: Mapping[str, np.ndarray], style: np.ndarray, strength: float,
                source: str) -> np.ndarray:
  """`style` [1024] at `strength` between the original scene (0) and the style (1).

  Raises:
    UserError naming `source` (the run) when it has no "original" style to blend from.
  """
  if ORIGINAL not in vectors:
    raise UserError(f"--strength: {source} has no {ORIGINAL!r} style (make the dataset with "
                    "--include-original)")
  return blend(vectors[ORIGINAL], style, strength)


def choose_main_style(vectors: Mapping[str, np.ndarray], encoder_cache: Dict[str, Any],
                      source: str, style: Optional[str] = None,
                      interp: Optional[Sequence[str]] = None, t: float = 0.5,
                      strength: Optional[float] = None,
                      size: Optional[Tuple[int, int]] = None) -> Tuple[np.ndarray, str]:
  """(style vector [1024], label) of `msnerf render`'s main video.

  Args:
    vectors: the run's training styles, name -> [1024] (the first is the default style).
    source: the run folder (named in errors).
    style: a STYLE (name or image file); default the first training style.
    interp: two STYLEs A, B: the blend (1 - t) A + t B instead of `style`.
    strength: in [0, 1], the chosen style's strength over the original scene.
    size: as resolve_style's.
  """
  check_unit("--t", t)
  check_unit("--strength", strength)
  if interp:
    main = blend(resolve_style(interp[0], vectors, encoder_cache, size),
                 resolve_style(interp[1], vectors, encoder_cache, size), t)
    label = f"{interp[0]} -> {interp[1]} at t={t:g}"
  else:
    label = style or next(iter(vectors))
    main = resolve_style(label, vectors, encoder_cache, size)
  if strength is not None:
    main = at_strength(vectors, main, strength, source)
    label += f" at strength {strength:g}"
  return main, label


def morph_ends(vectors: Mapping[str, np.ndarray], encoder_cache: Dict[str, Any],
               morph: Optional[Sequence[str]] = None,
               size: Optional[Tuple[int, int]] = None
               ) -> Tuple[Optional[List[str]], Optional[List[np.ndarray]]]:
  """(the two STYLEs, their vectors) a morph goes between: `morph`, else the first two
  training styles; (None, None) when the run has a single style and none is given."""
  names = list(vectors)
  ends = list(morph) if morph else (names[:2] if len(names) >= 2 else None)
  if ends is None:
    return None, None
  return ends, [resolve_style(s, vectors, encoder_cache, size) for s in ends]


def sweep(a: np.ndarray, b: np.ndarray, n: int) -> List[np.ndarray]:
  """n style vectors going from a to b in equal steps, both ends included (n >= 2)."""
  return [blend(a, b, t) for t in np.linspace(0.0, 1.0, n)]


def morph_loop(vectors: Sequence[np.ndarray], n: int) -> List[np.ndarray]:
  """n style vectors moving through `vectors` in a loop (v0 -> v1 -> ... -> v0)."""
  k = len(vectors)
  out = []
  for i in range(n):
    u = i * k / n
    j = int(np.floor(u))
    out.append(blend(vectors[j % k], vectors[(j + 1) % k], u - j))
  return out


VECTOR_MAX_SIDE = 512  # style images are shrunk to this before their style vector is taken.


def style_vector_of(encoder_params: Any, image: np.ndarray,
                    size: Optional[Tuple[int, int]] = None) -> np.ndarray:
  """The style vector [1024] of an image [h, w, 3] in [0, 1], with its longer side shrunk to
  VECTOR_MAX_SIDE, so the vector of a style does not depend on the file's resolution (and one
  compilation serves most images). Used for training styles and for any image at render time.

  With `size` (height, width), the image is cover-cropped to it instead, as AdaIN crops a
  style for a content image of that size (stylize.stylize_image): the statistics a feature
  run paints with, so its strokes have the scale per-frame AdaIN's have.
  """
  h, w = image.shape[:2]
  scale = VECTOR_MAX_SIDE / max(h, w)
  if size is not None and min(h, w) >= 16:
    image = images_lib.cover_crop(image, *size)
  elif scale < 1:
    image = images_lib.resize(image, max(16, round(h * scale)), max(16, round(w * scale)))
  if min(image.shape[:2]) < 16:
    raise UserError(f"style image of {w}x{h} pixels is too small (needs at least 16x16)")
  return np.asarray(adain_lib.style_vector_jit(encoder_params, jnp.asarray(image, jnp.float32)))
