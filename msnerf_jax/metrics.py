"""Image quality metrics: PSNR and SSIM (dm-pix), on images in [0, 1]."""

import dm_pix
import jax.numpy as jnp


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
