"""The losses that paint colour fields from rendered views: ARF's nearest-neighbour feature
matching (NNFM) on VGG16 relu3_1..relu3_3, the AdaIN statistics loss, a content term and
total variation. Pure and jittable;
a style enters as its precomputed `StyleTarget` (style_target), so no step re-encodes it.
"""

from typing import Any, Dict, NamedTuple, Tuple

import chex
import jax
import jax.numpy as jnp

from msnerf_jax.models import vgg
from msnerf_jax.style import adain as adain_lib

NNFM_LAYERS = ("relu3_1", "relu3_2", "relu3_3")  # ARF's block: conv3_1..conv3_3.


class StyleTarget(NamedTuple):
  """What the losses need of one style image (a pytree; stack them for M styles):
  features [S, 768] (its relu3_1..3_3 feature vectors, unit length) and stats {layer:
  (mean [C], std [C])} of relu1_1..relu4_1."""
  features: jnp.ndarray
  stats: Dict[str, Tuple[jnp.ndarray, jnp.ndarray]]


def _block(feats: Dict[str, jnp.ndarray]) -> jnp.ndarray:
  """relu3_1..relu3_3 [B, h, w, 256] each -> [B, h * w, 768]."""
  block = jnp.concatenate([feats[name] for name in NNFM_LAYERS], -1)
  return block.reshape(block.shape[0], -1, block.shape[-1])


def _unit(x: jnp.ndarray) -> jnp.ndarray:
  return x / jnp.maximum(jnp.linalg.norm(x, axis=-1, keepdims=True), 1e-8)


def style_target(encoder_params: Any, style: jnp.ndarray) -> StyleTarget:
  """The StyleTarget of a style image [H, W, 3] in [0, 1]."""
  chex.assert_rank(style, 3)
  feats = adain_lib.encode(encoder_params, style[None], all_layers=True)
  stats = {name: tuple(s[0] for s in adain_lib.channel_stats(feats[name]))
           for name in vgg.STYLE_LAYERS}
  return StyleTarget(_unit(_block(feats)[0]), stats)


def nnfm(features: jnp.ndarray, style_features: jnp.ndarray) -> jnp.ndarray:
  """ARF's nearest-neighbour feature matching: each feature vector [N, C] is compared with
  its cosine-nearest style feature vector (unit length, [S, C]); the loss is the mean of
  1 - cos to it. The neighbour is chosen without gradient. Returns []."""
  unit = _unit(features)
  nearest = jnp.argmax(jax.lax.stop_gradient(unit) @ style_features.T, -1)
  return jnp.mean(1.0 - jnp.sum(unit * style_features[nearest], -1))


def total_variation(images: jnp.ndarray) -> jnp.ndarray:
  """Mean squared difference of neighbouring pixels of images [B, H, W, 3], per image: [B]."""
  dy = jnp.mean(jnp.square(images[:, 1:] - images[:, :-1]), (1, 2, 3))
  dx = jnp.mean(jnp.square(images[:, :, 1:] - images[:, :, :-1]), (1, 2, 3))
  return dx + dy


def painting_losses(encoder_params: Any, renders: jnp.ndarray, photos: jnp.ndarray,
                    targets: StyleTarget) -> Dict[str, jnp.ndarray]:
  """The terms of B rendered views [B, H, W, 3], each against its photo [B, H, W, 3] (the
  content target) and its style (targets, stacked [B, ...]).

  Returns: {"nnfm", "adain", "content", "tv"}, each [B]: NNFM on relu3_1..3_3, the AdaIN
  statistics loss (eq. 12 of Huang & Belongie) on relu1_1..4_1, the MSE of the renders'
  relu3_1..3_3 features to the photos' (ARF's content term) and total_variation.
  """
  chex.assert_equal_shape([renders, photos])
  b = renders.shape[0]
  feats = adain_lib.encode(encoder_params, jnp.concatenate([renders, photos]), all_layers=True)
  block = _block(feats)
  ours, content = block[:b], jax.lax.stop_gradient(block[b:])
  stats = {name: adain_lib.channel_stats(feats[name][:b]) for name in vgg.STYLE_LAYERS}
  adain = sum(jnp.mean(jnp.square(stats[n][0] - targets.stats[n][0]), -1)
              + jnp.mean(jnp.square(stats[n][1] - targets.stats[n][1]), -1)
              for n in vgg.STYLE_LAYERS)
  return {"nnfm": jax.vmap(nnfm)(ours, targets.features), "adain": adain,
          "content": jnp.mean(jnp.square(ours - content), (1, 2)),
          "tv": total_variation(renders)}
