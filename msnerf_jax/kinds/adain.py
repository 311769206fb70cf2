"""The "adain" run kind: an AdaIN decoder trained against the frozen VGG encoder
(`msnerf adain train`); it has no scene, it paints the other kinds' styles."""

from msnerf_jax.core.config import AdainConfig
from msnerf_jax.kinds.base import RunKind
from msnerf_jax.models import decoder as decoder_lib


def init_params(config, key):
  """The flax variables {"params": {"conv0": ...}} of the decoder (None for an unknown
  upsampling mode, which the decoder's loader refuses with its own message)."""
  if config.upsample not in decoder_lib.UPSAMPLE_MODES:
    return None
  return decoder_lib.init_decoder(key, config.upsample)


KIND = RunKind(
    name="adain",
    config_class=AdainConfig,
    train_command="msnerf adain train",
    title="AdaIN",
    params_layout='{"params": {"conv0", ...}}: the decoder\'s flax variables',
    init_params=init_params,
)
