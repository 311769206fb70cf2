"""Mutations of valid files for tests/test_fuzz_readers.py: hypothesis strategies that take a
valid document (JSON tree, text, binary record layout, .npy array, image) and break it the
ways users' files break: fields removed, wrong types, NaN/inf, huge and negative sizes,
truncation, wrong magic, non-UTF-8 bytes, deep nesting."""

import io
import json
import math
import re
import struct

import numpy as np
from hypothesis import strategies as st
from PIL import Image

# ----------------------------------------------------------------------------- bytes

DEEP = 100_000  # nesting depth of the deep-nesting mutation (past Python's recursion limit)


@st.composite
def mutated_bytes(draw, data: bytes, text: bool = False):
  """`data` with one to three byte-level mutations: truncation, a byte overwritten, bytes
  inserted or deleted, a range duplicated, a wrong magic, non-UTF-8 bytes; for text formats
  also deep nesting and a byte-order mark."""
  ops = ["truncate", "overwrite", "insert", "delete", "duplicate", "magic", "non_utf8"]
  if text:
    ops += ["deep", "bom", "nul"]
  for _ in range(draw(st.integers(1, 3))):
    op = draw(st.sampled_from(ops))
    at = draw(st.integers(0, len(data)))
    if op == "truncate":
      data = data[:at]
    elif op == "overwrite" and data:
      at = min(at, len(data) - 1)
      data = data[:at] + bytes([draw(st.integers(0, 255))]) + data[at + 1:]
    elif op == "insert":
      data = data[:at] + draw(st.binary(min_size=1, max_size=16)) + data[at:]
    elif op == "delete":
      data = data[:at] + data[at + draw(st.integers(1, 64)):]
    elif op == "duplicate":
      data = data[:at] + data[at:at + draw(st.integers(1, 256))] + data[at:]
    elif op == "magic":
      data = draw(st.sampled_from([b"\x89PNG\r\n\x1a\n", b"\xff\xd8\xff", b"\x93NUMPY",
                                   b"PK\x03\x04", b"GIF89a", b"{", b"\0\0\0\0"])) + data[8:]
    elif op == "non_utf8":
      data = data[:at] + draw(st.sampled_from([b"\xff", b"\xc3\x28", b"\xed\xa0\x80",
                                               b"\xf8\x88\x80\x80\x80"])) + data[at:]
    elif op == "deep":
      opener = draw(st.sampled_from([b"[", b'{"a":']))
      data = data[:at] + opener * DEEP + data[at:]
    elif op == "bom":
      data = b"\xef\xbb\xbf" + data
    elif op == "nul":
      data = data[:at] + b"\0" + data[at:]
  return data


# ----------------------------------------------------------------------------- JSON

HUGE_INTS = [0, -1, 1, 2 ** 31, 2 ** 32 + 1, 2 ** 63, -2 ** 63, 2 ** 64, 10 ** 400, -10 ** 400]
NASTY_FLOATS = [math.nan, math.inf, -math.inf, 0.0, -0.0, 1e-320, 1e308, -1e308, 0.5, -2.5]


def nasty_values(depth: int = 2):
  """JSON values of the wrong type or range: None, booleans, huge and negative integers,
  NaN/inf, strings, and (nested) lists and objects."""
  leaves = st.one_of(
      st.none(), st.booleans(), st.sampled_from(HUGE_INTS), st.integers(-10, 10 ** 6),
      st.sampled_from(NASTY_FLOATS), st.floats(), st.text(max_size=12),
      st.sampled_from(["", "nan", "1", "PINHOLE", "OPENCV", "perspective", "nerf", "../x",
                       "\udcff", "\0"]))
  if depth <= 0:
    return leaves
  inner = nasty_values(depth - 1)
  return st.one_of(leaves, st.lists(inner, max_size=5),
                   st.dictionaries(st.text(max_size=6), inner, max_size=3),
                   st.lists(st.sampled_from(NASTY_FLOATS + [1.0, 0.0]), min_size=0, max_size=17))


def json_paths(doc, prefix=()):
  """Every path (tuple of keys / indices) into a JSON tree, the root () included."""
  out = [prefix]
  if isinstance(doc, dict):
    for k, v in doc.items():
      out += json_paths(v, prefix + (k,))
  elif isinstance(doc, list):
    for i, v in enumerate(doc):
      out += json_paths(v, prefix + (i,))
  return out


def _get(doc, path):
  for key in path:
    doc = doc[key]
  return doc


@st.composite
def mutated_json(draw, doc, bytes_too: bool = True):
  """The bytes of a JSON document `doc` (not changed) after one to four structured
  mutations: a key or element removed, a value replaced by a nasty one, wrapped in a list,
  a list emptied or grown, an unknown key added; then sometimes byte-level mutations."""
  doc = json.loads(json.dumps(doc))
  for _ in range(draw(st.integers(1, 4))):
    path = draw(st.sampled_from(json_paths(doc)))
    op = draw(st.sampled_from(["remove", "replace", "replace", "wrap", "empty", "grow", "add",
                               "deep"]))
    if not path:
      if op in ("replace", "wrap", "deep"):
        doc = draw(nasty_values()) if op == "replace" else [doc]
      continue
    parent, key = _get(doc, path[:-1]), path[-1]
    if op == "remove":
      del parent[key]
    elif op == "replace":
      parent[key] = draw(nasty_values())
    elif op == "wrap":
      parent[key] = [parent[key]]
    elif op == "empty":
      parent[key] = [] if isinstance(parent[key], list) else {}
    elif op == "grow" and isinstance(parent[key], list):
      parent[key] = parent[key] + parent[key][:draw(st.integers(0, 3))] + [draw(nasty_values(1))]
    elif op == "add" and isinstance(parent[key], dict):
      parent[key][draw(st.text(max_size=8))] = draw(nasty_values(1))
    elif op == "deep":
      value = parent[key]
      for _ in range(draw(st.integers(50, 400))):  # (deeper: mutated_bytes' "deep")
        value = [value]
      parent[key] = value
  text = json.dumps(doc, allow_nan=True)
  data = text.encode("utf-8", "surrogatepass")
  if bytes_too and draw(st.integers(0, 3)) == 0:
    data = draw(mutated_bytes(data, text=True))
  return data


# ----------------------------------------------------------------------------- text records

NASTY_TOKENS = ["nan", "inf", "-inf", "-1", "0", "1e999", "99999999999999999999", "abc", "",
                "1.5", "-0", "PINHOLE", "FISHEYE", "\xff", "4294967296", "1e-320"]


@st.composite
def mutated_lines(draw, text: str):
  """A whitespace-separated record file (COLMAP's .txt) after one to four mutations: a
  line removed, duplicated or cut short, a token replaced by a nasty one, a token removed
  or added; then sometimes byte-level mutations."""
  lines = [line.split(" ") for line in text.split("\n")]
  for _ in range(draw(st.integers(1, 4))):
    n = draw(st.integers(0, len(lines) - 1)) if lines else 0
    op = draw(st.sampled_from(["del_line", "dup_line", "cut_line", "token", "token", "del_token",
                               "add_token"]))
    if not lines:
      lines = [[draw(st.sampled_from(NASTY_TOKENS))]]
    elif op == "del_line":
      del lines[n]
    elif op == "dup_line":
      lines.insert(n, list(lines[n]))
    elif op == "cut_line":
      lines[n] = lines[n][:draw(st.integers(0, len(lines[n])))]
    else:
      k = draw(st.integers(0, max(0, len(lines[n]) - 1)))
      token = draw(st.one_of(st.sampled_from(NASTY_TOKENS), st.text(max_size=6)))
      if op == "token" and lines[n]:
        lines[n][k] = token
      elif op == "del_token" and lines[n]:
        del lines[n][k]
      else:
        lines[n].insert(k, token)
  data = "\n".join(" ".join(line) for line in lines).encode("utf-8", "surrogatepass")
  if draw(st.integers(0, 3)) == 0:
    data = draw(mutated_bytes(data))
  return data


# ----------------------------------------------------------------------------- binary records

FORMAT_VALUES = {
    "Q": st.one_of(st.sampled_from([0, 1, 2, 7, 2 ** 31, 2 ** 32, 2 ** 63, 2 ** 64 - 1]),
                   st.integers(0, 2 ** 64 - 1)),
    "q": st.one_of(st.sampled_from([0, -1, 2 ** 62, -2 ** 63]), st.integers(-2 ** 63, 2 ** 63 - 1)),
    "i": st.one_of(st.sampled_from([0, -1, 1, 2, 3, 11, 99, -2 ** 31, 2 ** 31 - 1]),
                   st.integers(-2 ** 31, 2 ** 31 - 1)),
    "I": st.one_of(st.sampled_from([0, 1, 2, 99, 2 ** 32 - 1]), st.integers(0, 2 ** 32 - 1)),
    "d": st.one_of(st.sampled_from(NASTY_FLOATS), st.floats(width=64)),
    "B": st.integers(0, 255),
}


@st.composite
def mutated_records(draw, data: bytes, fields):
  """Binary records `data` whose fields [(offset, struct format char)] get one to three
  structured mutations (a count or id made huge, negative or zero, a double NaN/inf), then
  sometimes byte-level mutations."""
  data = bytearray(data)
  for _ in range(draw(st.integers(1, 3))):
    offset, fmt = draw(st.sampled_from(fields))
    struct.pack_into("<" + fmt, data, offset, draw(FORMAT_VALUES[fmt]))
  data = bytes(data)
  if draw(st.integers(0, 2)) == 0:
    data = draw(mutated_bytes(data))
  return data


def colmap_fields(name: str, data: bytes):
  """[(offset, format char)] of every field of a valid COLMAP binary file `name` (cameras,
  images or points3D), walked as COLMAP's format lays them out."""
  from msnerf_jax.data import colmap  # pylint: disable=g-import-not-at-top
  fields, at = [], 0

  def take(fmt):
    nonlocal at
    start = at
    for c in re.sub(r"(\d+)(\w)", lambda m: m.group(2) * int(m.group(1)), fmt):
      fields.append((at, c))
      at += struct.calcsize("<" + c)
    return struct.unpack_from("<" + fmt, data, start)

  count = take("Q")[0]
  for _ in range(count):
    if name == "cameras":
      _, model, _, _ = take("iiQQ")
      take("d" * colmap.CAMERA_MODELS[model][1])
    elif name == "images":
      take("I7dI")
      at = data.index(b"\0", at) + 1
      n = take("Q")[0]
      for _ in range(n):
        take("ddq")
    else:
      n = take("Q3d3BdQ")[-1]
      for _ in range(n):
        take("ii")
  assert at == len(data), (name, at, len(data))
  return fields


# ----------------------------------------------------------------------------- arrays


def npy_bytes(array) -> bytes:
  buffer = io.BytesIO()
  np.save(buffer, array, allow_pickle=True)
  return buffer.getvalue()


@st.composite
def mutated_npy(draw, valid: np.ndarray):
  """The bytes of a .npy file: `valid` with NaN/inf/negative/huge entries, another shape
  (fewer or more axes, empty), another dtype (int, float16, complex, bool, strings, a
  structured or object dtype, big-endian), or byte-level mutations of its header and data."""
  array = np.array(valid)
  op = draw(st.sampled_from(["values", "shape", "dtype", "bytes", "bytes", "mixed"]))
  if array.dtype.kind not in "biuf":  # (a string: numbers of its shape to break instead)
    array = np.zeros(array.shape)
  if op in ("values", "mixed"):
    flat = array.reshape(-1).astype(np.float64)
    for _ in range(draw(st.integers(1, 4))):
      if flat.size:
        flat[draw(st.integers(0, flat.size - 1))] = draw(st.sampled_from(NASTY_FLOATS + [-1.0]))
    array = flat.reshape(array.shape)
  if op in ("shape", "mixed"):
    shape = draw(st.sampled_from([(), (0,), (0, 17), (2,), array.shape[::-1],
                                  array.shape + (1,), array.shape[:-1], (1,) + array.shape,
                                  array.shape[:-1] + (array.shape[-1] + 1,) if array.ndim
                                  else (1,)]))
    size = int(np.prod(shape))
    array = np.resize(array, shape) if size else np.zeros(shape, array.dtype)
  if op in ("dtype", "mixed"):
    dtype = draw(st.sampled_from(["int64", "float16", "complex64", "bool", "uint8", ">f8",
                                  "U4", "S3", "object", "struct", "datetime64[s]", "V8"]))
    if dtype == "struct":
      array = np.zeros(array.shape, [("a", "<f8"), ("b", "<i4")])
    elif dtype == "object":
      array = array.astype(object)
    elif dtype in ("U4", "S3"):
      array = array.astype(str).astype(dtype)
    elif dtype == "V8":
      array = np.zeros(array.shape, "V8")
    elif dtype == "datetime64[s]":
      array = np.zeros(array.shape, "datetime64[s]")
    else:
      with np.errstate(all="ignore"):
        array = array.astype(dtype)
  data = npy_bytes(array if op != "bytes" else valid)
  if op == "bytes" or draw(st.integers(0, 4)) == 0:
    data = draw(mutated_bytes(data))
  return data


# ----------------------------------------------------------------------------- images

MODES = ["1", "L", "LA", "P", "PA", "RGB", "RGBA", "CMYK", "YCbCr", "I", "I;16", "F", "LAB",
         "HSV", "RGBX"]
FORMATS = {"PNG": ("1", "L", "LA", "P", "RGB", "RGBA", "I", "I;16"),
           "JPEG": ("L", "RGB", "CMYK"),
           "TIFF": ("1", "L", "LA", "P", "RGB", "RGBA", "CMYK", "I", "I;16", "F", "YCbCr", "LAB"),
           "BMP": ("1", "L", "P", "RGB"), "WEBP": ("RGB", "RGBA"), "GIF": ("L", "P"),
           "PPM": ("1", "L", "RGB", "I")}


@st.composite
def images(draw):
  """Bytes of a small image in any format and mode Pillow writes, any size from 1x1, with
  extreme pixels (NaN/inf for float images), sometimes animated."""
  fmt = draw(st.sampled_from(sorted(FORMATS)))
  mode = draw(st.sampled_from(FORMATS[fmt]))
  w, h = draw(st.integers(1, 40)), draw(st.integers(1, 40))
  seed = draw(st.integers(0, 2 ** 16))
  rng = np.random.default_rng(seed)
  base = Image.fromarray(rng.integers(0, 255, (h, w, 3), dtype=np.uint8))
  if mode == "F":
    values = rng.normal(0, 2, (h, w)).astype(np.float32)
    values.reshape(-1)[:draw(st.integers(0, 3))] = draw(st.sampled_from(
        [np.nan, np.inf, -np.inf, 1e30]))
    image = Image.fromarray(values, "F")
  elif mode in ("I", "I;16"):
    image = Image.fromarray(rng.integers(-70000 if mode == "I" else 0, 70000 if mode == "I"
                                         else 65535, (h, w)).astype(
                                             np.int32 if mode == "I" else np.uint16))
    if mode == "I;16" and image.mode != "I;16":
      image = image.convert("I;16")
  else:
    image = base.convert(mode)
  buffer = io.BytesIO()
  frames = draw(st.integers(1, 3)) if fmt in ("GIF", "WEBP", "PNG", "TIFF") else 1
  extra = [image.transpose(Image.FLIP_LEFT_RIGHT) for _ in range(frames - 1)]
  try:
    image.save(buffer, format=fmt, save_all=frames > 1, append_images=extra)
  except (OSError, ValueError, KeyError, TypeError):
    buffer = io.BytesIO()
    base.save(buffer, format="PNG")
  return buffer.getvalue()


PNG_SIDES = [0, 1, 7, 100_000, 2 ** 31 - 1]  # tiny, or past the decoder's pixel limit


def png_with_size(data: bytes, width: int, height: int) -> bytes:
  """A PNG's bytes with the size in its IHDR chunk replaced (the chunk's CRC fixed)."""
  import zlib  # pylint: disable=g-import-not-at-top
  assert data[12:16] == b"IHDR"
  body = b"IHDR" + struct.pack(">II", width, height) + data[24:29]
  return data[:12] + body + struct.pack(">I", zlib.crc32(body)) + data[33:]


@st.composite
def mutated_image(draw, valid: bytes):
  """Bytes of an image: another valid-or-odd image (images()), a PNG that claims another
  size (0, huge) with a valid header, or `valid` mutated byte by byte (truncated, chunk
  corrupted, wrong magic ...)."""
  op = draw(st.sampled_from(["image", "image", "size", "bytes", "bytes"]))
  if op == "image":
    return draw(images())
  if op == "size":
    png = valid if valid[12:16] == b"IHDR" else None
    if png is None:
      buffer = io.BytesIO()
      Image.open(io.BytesIO(valid)).save(buffer, format="PNG")
      png = buffer.getvalue()
    data = png_with_size(png, draw(st.sampled_from(PNG_SIDES)), draw(st.sampled_from(PNG_SIDES)))
    return data if draw(st.booleans()) else draw(mutated_bytes(data))
  return draw(mutated_bytes(valid))
