"""AdaIN in 3D: stylizing a rendered VGG feature map (a feature field's, see
models/feature_field.py) and painting it with the frozen AdaIN decoder.

A style is one per-channel affine map of the scene's features, with the content statistics
pooled once over the whole scene (never per frame), so every view gets the same map and the
features the decoder paints from stay fixed to the scene. The map is applied to the
composited features: AdaIN is affine and compositing linear, so this equals stylizing every
3D sample and compositing, once the constant terms are scaled by the accumulated opacity.
"""

from typing import Any, Sequence, Tuple

import chex
import jax
import jax.numpy as jnp
import numpy as np

from msnerf_jax.style.adain import EPS
from msnerf_jax.data import images as images_lib
from msnerf_jax.core.errors import UserError
from msnerf_jax.models import decoder as decoder_lib

# (mean, std) channel statistics, each broadcastable to the features' [..., C].
Stats = Tuple[Any, Any]
CELL = 8  # input pixels per relu4_1 cell along each side (three 2x poolings).


def stylize_features(features: jnp.ndarray, accumulation: jnp.ndarray, content_stats: Stats,
                     style_stats: Stats, alpha=1.0) -> jnp.ndarray:
  """AdaIN of composited features with fixed content statistics (pure, jittable, vmappable).

  T(F) = std / c_std * (F - c_mean * A) + mean * A, with the target statistics blended by
  the strength: mean = alpha * s_mean + (1 - alpha) * c_mean (likewise the std), which is
  the AdaIN paper's alpha * AdaIN(c, s) + (1 - alpha) * c. Applied to F = sum_i w_i f_i and
  A = sum_i w_i it equals sum_i w_i T(f_i); alpha = 0 returns F.

  Args:
    features: [..., C] composited features (a feature map [H, W, C], cells, rays).
    accumulation: [...] the summed compositing weights of each (1 where a background
      feature fills the rest).
    content_stats: (mean, std), each [C]: the scene's pooled statistics.
    style_stats: (mean, std), each [C] (or [..., C] broadcastable): the style's.
    alpha: strength in [0, 1] (may be traced).
  Returns:
    [..., C].
  """
  chex.assert_equal_shape_prefix([features, accumulation], accumulation.ndim)
  c_mean, c_std = content_stats
  s_mean, s_std = style_stats
  chex.assert_shape([c_mean, c_std], (features.shape[-1],))
  mean = alpha * s_mean + (1.0 - alpha) * c_mean
  std = alpha * s_std + (1.0 - alpha) * c_std
  a = accumulation[..., None]
  return std / c_std * (features - c_mean * a) + mean * a


def style_vector_of_stats(stats: Stats) -> np.ndarray:
  """The style vector [1024] (means, then stds: adain.style_vector's layout) of relu4_1
  statistics (mean, std) [512], e.g. a scene's content statistics: AdaIN towards them is
  the identity, so blending a style's vector towards them sets the strength."""
  return np.concatenate([np.ravel(stats[0]), np.ravel(stats[1])]).astype(np.float32)


def painted_size(height: int, width: int, scale: int) -> Tuple[int, int]:
  """(height, width) the decoder paints a view of height x width at stylize scale `scale`:
  enlarged and padded to whole cells (what per-frame AdaIN crops a style picture to)."""
  return -(-height * scale // CELL) * CELL, -(-width * scale // CELL) * CELL


# The cell-grid offsets (rows, cols; enlarged pixels) a view's decodes are averaged over
# (views.render_feature_styles' `grids`): the grid moved by half a cell along each axis.
GRID_OFFSETS = {1: ((0, 0),), 2: ((0, 0), (4, 4)), 4: ((0, 0), (0, 4), (4, 0), (4, 4))}
DEFAULT_GRIDS = 1


def grid_offsets(grids: int) -> Tuple[Tuple[int, int], ...]:
  """The offsets of GRID_OFFSETS[grids]; UserError for another number."""
  if grids not in GRID_OFFSETS:
    raise UserError(f"--grids {grids}: choose from {', '.join(map(str, GRID_OFFSETS))}")
  return GRID_OFFSETS[grids]


def cell_grid(height: int, width: int, scale: int, per_side: int = 2,
              offset: Tuple[int, int] = (0, 0), pad: int = 0
              ) -> Tuple[np.ndarray, np.ndarray]:
  """Sub-pixel positions of the rays a relu4_1 cell averages: an image of height x width
  stylized `scale` x enlarged (and padded to multiples of CELL) has ceil(scale h / 8) x
  ceil(scale w / 8) cells, each over an 8 x 8 block of the enlarged image, that is 8 / scale
  pixels of the view; per_side x per_side rays sit at the centres of its sub-blocks.

  offset: (rows, cols) enlarged pixels the grid starts above and left of the view's corner;
  pad: enlarged pixels added below and right before the cells are counted (pad >= offset:
  the moved grid still covers the view; the same pad gives every offset the same shape).

  Returns: rows, cols [cells_h, cells_w, per_side ** 2] in the view's pixel coordinates
  (pixel centres at integers).
  """
  images_lib.check_scale(scale)
  ch, cw = -(-(height * scale + pad) // CELL), -(-(width * scale + pad) // CELL)
  sub = (np.arange(per_side) + 0.5) / per_side
  def axis(n, start):  # [n, per_side]: block start plus sub-block centres, in view pixels.
    return (CELL * (np.arange(n)[:, None] + sub) - start) / scale - 0.5
  rows = np.broadcast_to(axis(ch, offset[0])[:, None, :, None], (ch, cw, per_side, per_side))
  cols = np.broadcast_to(axis(cw, offset[1])[None, :, None, :], (ch, cw, per_side, per_side))
  return (rows.reshape(ch, cw, -1).astype(np.float32),
          cols.reshape(ch, cw, -1).astype(np.float32))


def pooled_stats(feature_maps: Sequence[np.ndarray]) -> Tuple[np.ndarray, np.ndarray]:
  """(mean [C], std [C]) over every position of every map [h, w, C] (float64 sums; std
  unbiased, like adain.channel_stats, plus its eps)."""
  total = squares = 0.0
  count = 0
  for f in feature_maps:
    flat = np.asarray(f, np.float64).reshape(-1, f.shape[-1])
    total = total + flat.sum(0)
    squares = squares + np.square(flat).sum(0)
    count += flat.shape[0]
  mean = total / count
  var = np.maximum(squares - count * mean * mean, 0.0) / max(count - 1, 1)
  return mean.astype(np.float32), (np.sqrt(var) + EPS).astype(np.float32)


def _decode(decoder_params, features, accumulation, content_stats, style_means, style_stds,
            alpha, upsample: str):
  """[h, w, C] features -> [K, 8h, 8w, 3] in [0, 1], one image per style (K stats)."""
  styled = jax.vmap(lambda m, s: stylize_features(features, accumulation, content_stats,
                                                  (m, s), alpha))(style_means, style_stds)
  return decoder_lib.paint(decoder_params, styled, upsample)


decode_styles_jit = jax.jit(_decode, static_argnames=("upsample",))


def decode_styles(decoder, feature_map: np.ndarray, accumulation: np.ndarray,
                  content_stats: Stats, style_means: np.ndarray, style_stds: np.ndarray,
                  alpha: float, height: int, width: int, scale: int,
                  offset: Tuple[int, int] = (0, 0)) -> np.ndarray:
  """One feature map painted in K styles: [K, height, width, 3] float32 in [0, 1].

  The decoder paints the cells at scale x the view's size (cropped from the padding), and
  the result is box-averaged back to height x width, as stylize.stylize_image does.

  Args:
    decoder: stylize.Decoder; feature_map [h, w, 512], accumulation [h, w].
    offset: the (rows, cols) enlarged pixels the map's cell grid starts above and left of
      the view (cell_grid's): the painting is cropped from there.
    style_means, style_stds: [K, 512] (e.g. blends: adain.blend_stats).
  """
  out = np.asarray(decode_styles_jit(decoder.params, jnp.asarray(feature_map),
                                     jnp.asarray(accumulation), content_stats,
                                     jnp.asarray(style_means), jnp.asarray(style_stds),
                                     jnp.float32(alpha), upsample=decoder.config.upsample))
  out = out[:, offset[0]:offset[0] + height * scale, offset[1]:offset[1] + width * scale]
  if scale > 1:
    out = np.stack([images_lib.resize(o, height, width) for o in out])
  return out
