"""The AdaIN trainer's losses: content and style through the frozen VGG, and the shift
consistency of the decoder's strokes (beyond the AdaIN paper)."""

from typing import Any, Dict, Optional, Tuple

import chex
import jax
import jax.numpy as jnp

from msnerf_jax.style import adain as adain_lib
from msnerf_jax.core import config as config_lib
from msnerf_jax.style.features import CELL
from msnerf_jax.models import decoder as decoder_lib
from msnerf_jax.models import vgg


SHIFT_MARGIN = 8  # pixels at each border of a crop left out of the shift loss (border effects).


def window(images: jnp.ndarray, corners: jnp.ndarray, side: int) -> jnp.ndarray:
  """Square windows: images [B, H, W, C], corners [B, 2] int (y, x) -> [B, side, side, C]."""
  take = lambda image, corner: jax.lax.dynamic_slice(
      image, (corner[0], corner[1], 0), (side, side, image.shape[-1]))
  return jax.vmap(take)(images, corners)


def resample_cells(features: jnp.ndarray, shifts: jnp.ndarray) -> jnp.ndarray:
  """A relu4_1 map moved by a sub-cell shift, bilinear between neighbouring cells: what a
  feature field's render gives when the camera moves the scene by (dy, dx) pixels.

  Args:
    features: [B, h, w, C]; shifts: [B, 2] int (dy, dx) pixels, each in [0, CELL].
  Returns:
    [B, h - 1, w - 1, C]: cell (i, j) is the map at (i + dy / CELL, j + dx / CELL).
  """
  a = (shifts[:, 0].astype(features.dtype) / CELL)[:, None, None, None]
  b = (shifts[:, 1].astype(features.dtype) / CELL)[:, None, None, None]
  rows = (1 - a) * features[:, :-1] + a * features[:, 1:]
  return (1 - b) * rows[:, :, :-1] + b * rows[:, :, 1:]


def shift_loss(decoder_params: Any, encoder_params: Any, content: jnp.ndarray,
               output: jnp.ndarray, style_mean: jnp.ndarray, style_std: jnp.ndarray,
               shifts: jnp.ndarray, upsample: str, source: str = "photo",
               target: Optional[jnp.ndarray] = None) -> jnp.ndarray:
  """Shift consistency of the stylization: decoding a moved crop moves the strokes with it.

  The window of side S - CELL at (dy, dx) of each content crop is stylized on its own (its
  relu4_1 cells sit dy, dx pixels off the crop's) and compared with the same window of the
  crop's stylization `output`, SHIFT_MARGIN pixels from the window's borders left out. With
  source "photo" the window's map is the encoder's of the moved pixels; with "features" it is
  the crop's AdaIN map `target` resampled by the shift (`resample_cells`).

  Args:
    content, output: [B, S, S, 3] (content read with "photo" only); style_mean, style_std:
      [B, 512] (relu4_1 statistics).
    shifts: [B, 2] int (dy, dx), each in [1, CELL).
    source: "photo" or "features" (config.SHIFT_SOURCES).
    target: [B, S / CELL, S / CELL, 512], the crop's AdaIN map; read with "features".
  Returns:
    [] mean squared pixel difference.
  """
  side = output.shape[1] - CELL
  if source == "features":
    chex.assert_shape(target, (output.shape[0], output.shape[1] // CELL,
                               output.shape[2] // CELL, None))
    moved_target = jax.lax.stop_gradient(resample_cells(target, shifts))
  else:
    moved = adain_lib.encode(encoder_params, window(content, shifts, side))["relu4_1"]
    moved_target = jax.lax.stop_gradient(adain_lib.adain_from_stats(moved, style_mean, style_std))
  moved_out = decoder_lib.Decoder(upsample).apply(decoder_params, moved_target)
  inner = slice(SHIFT_MARGIN, side - SHIFT_MARGIN)
  same = window(output, shifts, side)
  return jnp.mean(jnp.square(moved_out[:, inner, inner] - same[:, inner, inner]))


def adain_targets(encoder_params: Any, content: Optional[jnp.ndarray],
                  features: Optional[jnp.ndarray], style_mean: jnp.ndarray,
                  style_std: jnp.ndarray) -> jnp.ndarray:
  """The relu4_1 maps the decoder paints: AdaIN of the photo crops' encodings (their own
  statistics, the paper's), then the normalised feature crops given the style's statistics
  (`n * std + mean`, as a feature run's view is stylized), concatenated along the batch.

  Args:
    content: [P, S, S, 3] or None; features: [F, S / 8, S / 8, 512] or None (P + F = B).
    style_mean, style_std: [B, 512], the first P for the photos.
  Returns:
    [B, S / 8, S / 8, 512].
  """
  parts, p = [], 0
  if content is not None:
    p = content.shape[0]
    feats = adain_lib.encode(encoder_params, content)["relu4_1"]
    parts.append(adain_lib.adain_from_stats(feats, style_mean[:p], style_std[:p]))
  if features is not None:
    parts.append(features * style_std[p:, None, None] + style_mean[p:, None, None])
  return jnp.concatenate(parts) if len(parts) > 1 else parts[0]


def losses(decoder_params: Any, encoder_params: Any, content: Optional[jnp.ndarray],
           style: jnp.ndarray, config: config_lib.AdainConfig,
           shifts: Optional[jnp.ndarray] = None, features: Optional[jnp.ndarray] = None
           ) -> Tuple[jnp.ndarray, Dict[str, jnp.ndarray]]:
  """AdaIN training loss (Huang & Belongie eq. 11-13), plus the optional shift consistency.

  Args:
    content: [P, S, S, 3] photo crops in [0, 1], or None; style: [B, S, S, 3] in [0, 1].
    shifts: [B, 2] int sub-cell shifts (`random_shifts`); read when config.shift_weight > 0.
    features: [F, S / 8, S / 8, 512] feature crops normalised by their scene's statistics
      (`render_content_features`), or None; P + F = B.
  Returns:
    (total [], {"loss", "content", "style"[, "shift"]}): content = MSE(relu4_1(g(t)), t) with
    t = AdaIN(f(c), f(s)) (`adain_targets`); style = sum over relu1_1..relu4_1 of MSE of
    means + MSE of stds; shift = `shift_loss`, weighted by config.shift_weight.
  """
  n_photos = 0 if content is None else content.shape[0]
  n_features = 0 if features is None else features.shape[0]
  chex.assert_equal(n_photos + n_features, style.shape[0])
  if content is not None:
    chex.assert_equal_shape([content, style[:n_photos]])
  if features is not None:
    chex.assert_shape(features, (n_features, style.shape[1] // CELL, style.shape[2] // CELL, None))
  encoder_params = jax.lax.stop_gradient(encoder_params)  # frozen: XLA drops its backward.
  target_stats = adain_lib.style_stats(encoder_params, style)
  target = adain_targets(encoder_params, content, features, *target_stats["relu4_1"])
  target = jax.lax.stop_gradient(target)
  output = decoder_lib.Decoder(config.upsample).apply(decoder_params, target)
  out_feats = adain_lib.encode(encoder_params, output)
  content_loss = jnp.mean(jnp.square(out_feats["relu4_1"] - target))
  out_stats = {name: adain_lib.channel_stats(out_feats[name]) for name in vgg.STYLE_LAYERS}
  style_loss = adain_lib.style_loss(out_stats, jax.lax.stop_gradient(target_stats))
  total = config.content_weight * content_loss + config.style_weight * style_loss
  metrics = {"content": content_loss, "style": style_loss}
  if config.shift_weight > 0:
    chex.assert_shape(shifts, (style.shape[0], 2))
    mean, std = jax.lax.stop_gradient(target_stats["relu4_1"])
    metrics["shift"] = shift_loss(decoder_params, encoder_params, content, output, mean, std,
                                  shifts, config.upsample, config.shift_source, target)
    total = total + config.shift_weight * metrics["shift"]
  return total, {"loss": total, **metrics}


