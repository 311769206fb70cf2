"""AdaIN decoder: the mirror of the VGG encoder up to relu4_1 (reflect padding, x2 upsampling)."""

import chex
import flax.linen as nn
import jax
import jax.numpy as jnp

UPSAMPLE_MODES = ("nearest", "bilinear")
# Output channels of the convs; "U" is a x2 upsampling (METHOD.md "Decoder").
DECODER_LAYOUT = (256, "U", 256, 256, 256, 128, "U", 128, 64, "U", 64, 3)


def upsample2x(x: jnp.ndarray, mode: str) -> jnp.ndarray:
  """[B, H, W, C] -> [B, 2H, 2W, C]; bilinear uses half-pixel centres (PyTorch align_corners=False)."""
  if mode == "nearest":
    return jnp.repeat(jnp.repeat(x, 2, axis=1), 2, axis=2)
  if mode == "bilinear":
    b, h, w, c = x.shape
    return jax.image.resize(x, (b, 2 * h, 2 * w, c), method="bilinear", antialias=False)
  raise ValueError(f"upsample mode {mode!r} not in {UPSAMPLE_MODES}")


class ReflectConv(nn.Module):
  """3x3 convolution on a reflect-padded input (same output size).

  Computed as a SAME convolution of the padded input with its 1-pixel rim cropped, which
  equals the VALID convolution exactly: XLA's CPU backend runs VALID convolutions about 4x
  slower than SAME ones (measured on jax 0.10, AMD EPYC).
  """
  features: int

  @nn.compact
  def __call__(self, x: jnp.ndarray) -> jnp.ndarray:
    x = jnp.pad(x, ((0, 0), (1, 1), (1, 1), (0, 0)), mode="reflect")
    return nn.Conv(self.features, (3, 3), padding="SAME", name="Conv_0")(x)[:, 1:-1, 1:-1, :]


class Decoder(nn.Module):
  """Maps AdaIN features [B, H, W, 512] (relu4_1 size) to images [B, 8H, 8W, 3].

  ReLU after every conv but the last; the output is not clamped (the losses see it raw;
  callers clip to [0, 1] for display).
  """
  upsample: str = "nearest"

  @nn.compact
  def __call__(self, feats: jnp.ndarray) -> jnp.ndarray:
    chex.assert_rank(feats, 4)
    chex.assert_axis_dimension(feats, 3, 512)
    x = feats
    convs = [v for v in DECODER_LAYOUT if v != "U"]
    i = 0
    for v in DECODER_LAYOUT:
      if v == "U":
        x = upsample2x(x, self.upsample)
        continue
      x = ReflectConv(v, name=f"conv{i}")(x)
      i += 1
      if i < len(convs):
        x = nn.relu(x)
    return x


def init_decoder(key: jax.Array, upsample: str = "nearest", feat_size: int = 8):
  """Fresh decoder params ({"params": ...}) from an explicit PRNG key."""
  return jax.jit(Decoder(upsample=upsample).init)(key, jnp.zeros((1, feat_size, feat_size, 512)))
