"""The sample pictures the AdaIN trainer writes every `sample_every` steps: a few fixed crops
(content | style | the decoder's output), painted with the decoder being trained."""

import functools

import jax
import jax.numpy as jnp
import numpy as np

from msnerf_jax.core import config as config_lib
from msnerf_jax.models import decoder as decoder_lib
from msnerf_jax.style import adain as adain_lib
from msnerf_jax.style.features import CELL
from msnerf_jax.train.adain_data import feature_batch, random_crops, random_feature_crops
from msnerf_jax.train.adain_losses import adain_targets


@functools.lru_cache(maxsize=4)
def make_stylize_fn(upsample: str):
  """jitted (decoder_params, encoder_params, content [B,H,W,3], style [B,H',W',3]) -> [B,H,W,3]."""

  def fn(decoder_params, encoder_params, content, style):
    feats = adain_lib.encode(encoder_params, content)["relu4_1"]
    style_feats = adain_lib.encode(encoder_params, style)["relu4_1"]
    return decoder_lib.paint(decoder_params, adain_lib.adain(feats, style_feats), upsample)

  return jax.jit(fn)


@functools.lru_cache(maxsize=4)
def make_feature_stylize_fn(upsample: str):
  """jitted (decoder_params, encoder_params, normalised features [B,h,w,512], stats [2, 512],
  style [B,H,W,3]) -> (the features decoded unstylized, stylized), each [B, 8h, 8w, 3]."""

  def fn(decoder_params, encoder_params, features, stats, style):
    mean, std = adain_lib.channel_stats(adain_lib.encode(encoder_params, style)["relu4_1"])
    decode = lambda t: decoder_lib.paint(decoder_params, t, upsample)
    own = [jnp.broadcast_to(x, mean.shape) for x in stats]  # AdaIN towards the scene: identity.
    return (decode(adain_targets(encoder_params, None, features, *own)),
            decode(adain_targets(encoder_params, None, features, mean, std)))

  return jax.jit(fn)


def sample_grid(content: np.ndarray, style: np.ndarray, output: np.ndarray) -> np.ndarray:
  """Rows of (content | style | output) with 4-pixel white gaps: [B*S + gaps, 3*S + gaps, 3]."""
  rows = []
  gap = 4
  for c, s, o in zip(content, style, output):
    sep = np.ones((c.shape[0], gap, 3), np.float32)
    rows.append(np.concatenate([c, sep, s, sep, o], axis=1))
    rows.append(np.ones((gap, rows[-1].shape[1], 3), np.float32))
  return np.concatenate(rows[:-1], axis=0)


def sample_painter(config: config_lib.AdainConfig, encoder_params, content_pools, style_pools,
                   feature_maps, feature_stats):
  """(painted(params) -> (content column, outputs), the style crops) of the fixed sample
  crops (up to 4) the trainer paints every sample_every steps. Without photos in a batch the
  content column is the unstylized decode of the feature crops."""
  sample_rng = np.random.default_rng([config.seed, 10**9])
  n_samples = min(4, config.batch)
  if feature_batch(config) == config.batch:
    stylize_features = make_feature_stylize_fn(config.upsample)
    sample_features = random_feature_crops(sample_rng, feature_maps, n_samples, config.size // CELL)
    sample_style = random_crops(sample_rng, style_pools, n_samples, config.size)

    def painted(params):
      return tuple(map(np.asarray, stylize_features(params, encoder_params, sample_features,
                                                    feature_stats, sample_style)))
    return painted, sample_style
  stylize = make_stylize_fn(config.upsample)
  sample_content = random_crops(sample_rng, content_pools, n_samples, config.size)
  sample_style = random_crops(sample_rng, style_pools, n_samples, config.size)

  def painted(params):
    return sample_content, np.asarray(stylize(params, encoder_params, sample_content,
                                              sample_style))
  return painted, sample_style
