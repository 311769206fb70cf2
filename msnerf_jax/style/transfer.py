"""Stylizing images with a trained AdaIN decoder: cover-crop styles, alpha, blends, colour."""

import dataclasses
from typing import Any, Optional, Sequence, Tuple

import chex
import jax
import jax.numpy as jnp
import numpy as np

from msnerf_jax.style import adain as adain_lib
from msnerf_jax.core import config as config_lib
from msnerf_jax.data import images as images_lib
from msnerf_jax.data.images import cover_crop
from msnerf_jax.core.errors import UserError
from msnerf_jax.models import decoder as decoder_lib
from msnerf_jax.core.progress import progress_bar

# (mean, std) [1, C] channel statistics.
Stats = Tuple[Any, Any]


def colour_map(source: jnp.ndarray, target: jnp.ndarray, eps: float = 1e-5,
               source_weights: Optional[jnp.ndarray] = None
               ) -> Tuple[jnp.ndarray, jnp.ndarray, jnp.ndarray]:
  """The affine map of RGB values that gives the pixels of `source` [..., 3] (all of them
  together) the mean and covariance of `target`'s [..., 3]: x' = T (x - mu_s) + mu_t with
  T = C_t^1/2 C_s^-1/2. Returns (T [3, 3], mu_s [3], mu_t [3]).

  source_weights: [...] (source's shape without its last axis), each pixel's weight in
  source's mean and covariance, e.g. its opacity, so that a white background does not count
  as the scene's colour; None: every pixel alike.
  """
  def stats(x):
    flat = x.reshape(-1, 3)
    mu = jnp.mean(flat, axis=0)
    centred = flat - mu
    # eps * I keeps the inverse square root finite on flat (e.g. grey) images.
    cov = centred.T @ centred / max(flat.shape[0] - 1, 1) + eps * jnp.eye(3)
    return mu, cov

  def weighted_stats(x, w):
    flat, w = x.reshape(-1, 3), jnp.reshape(w, (-1, 1))
    total = jnp.maximum(jnp.sum(w), eps)
    mu = jnp.sum(w * flat, axis=0) / total
    centred = flat - mu
    return mu, (w * centred).T @ centred / total + eps * jnp.eye(3)

  def sqrtm(c, power):
    vals, vecs = jnp.linalg.eigh(c)
    return (vecs * jnp.maximum(vals, eps) ** power) @ vecs.T

  mu_s, cov_s = (stats(source) if source_weights is None
                 else weighted_stats(source, source_weights))
  mu_t, cov_t = stats(target)
  return sqrtm(cov_t, 0.5) @ sqrtm(cov_s, -0.5), mu_s, mu_t


def apply_colour_map(images: jnp.ndarray, transform: jnp.ndarray, mu_s: jnp.ndarray,
                     mu_t: jnp.ndarray) -> jnp.ndarray:
  """colour_map's map applied to images [..., 3], clipped to [0, 1]."""
  out = (images.reshape(-1, 3) - mu_s) @ transform.T + mu_t
  return jnp.clip(out.reshape(images.shape), 0.0, 1.0)


def match_color(source: jnp.ndarray, target: jnp.ndarray, eps: float = 1e-5) -> jnp.ndarray:
  """Colour-preserving transfer (Gatys et al., used by the AdaIN paper sec. 7.2).

  An affine map of `source`'s RGB values so that their mean and covariance equal those of
  `target` (colour_map).

  Args:
    source: [h, w, 3] (the style image), target: [h', w', 3] (the content image).
  Returns:
    [h, w, 3], clipped to [0, 1].
  """
  chex.assert_rank([source, target], 3)
  return apply_colour_map(source, *colour_map(source, target, eps))


@dataclasses.dataclass(frozen=True)
class Decoder:
  """A trained decoder loaded from a run folder."""
  run_dir: str
  config: config_lib.AdainConfig
  params: Any
  step: int


def style_stats_relu4_1(encoder_params: Any, styles: jnp.ndarray) -> tuple:
  """(mean [K, 512], std [K, 512]) of relu4_1 of style images [K, H, W, 3]."""
  return adain_lib.channel_stats(adain_lib.encode(encoder_params, styles)["relu4_1"])


def decode_with_stats(decoder_params: Any, encoder_params: Any, content: jnp.ndarray,
                      mean: jnp.ndarray, std: jnp.ndarray, alpha: float, upsample: str,
                      content_stats: Optional[Stats] = None) -> jnp.ndarray:
  """Content [1, H, W, 3] with target relu4_1 statistics (mean, std [1, 512]) -> [1, H, W, 3].

  H and W should be multiples of 8 (the decoder output is 8x the relu4_1 size).
  `content_stats` (mean, std [1, 512]) replace the content's own relu4_1 statistics.
  """
  feats = adain_lib.encode(encoder_params, content)["relu4_1"]
  target = adain_lib.adain_from_stats(feats, mean, std, alpha, content_stats)
  return decoder_lib.paint(decoder_params, target, upsample)


def stylize_arrays(decoder_params: Any, encoder_params: Any, content: jnp.ndarray,
                   styles: jnp.ndarray, weights: jnp.ndarray, alpha: float,
                   upsample: str, content_stats: Optional[Stats] = None) -> jnp.ndarray:
  """Stylizes one content image with a weighted blend of K styles (all jit-able).

  Args:
    content: [1, H, W, 3] in [0, 1], H, W multiples of 8.
    styles: [K, H', W', 3] in [0, 1].
    weights: [K] non-negative (normalised here).
    alpha: style strength in [0, 1].
    content_stats: optional (mean, std [1, 512]) relu4_1 statistics that normalise the
      content instead of its own (see `scene_content_stats`).
  Returns:
    [1, H, W, 3] in [0, 1].
  """
  chex.assert_shape(content, (1, None, None, 3))
  chex.assert_rank(styles, 4)
  means, stds = style_stats_relu4_1(encoder_params, styles)
  mean, std = adain_lib.blend_stats(means, stds, weights)
  return decode_with_stats(decoder_params, encoder_params, content, mean, std, alpha, upsample,
                           content_stats)


_stylize_jit = jax.jit(stylize_arrays, static_argnames=("upsample",))


@jax.jit
def _relu4_1_sums(encoder_params: Any, image: jnp.ndarray):
  """Sums over positions of relu4_1 features and of their squares ([C], [C]), and the count."""
  f = adain_lib.encode(encoder_params, image)["relu4_1"]
  return jnp.sum(f, axis=(0, 1, 2)), jnp.sum(jnp.square(f), axis=(0, 1, 2)), f[..., 0].size


def scene_content_stats(encoder_params: Any, views: Sequence[np.ndarray], scale: int = 1,
                        progress: bool = False) -> Stats:
  """relu4_1 mean and std over every position of every view, as `stylize_image` sees them.

  Per-view AdaIN normalises each view by its own statistics, which change with what the
  view shows, so one surface gets a different colour map in each view. Normalising every
  view by these scene statistics instead gives all views the same map.

  Args:
    views: [H, W, 3] images in [0, 1] (e.g. a scene's training views).
    scale: the stylize scale (views are enlarged and padded as `stylize_image` does).
  Returns:
    (mean [1, 512], std [1, 512]) float32; std is unbiased plus adain.EPS, like
    `adain.channel_stats`.
  """
  if not len(views):
    raise UserError("no views to take scene statistics from")
  images_lib.check_scale(scale)
  sums = squares = 0.0
  count = 0
  for view in progress_bar(views, desc="scene statistics", disable=not progress, leave=False):
    s, q, n = _relu4_1_sums(encoder_params, jnp.asarray(enlarged(view, scale)[None]))
    sums = sums + np.asarray(s, np.float64)
    squares = squares + np.asarray(q, np.float64)
    count += int(n)
  mean = sums / count
  var = np.maximum(squares - count * mean * mean, 0.0) / max(count - 1, 1)
  return (mean[None].astype(np.float32),
          (np.sqrt(var) + adain_lib.EPS)[None].astype(np.float32))


def pad_to_multiple(image: np.ndarray, multiple: int = 8) -> np.ndarray:
  """Reflect-pads [h, w, 3] at the bottom/right to multiples of `multiple`."""
  h, w = image.shape[:2]
  ph, pw = (-h) % multiple, (-w) % multiple
  if ph == 0 and pw == 0:
    return image
  return np.pad(image, ((0, ph), (0, pw), (0, 0)), mode="reflect" if min(h, w) > max(ph, pw) else "edge")


def enlarged(view: np.ndarray, scale: int) -> np.ndarray:
  """A view [H, W, 3] enlarged `scale` times and padded to multiples of 8, as stylize_image
  hands it to the encoder: [8 ceil(sH/8), 8 ceil(sW/8), 3] float32."""
  h, w = view.shape[:2]
  return pad_to_multiple(images_lib.resize(np.asarray(view, np.float32), h * scale, w * scale))


def stylize_image(decoder: Decoder, encoder_params: Any, content: np.ndarray,
                  styles: Sequence[np.ndarray], weights: Optional[Sequence[float]] = None,
                  alpha: float = 1.0, preserve_color: bool = False,
                  scale: int = 1, content_stats: Optional[Stats] = None) -> np.ndarray:
  """Stylizes content [H, W, 3] with styles (each [h, w, 3]), blended by `weights`.

  Each style is resized to cover the content and centre-cropped to its size (reference
  behaviour for NeRF views); with `preserve_color`, each style's colours are first matched
  to the content's. With `scale` > 1 the content is enlarged (bicubic) to scale x its size,
  stylized there (styles cover the enlarged size), and the result is box-averaged back: the
  strokes are `scale` x finer relative to the scene, as when the reference code stylizes 400x400
  Blender views that are then trained on at 100x100. `content_stats` (from
  `scene_content_stats` at the same scale) normalise the content instead of its own relu4_1
  statistics. Returns [H, W, 3] float32 in [0, 1].
  """
  if not styles:
    raise UserError("no style image given")
  weights = [1.0] * len(styles) if weights is None else list(weights)
  check_weights(weights, len(styles))
  if not 0.0 <= alpha <= 1.0:
    raise UserError(f"--alpha {alpha}: must be in [0, 1]")
  images_lib.check_scale(scale)
  h, w = content.shape[:2]
  if scale > 1:
    big = stylize_image(decoder, encoder_params, images_lib.resize(content, h * scale, w * scale),
                        styles, weights, alpha, preserve_color, content_stats=content_stats)
    return images_lib.resize(big, h, w)
  padded = pad_to_multiple(content)
  ph, pw = padded.shape[:2]
  crops = np.stack([cover_crop(s, ph, pw) for s in styles])
  if preserve_color:
    crops = np.stack([np.asarray(match_color(jnp.asarray(s), jnp.asarray(padded))) for s in crops])
  out = _stylize_jit(decoder.params, encoder_params, jnp.asarray(padded[None]), jnp.asarray(crops),
                     jnp.asarray(weights, jnp.float32), jnp.float32(alpha),
                     upsample=decoder.config.upsample, content_stats=content_stats)
  return np.asarray(out[0, :h, :w])


def check_weights(weights: Sequence[float], n_styles: int) -> None:
  """UserError unless there is one non-negative weight per style and their sum is positive."""
  if len(weights) != n_styles:
    raise UserError(f"--weights: got {len(weights)} weights for {n_styles} styles")
  if any(not np.isfinite(x) or x < 0 for x in weights) or sum(weights) <= 0:
    raise UserError(f"--weights {' '.join(map(str, weights))}: must be >= 0 with a positive sum")
