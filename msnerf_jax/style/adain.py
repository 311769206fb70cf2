"""AdaIN: channel statistics, adaptive instance normalisation, style vectors and style blending."""

import functools
from typing import Any, Dict, Optional, Sequence, Tuple

import chex
import jax
import jax.numpy as jnp

from msnerf_jax.models import vgg

# Added to the standard deviation before dividing by it (reference code): keeps flat
# (constant) feature maps from producing inf/NaN.
EPS = 1e-8


def channel_stats(feats: jnp.ndarray, eps: float = EPS) -> Tuple[jnp.ndarray, jnp.ndarray]:
  """Per-channel mean and std over space.

  Args:
    feats: [B, H, W, C] feature maps (H * W >= 2).
    eps: added to the std (reference code: unbiased std + 1e-8).
  Returns:
    (mean [B, C], std [B, C]); std is the unbiased (n - 1) standard deviation plus eps.
  """
  chex.assert_rank(feats, 4)
  mean = jnp.mean(feats, axis=(1, 2))
  n = feats.shape[1] * feats.shape[2]
  var = jnp.sum(jnp.square(feats - mean[:, None, None, :]), axis=(1, 2)) / max(n - 1, 1)
  return mean, jnp.sqrt(var) + eps


def adain_from_stats(content_feats: jnp.ndarray, style_mean: jnp.ndarray, style_std: jnp.ndarray,
                     alpha: float = 1.0,
                     content_stats: Optional[Tuple[jnp.ndarray, jnp.ndarray]] = None
                     ) -> jnp.ndarray:
  """AdaIN with given target statistics: s_std * (c - c_mean) / c_std + s_mean.

  Strength `alpha` blends the statistics, s = alpha * s + (1 - alpha) * c, which equals the
  AdaIN paper's alpha * AdaIN(c, s) + (1 - alpha) * c.

  Args:
    content_feats: [B, H, W, C].
    style_mean, style_std: [B, C] (or [1, C], broadcast over the batch).
    alpha: scalar in [0, 1] (may be traced).
    content_stats: (mean, std) [1, C] that replace each image's own statistics c_mean and
      c_std, e.g. those of a whole scene (`stylize.scene_content_stats`): every image is
      then normalised by the same affine map.
  Returns:
    [B, H, W, C].
  """
  chex.assert_rank([content_feats, style_mean, style_std], [4, 2, 2])
  chex.assert_equal_shape([style_mean, style_std])
  chex.assert_axis_dimension(style_mean, 1, content_feats.shape[-1])
  if content_stats is None:
    c_mean, c_std = channel_stats(content_feats)
  else:
    c_mean, c_std = content_stats
    chex.assert_shape([c_mean, c_std], (1, content_feats.shape[-1]))
  mean = alpha * style_mean + (1.0 - alpha) * c_mean
  std = alpha * style_std + (1.0 - alpha) * c_std
  normalized = (content_feats - c_mean[:, None, None, :]) / c_std[:, None, None, :]
  return normalized * std[:, None, None, :] + mean[:, None, None, :]


def adain(content_feats: jnp.ndarray, style_feats: jnp.ndarray, alpha: float = 1.0) -> jnp.ndarray:
  """Adaptive instance normalisation (Huang & Belongie 2017, eq. 8).

  Args:
    content_feats: [B, H, W, C] content features.
    style_feats: [B or 1, H', W', C] style features (any spatial size).
    alpha: style strength in [0, 1]; 0 returns the content features.
  Returns:
    [B, H, W, C]: content features with the style's per-channel mean and std.
  """
  chex.assert_rank([content_feats, style_feats], 4)
  chex.assert_axis_dimension(style_feats, 3, content_feats.shape[-1])
  s_mean, s_std = channel_stats(style_feats)
  return adain_from_stats(content_feats, s_mean, s_std, alpha)


def blend_stats(means: jnp.ndarray, stds: jnp.ndarray,
                weights: jnp.ndarray) -> Tuple[jnp.ndarray, jnp.ndarray]:
  """Weighted blend of several styles' statistics (AdaIN paper style interpolation).

  sum_k w_k AdaIN(c, s_k) = AdaIN with mean sum_k w_k mean_k and std sum_k w_k std_k, so
  blending statistics is the paper's feature-space interpolation.

  Args:
    means, stds: [K, C] per-style statistics.
    weights: [K], normalised here to sum to 1.
  Returns:
    (mean [1, C], std [1, C]).
  """
  chex.assert_rank([means, stds, weights], [2, 2, 1])
  chex.assert_equal_shape([means, stds])
  chex.assert_axis_dimension(means, 0, weights.shape[0])
  w = weights / jnp.sum(weights)
  return (w @ means)[None], (w @ stds)[None]


@functools.partial(jax.jit, static_argnames=("all_layers",))
def encode(encoder_params: Any, images: jnp.ndarray, all_layers: bool = False) -> Dict[str, jnp.ndarray]:
  """VGG features of images [B, H, W, 3] in [0, 1]: dict relu1_1 ... relu4_1 (jitted; inlined
  when called inside another jit)."""
  return vgg.VGGEncoder().apply(encoder_params, images, all_layers=all_layers)


def style_stats(encoder_params: Any, images: jnp.ndarray) -> Dict[str, Tuple[jnp.ndarray, jnp.ndarray]]:
  """Per-layer (mean [B, C], std [B, C]) of relu1_1 ... relu4_1 of images [B, H, W, 3]."""
  feats = encode(encoder_params, images)
  return {name: channel_stats(feats[name]) for name in vgg.STYLE_LAYERS}


def style_vector(encoder_params: Any, image: jnp.ndarray) -> jnp.ndarray:
  """The 1024-number style vector of one image: relu4_1 channel means (512), then stds (512).

  Args:
    encoder_params: from `vgg.load_vgg_params()`.
    image: [H, W, 3] in [0, 1] (or [1, H, W, 3]); H, W >= 16.
  Returns:
    [1024] float32.
  """
  if image.ndim == 3:
    image = image[None]
  chex.assert_shape(image, (1, None, None, 3))
  feats = encode(encoder_params, image)["relu4_1"]
  mean, std = channel_stats(feats)
  out = jnp.concatenate([mean[0], std[0]])
  chex.assert_shape(out, (1024,))
  return out


style_vector_jit = jax.jit(style_vector)


def style_loss(output_stats: Dict[str, Tuple[jnp.ndarray, jnp.ndarray]],
               target_stats: Dict[str, Tuple[jnp.ndarray, jnp.ndarray]],
               layers: Sequence[str] = vgg.STYLE_LAYERS) -> jnp.ndarray:
  """Sum over layers of MSE(mean_out, mean_style) + MSE(std_out, std_style) (AdaIN eq. 12).

  Stats are (mean [B, C], std [B, C]); target stats may have batch 1 (broadcast). Returns [].
  """
  total = 0.0
  for name in layers:
    (om, os_), (tm, ts) = output_stats[name], target_stats[name]
    total = total + jnp.mean(jnp.square(om - tm)) + jnp.mean(jnp.square(os_ - ts))
  return total
