"""Robust image reading and writing: any common format, mode and bit depth in, float32 RGB out."""

import io
import numbers
import os
import warnings
from typing import Any, List, Optional, Sequence

import numpy as np
from PIL import Image

from msnerf_jax.core import files
from msnerf_jax.core.errors import UserError

IMAGE_EXTENSIONS = (".png", ".jpg", ".jpeg", ".bmp", ".tif", ".tiff", ".webp")

# Decoding more pixels than this is refused (8000x8000 is 64M and fine; a 1 GPixel bomb is not).
MAX_DECODE_PIXELS = 300_000_000


def cover_crop(image: np.ndarray, height: int, width: int) -> np.ndarray:
  """Resizes [h, w, 3] to cover height x width (aspect kept), then centre-crops to it."""
  h, w = image.shape[:2]
  scale = max(height / h, width / w)
  nh, nw = max(height, round(h * scale)), max(width, round(w * scale))
  image = resize(image, nh, nw)
  y, x = (nh - height) // 2, (nw - width) // 2
  return image[y:y + height, x:x + width]


def list_images(folder: str) -> List[str]:
  """Sorted paths of the image files (by extension) directly inside `folder`."""
  if not os.path.exists(folder):
    raise UserError(f"{folder}: no such folder")
  if not os.path.isdir(folder):
    raise UserError(f"{folder}: not a folder")
  paths = sorted(
      os.path.join(folder, name) for name in os.listdir(folder)
      if name.lower().endswith(IMAGE_EXTENSIONS) and not name.startswith("."))
  if not paths:
    raise UserError(f"{folder}: no image files ({', '.join(IMAGE_EXTENSIONS)})")
  return paths


def one_line(error: BaseException) -> str:
  """An exception's message on one line (numpy's and Pillow's may span several)."""
  return " ".join(str(error).split())


def file_problem(error: BaseException) -> str:
  """What np.load found wrong with a broken file, on one line: the message of the errors a
  bad file is expected to raise, with the type's name for the others (a broken .npy header
  raises SyntaxError, TokenError ...)."""
  if isinstance(error, (ValueError, OSError, EOFError, KeyError)):
    return one_line(error)
  return f"{type(error).__name__}: {one_line(error)}"


def _to_float(array: np.ndarray, path: str) -> np.ndarray:
  if array.dtype == np.uint8:
    return array.astype(np.float32) / 255.0
  if array.dtype in (np.uint16, np.int32, np.uint32) or array.dtype == np.int16:
    # 16-bit PNG/TIFF (Pillow reports 'I;16' or 'I' as int32 with values up to 65535).
    return np.clip(array.astype(np.float32) / 65535.0, 0.0, 1.0)
  if np.issubdtype(array.dtype, np.floating):
    if np.any(np.isnan(array)):  # (a float TIFF)
      raise UserError(f"{path}: pixels hold NaN")
    return np.clip(array.astype(np.float32), 0.0, 1.0)
  if array.dtype == bool:
    return array.astype(np.float32)
  raise UserError(f"{path}: unsupported pixel type {array.dtype}")


def read_image(path: str,
               background: Optional[float] = 1.0,
               max_side: Optional[int] = None,
               keep_alpha: bool = False,
               reduce: int = 1) -> np.ndarray:
  """Reads an image file as float32 RGB in [0, 1].

  Grayscale is replicated to RGB, palette images are expanded, 16-bit images are scaled by
  1/65535. An alpha channel is composited over a constant `background` (Blender convention
  `rgb * a + bg * (1 - a)`), or kept as a fourth channel when `keep_alpha`. With `max_side`,
  images larger than that are downscaled while decoding (JPEG draft mode), so huge files
  do not need their full-resolution buffer. `reduce` > 1 shrinks by that integer factor
  with box (area) averaging of the stored pixels, before any alpha compositing.

  Returns:
    [height, width, 3] (or [height, width, 4] with keep_alpha) float32.
  Raises:
    UserError naming the file when it is missing, empty, truncated or not an image.
  """
  if not os.path.exists(path):
    raise UserError(f"{path}: no such file")
  if os.path.isdir(path):
    raise UserError(f"{path}: is a folder, expected an image file")
  if os.path.getsize(path) == 0:
    raise UserError(f"{path}: empty file")
  return _decode(path, path, background, max_side, keep_alpha, reduce)


STYLE_MIN_SIDE = 16  # VGG's relu4_1 needs 2 x 2 cells.


def read_style_image(path: str, max_side: Optional[int] = 1024) -> np.ndarray:
  """A style picture as read_image reads it ([h, w, 3] float32), longer side shrunk to
  `max_side`; UserError for a file read_image refuses, an animated image (which frame would
  be the style?) or one under STYLE_MIN_SIDE pixels a side."""
  image = read_image(path, max_side=max_side)
  with Image.open(path) as opened:
    if getattr(opened, "n_frames", 1) > 1:
      raise UserError(f"{path}: an animated image ({opened.n_frames} frames); give one still "
                      "picture per style")
  if min(image.shape[:2]) < STYLE_MIN_SIDE:
    raise UserError(f"{path}: style image is {image.shape[1]}x{image.shape[0]}, need at least "
                    f"{STYLE_MIN_SIDE}x{STYLE_MIN_SIDE}")
  return image


def decode_image(data: bytes, name: str, background: Optional[float] = 1.0,
                 max_side: Optional[int] = None) -> np.ndarray:
  """An image file's bytes (e.g. an upload) as float32 RGB [h, w, 3] in [0, 1], as
  read_image reads files; UserError naming `name` when they are empty or not an image."""
  if not data:
    raise UserError(f"{name}: empty file")
  return _decode(io.BytesIO(data), name, background, max_side, False, 1)


def _decode(source, path: str, background: Optional[float], max_side: Optional[int],
            keep_alpha: bool, reduce: int) -> np.ndarray:
  """read_image's decoding of `source` (a file name or a binary file object), named `path`
  in errors."""
  try:
    with warnings.catch_warnings():
      warnings.simplefilter("error", Image.DecompressionBombWarning)
      Image.MAX_IMAGE_PIXELS = MAX_DECODE_PIXELS
      with Image.open(source) as image:
        if max_side is not None and max(image.size) > max_side:
          image.draft("RGB", (max_side, max_side))  # JPEG: decode at 1/2, 1/4, 1/8 scale.
        image.load()
        image = _normalize_mode(image)
        if reduce > 1:
          if image.size[0] < reduce or image.size[1] < reduce:
            raise UserError(f"{path}: {image.size[0]}x{image.size[1]} is too small to downscale "
                            f"by {reduce}")
          image = image.reduce(reduce)
        if max_side is not None and max(image.size) > max_side:
          scale = max_side / max(image.size)
          size = (max(1, round(image.size[0] * scale)), max(1, round(image.size[1] * scale)))
          image = image.resize(size, Image.BICUBIC if image.mode in ("RGB", "RGBA") else Image.BILINEAR)
        array = np.asarray(image)
  except UserError:
    raise
  except (Image.DecompressionBombError, Image.DecompressionBombWarning):
    raise UserError(f"{path}: image too large to decode (over {MAX_DECODE_PIXELS} pixels)") from None
  except Image.UnidentifiedImageError:
    raise UserError(f"{path}: not an image (no image format recognised)") from None
  except (OSError, SyntaxError, ValueError) as e:
    raise UserError(f"{path}: unreadable or truncated image ({one_line(e)})") from None
  except Exception as e:  # Pillow raises many types for corrupt data.
    raise UserError(f"{path}: not a readable image ({type(e).__name__}: {one_line(e)})") from None
  return _to_rgb(_to_float(array, path), background, keep_alpha)


def _normalize_mode(image: Image.Image) -> Image.Image:
  """Brings any Pillow mode to one whose numpy array is L, LA, RGB, RGBA or 16-bit L."""
  mode = image.mode
  if mode in ("L", "LA", "RGB", "RGBA", "I;16", "I;16B", "I;16L", "I", "F"):
    if mode in ("I;16B", "I;16L"):
      return image.convert("I")
    return image
  if mode == "P" or mode == "PA":
    return image.convert("RGBA")
  if mode == "1":
    return image.convert("L")
  return image.convert("RGB")  # CMYK, YCbCr, LAB, HSV ...


def over_background(rgb: np.ndarray, alpha: np.ndarray, background=1.0) -> np.ndarray:
  """rgb [..., 3] put over a background (a colour, or white) by its opacity alpha [..., 1]:
  rgb a + background (1 - a). The one composite of a picture over white."""
  return rgb * alpha + background * (1.0 - alpha)


def _to_rgb(array: np.ndarray, background: Optional[float], keep_alpha: bool) -> np.ndarray:
  if array.ndim == 2:
    array = array[..., None]
  channels = array.shape[-1]
  if channels in (1, 2):
    rgb = np.repeat(array[..., :1], 3, axis=-1)
    alpha = array[..., 1:2] if channels == 2 else None
  else:
    rgb = array[..., :3]
    alpha = array[..., 3:4] if channels == 4 else None
  if keep_alpha:
    if alpha is None:
      alpha = np.ones_like(rgb[..., :1])
    return np.ascontiguousarray(np.concatenate([rgb, alpha], axis=-1), dtype=np.float32)
  if alpha is not None and background is not None:
    rgb = over_background(rgb, alpha, background)
  return np.ascontiguousarray(rgb, dtype=np.float32)


def to_uint8(image: np.ndarray) -> np.ndarray:
  """float [0, 1] -> uint8, with rounding."""
  return (np.clip(np.asarray(image, dtype=np.float32), 0.0, 1.0) * 255.0 + 0.5).astype(np.uint8)


def resize(image: np.ndarray, height: int, width: int) -> np.ndarray:
  """Area/bicubic resize of a float image [h, w, c] to [height, width, c] (Pillow, per channel)."""
  if image.shape[:2] == (height, width):
    return image
  channels = [
      np.asarray(Image.fromarray(image[..., c].astype(np.float32), mode="F").resize(
          (width, height), Image.BOX if height < image.shape[0] else Image.BICUBIC))
      for c in range(image.shape[-1])
  ]
  return np.clip(np.stack(channels, axis=-1), 0.0, 1.0).astype(np.float32)


def check_scale(scale: int, what: str = "--stylize-scale") -> None:
  """UserError unless `scale` (stylize_image's) is a whole number >= 1; `what` names its source."""
  if isinstance(scale, bool) or not isinstance(scale, numbers.Integral) or scale < 1:
    raise UserError(f"{what} {scale!r}: must be a whole number >= 1")


def write_image(path: str, image: np.ndarray) -> None:
  """Writes a float [0, 1] or uint8 image [h, w, 3|1] atomically; format from the extension."""
  import io
  array = np.asarray(image)
  if array.dtype != np.uint8:
    array = to_uint8(array)
  if array.ndim == 3 and array.shape[-1] == 1:
    array = array[..., 0]
  buffer = io.BytesIO()
  fmt = os.path.splitext(path)[1].lower().lstrip(".") or "png"
  fmt = {"jpg": "jpeg", "tif": "tiff"}.get(fmt, fmt)
  Image.fromarray(array).save(buffer, format=fmt.upper())
  files.atomic_write_bytes(path, buffer.getvalue())


def stack_same_size(images: Sequence[np.ndarray], paths: Sequence[str]) -> np.ndarray:
  """Stacks images into [n, h, w, c]; names the first file whose size differs from the first."""
  shape = images[0].shape
  for image, path in zip(images, paths):
    if image.shape != shape:
      raise UserError(
          f"{path}: image is {image.shape[1]}x{image.shape[0]}, expected {shape[1]}x{shape[0]} "
          f"like {paths[0]} (all views of a scene must have one size)")
  return np.stack(images)


def read_json(path: str, hint: str = "") -> Any:
  """The parsed JSON file at `path`; UserError naming it when it is not JSON (`hint` is added
  to the message). A missing file raises FileNotFoundError."""
  import json  # pylint: disable=g-import-not-at-top
  try:
    with open(path, encoding="utf-8") as f:
      return json.load(f)
  except (ValueError, UnicodeDecodeError) as e:  # (JSONDecodeError, a 5000-digit number)
    raise UserError(f"{path}: malformed JSON ({e}){hint}") from None
  except RecursionError:
    raise UserError(f"{path}: malformed JSON (nested too deeply){hint}") from None


def json_number(value: Any, source: str, key: str, positive: bool = False) -> float:
  """A JSON field's value as a float; UserError naming `source` and `key` unless it is a
  finite number (not a bool), and with `positive`, above 0."""
  number = float("nan")
  if isinstance(value, (int, float)) and not isinstance(value, bool):
    number = float(value) if abs(value) < 2 ** 1024 else float("inf")  # (10**400: no float)
  if not np.isfinite(number) or (positive and number <= 0):
    raise UserError(f"{source}: {key} must be a {'positive' if positive else 'finite'} "
                    f"number, got {value!r}")
  return number


def load_numbers(path: str, what: str = "a valid .npy array") -> np.ndarray:
  """np.load of a .npy file of real numbers (no pickles); UserError naming the file when it
  is missing, not a .npy file (`what` it should be) or holds other values (strings,
  records, complex numbers, dates ...)."""
  try:
    array = np.load(path, allow_pickle=False)
  except FileNotFoundError:
    raise UserError(f"{path}: missing") from None
  except MemoryError:
    raise
  except Exception as e:  # pylint: disable=broad-except  # a broken header: SyntaxError ...
    raise UserError(f"{path}: not {what} ({file_problem(e)})") from None
  if not isinstance(array, np.ndarray):
    array.close()  # (an NpzFile holds the file open)
    raise UserError(f"{path}: not {what} (an .npz archive)")
  if array.dtype.kind not in "biuf":
    raise UserError(f"{path}: holds {array.dtype} values, expected numbers")
  return array


def read_npy(path: str, shape: Sequence[Optional[int]]) -> np.ndarray:
  """np.load without pickles, as float32; UserError naming the file unless it holds a finite
  array of `shape` (None = any size along that axis)."""
  array = load_numbers(path)
  if array.ndim != len(shape) or any(s is not None and s != d for s, d in zip(shape, array.shape)):
    raise UserError(f"{path}: array of shape {array.shape}, expected "
                    f"{tuple('?' if s is None else s for s in shape)}")
  with np.errstate(over="ignore"):
    array = array.astype(np.float32)
  if not np.all(np.isfinite(array)):
    raise UserError(f"{path}: holds NaN or inf (or numbers beyond float32)")
  return array
