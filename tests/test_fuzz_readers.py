"""Property-based fuzzing of every reader of users' files (issue 46).

Each format starts from a valid tiny file (the builders of test_captures, test_bad_input and
conftest) and hypothesis breaks it (tests/fuzz_corpus.py: fields removed, wrong types,
NaN/inf, huge and negative sizes, truncation, wrong magic, non-UTF-8, deep nesting). Every
case must end in a result that passes the checks a valid one passes, or in a UserError whose
message starts with the file's path (one line); never another exception, never a hang (an
alarm per case), never a write (the folder's files and mtimes are compared).

The default run is small (derandomized, a few hundred cases per reader); the slow test runs
the same properties with many thousands per reader (MSNERF_FUZZ_EXAMPLES sets how many):
  python -m pytest -q -s -m slow tests/test_fuzz_readers.py
"""

import contextlib
import dataclasses
import io
import json
import os
import re
import signal
import struct

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from PIL import Image

from msnerf_jax import cli
from msnerf_jax.core import config as config_lib
from msnerf_jax.core.config import DataConfig
from msnerf_jax.core.errors import UserError
from msnerf_jax.data import camera_path as camera_path_lib
from msnerf_jax.data import colmap
from msnerf_jax.data import images as images_lib
from msnerf_jax.data import stylized as stylized_lib
from msnerf_jax.data.scene import load_scene
from msnerf_jax.kinds import runs
from msnerf_jax.train import paint_data

import fuzz_corpus as corpus
from conftest import write_blender_scene
from test_bad_input import write_llff_scene, write_stylized
from test_captures import colmap_capture, orbit_poses, transforms_frames, write_transforms

TIME_LIMIT_S = 20  # one case taking longer is a hang
EXAMPLES = 200  # per reader, default run
SLOW_EXAMPLES = int(os.environ.get("MSNERF_FUZZ_EXAMPLES", "6000"))  # per reader, slow run


def fuzz_settings(examples):
  return settings(max_examples=examples, derandomize=True, database=None, deadline=None,
                  print_blob=True, suppress_health_check=list(HealthCheck))


# ----------------------------------------------------------------------------- harness


class Hang(BaseException):
  """A reader ran past TIME_LIMIT_S (a BaseException: no reader's `except Exception` turns
  it into a UserError)."""


@contextlib.contextmanager
def time_limit(seconds):
  def on_alarm(signum, frame):
    raise Hang(f"no result after {seconds} s")
  previous = signal.signal(signal.SIGALRM, on_alarm)
  signal.setitimer(signal.ITIMER_REAL, seconds)
  try:
    yield
  finally:
    signal.setitimer(signal.ITIMER_REAL, 0)
    signal.signal(signal.SIGALRM, previous)


def files_of(folder):
  """{relative path: (size, mtime_ns)} of everything under `folder`."""
  out = {}
  for root, dirs, names in os.walk(folder):
    for name in names + dirs:
      full = os.path.join(root, name)
      st_ = os.lstat(full)
      out[os.path.relpath(full, folder)] = (st_.st_size, st_.st_mtime_ns)
  return out


@dataclasses.dataclass
class Format:
  """A reader of one file of a valid input folder: build(folder) writes the valid input,
  `file` is the fuzzed file (relative), load(folder) reads it as the library does,
  check(result) asserts what a valid result satisfies, `named` the path every error
  message must start with ("file": the fuzzed file, "folder": the input folder, or a
  function (folder, bytes) -> the paths it may start with)."""
  name: str
  build: object
  file: str
  mutate: object  # valid bytes -> strategy of bytes
  load: object
  check: object
  named: str = "file"


COUNTS = {}


def check_case(fmt, folder, data):
  """Writes `data` as the format's file in `folder`, reads it and checks the outcome;
  restores the valid file after. Returns the UserError's message, or None when it loaded."""
  COUNTS[fmt.name] = COUNTS.get(fmt.name, 0) + 1
  path = os.path.join(folder, fmt.file)
  valid = open(path, "rb").read()
  with open(path, "wb") as f:
    f.write(data)
  before = files_of(folder)
  try:
    with time_limit(TIME_LIMIT_S):
      try:
        result = fmt.load(folder)
      except UserError as e:
        message = str(e)
      else:
        message = None
    if message is None:
      fmt.check(result)
    else:
      named = (fmt.named(folder, data) if callable(fmt.named) else
               [path if fmt.named == "file" else folder])
      assert any(message.startswith(p + ":") or message.startswith(p + os.sep)
                 for p in named), message
      assert "\n" not in message, message
    assert files_of(folder) == before, "the reader wrote"
    return message
  finally:
    with open(path, "wb") as f:
      f.write(valid)


# ----------------------------------------------------------------------------- valid checks


def check_scene(result):
  scene, _ = result
  n = len(scene.images)
  assert n >= 1 and scene.images.dtype == np.float32 and scene.images.ndim == 4
  assert scene.images.shape[-1] == 3 and min(scene.images.shape[1:3]) >= 1
  assert np.all(np.isfinite(scene.images)) and scene.images.min() >= 0 and scene.images.max() <= 1
  assert scene.c2w.shape == (n, 3, 4) and np.all(np.isfinite(scene.c2w))
  for K in scene.intrinsics:
    assert np.all(np.isfinite(K)) and K[0, 0] > 0 and K[1, 1] > 0, K
  assert np.isfinite(scene.near) and np.isfinite(scene.far) and 0 <= scene.near < scene.far
  assert len(scene.splits["train"]) >= 1
  for ids in scene.splits.values():
    assert all(0 <= i < n for i in ids)
  assert scene.render_poses.ndim == 3 and np.all(np.isfinite(scene.render_poses))
  if scene.distortion is not None:
    assert scene.distortion.shape == (n, 5) and np.all(np.isfinite(scene.distortion))
  assert len(scene.image_paths) == n


def check_camera_path(result):
  cameras, fps = result
  assert cameras and np.isfinite(fps) and fps > 0
  for camera in cameras:
    assert isinstance(camera.height, int) and isinstance(camera.width, int)
    assert camera.height >= 1 and camera.width >= 1
    assert np.all(np.isfinite(camera.c2w)) and np.all(np.isfinite(camera.K))
    assert camera.K[0, 0] > 0 and camera.K[1, 1] > 0


def check_image(image, min_side=1):
  assert image.dtype == np.float32 and image.ndim == 3 and image.shape[-1] == 3
  assert min(image.shape[:2]) >= min_side
  assert np.all(np.isfinite(image)) and image.min() >= 0 and image.max() <= 1


def check_run(result):
  config, scene = result
  assert isinstance(config, config_lib.NerfConfig)
  check_scene((scene, None))


def check_stylized(data):
  m, n = len(data.names), len(data.c2w)
  assert m >= 1 and all(isinstance(name, str) for name in data.names)
  assert data.vectors.shape == (m, 1024) and np.all(np.isfinite(data.vectors))
  assert data.images.dtype == np.uint8 and data.images.shape[:2] == (m, n)
  assert data.c2w.shape == (n, 3, 4) and np.all(np.isfinite(data.c2w))
  for ids in data.splits.values():
    assert ids.ndim == 1 and all(0 <= i < n for i in ids)


def check_stats(stats):
  mean, std = stats
  assert mean.shape == std.shape and mean.shape[0] == 1 and mean.dtype == np.float32
  assert np.all(np.isfinite(mean)) and np.all(std > 0) and np.all(np.isfinite(std))


def check_cache(cache):
  assert set(cache) == {"points", "weights", "pixel", "accumulation"}
  n, p = cache["weights"].shape
  assert n >= 1 and cache["points"].shape == (n, p, 3) and cache["pixel"].shape == (n, p)
  assert cache["accumulation"].ndim == 2 and len(cache["accumulation"]) == n
  for key in ("points", "weights", "accumulation"):
    assert np.issubdtype(cache[key].dtype, np.floating) and np.all(np.isfinite(cache[key]))
  assert np.issubdtype(cache["pixel"].dtype, np.integer)
  assert np.all(cache["pixel"] >= 0) and np.all(cache["pixel"] < cache["accumulation"].shape[1])


# ----------------------------------------------------------------------------- valid inputs


def build_colmap(binary):
  def build(folder):
    colmap_capture(folder, binary=binary)
  return build


def build_transforms(folder):
  rng = np.random.default_rng(1)
  paths = [f"images/{i}.png" for i in range(4)]
  os.makedirs(os.path.join(folder, "images"))
  for p in paths:
    Image.fromarray(rng.integers(0, 255, (12, 16, 3), dtype=np.uint8)).save(
        os.path.join(folder, p))
  meta = {"camera_model": "OPENCV", "fl_x": 14.0, "fl_y": 14.5, "cx": 8.0, "cy": 6.0, "w": 16,
          "h": 12, "k1": -0.05, "k2": 0.01, "p1": 0.001, "p2": -0.001,
          "train_filenames": paths[:3], "val_filenames": paths[3:]}
  frames = transforms_frames(paths, orbit_poses(4))
  frames[1].update({"fl_x": 15.0, "fl_y": 15.0})
  write_transforms(folder, meta, frames)


def build_blender(folder):
  write_blender_scene(folder, n_train=3, n_val=1, size=8)


def build_llff(folder):
  write_llff_scene(folder, n=4, size=8, ext=".png")


def build_camera_path(folder):
  poses = orbit_poses(3)
  K = np.array([[20.0, 0, 8], [0, 20.0, 6], [0, 0, 1]])
  camera_path_lib.write_camera_path(os.path.join(folder, "camera_path.json"), poses, K, 12, 16)


def build_run(folder):
  scene = os.path.join(folder, "scene")
  build_blender(scene)
  config = config_lib.NerfConfig()
  record = {"kind": "nerf", "config": config_lib.to_dict(config),
            "data": config_lib.to_dict(DataConfig(path=scene))}
  with open(os.path.join(folder, "run.json"), "w") as f:
    json.dump(record, f)


def run_named(folder, data):
  """A run.json's errors name the run folder, or the scene folder the (fuzzed) file names."""
  try:
    scene = json.loads(data)["data"]["path"]
  except Exception:  # pylint: disable=broad-except
    scene = None
  return [folder] + ([scene] if isinstance(scene, str) and scene else [])


def build_stylized(folder):
  scene = os.path.join(folder, "scene")
  build_blender(scene)
  write_stylized(scene, os.path.join(folder, "stylized"), names=("red",))
  stats = np.concatenate([np.full((1, 8), 0.5), np.full((1, 8), 2.0)]).astype(np.float32)
  np.save(os.path.join(folder, "stylized", stylized_lib.CONTENT_STATS), stats)


def build_images(folder):
  rng = np.random.default_rng(2)
  Image.fromarray(rng.integers(0, 255, (10, 12, 4), dtype=np.uint8)).save(
      os.path.join(folder, "view.png"))
  Image.fromarray(rng.integers(0, 255, (24, 20, 3), dtype=np.uint8)).save(
      os.path.join(folder, "style.jpg"), quality=80)


CACHE_SOURCE = "/runs/nerf@2"


def build_cache(folder):
  rng = np.random.default_rng(3)
  n, p, pixels = 2, 1024, 64
  cache = {"points": rng.normal(size=(n, p, 3)).astype(np.float32),
           "weights": rng.random((n, p)).astype(np.float32),
           "pixel": np.sort(rng.integers(0, pixels, (n, p))).astype(np.int32),
           "accumulation": rng.random((n, pixels)).astype(np.float32)}
  with open(os.path.join(folder, paint_data.CACHE_FILE), "wb") as f:
    np.savez(f, nerf_run=np.array(CACHE_SOURCE), **cache)


def mutate_json(valid):
  return corpus.mutated_json(json.loads(valid))


def mutate_text(valid):
  return corpus.mutated_lines(valid.decode())


def mutate_colmap_bin(name):
  def mutate(valid):
    return corpus.mutated_records(valid, corpus.colmap_fields(name, valid))
  return mutate


def mutate_npy(valid):
  return corpus.mutated_npy(np.load(io.BytesIO(valid)))


def mutate_npz(valid):
  """An .npz whose members are mutated .npy files (a member removed, another added, the
  stamp of another run), or the archive's bytes mutated."""
  import zipfile  # pylint: disable=g-import-not-at-top
  members = dict(np.load(io.BytesIO(valid), allow_pickle=False))

  @st.composite
  def strategy(draw):
    if draw(st.integers(0, 3)) == 0:
      return draw(corpus.mutated_bytes(valid))
    out = {k: corpus.npy_bytes(v) for k, v in members.items()}
    for _ in range(draw(st.integers(1, 3))):
      key = draw(st.sampled_from(sorted(members)))
      op = draw(st.sampled_from(["mutate", "mutate", "remove", "rename"]))
      if op == "mutate":
        out[key] = draw(corpus.mutated_npy(members[key]))
      elif op == "remove":
        out.pop(key, None)
      else:
        out[draw(st.text("abcxyz_", min_size=1, max_size=5))] = out.pop(key, b"")
    buffer = io.BytesIO()
    with zipfile.ZipFile(buffer, "w") as z:
      for k, v in out.items():
        z.writestr(k + ".npy", v)
    return buffer.getvalue()
  return strategy()


def scene_loader(fmt, **kwargs):
  return lambda folder: load_scene(DataConfig(path=folder, format=fmt, **kwargs))


FORMATS = [
    Format("colmap cameras.bin", build_colmap(True), "sparse/0/cameras.bin",
           mutate_colmap_bin("cameras"), scene_loader("colmap"), check_scene, "folder"),
    Format("colmap images.bin", build_colmap(True), "sparse/0/images.bin",
           mutate_colmap_bin("images"), scene_loader("colmap"), check_scene, "folder"),
    Format("colmap points3D.bin", build_colmap(True), "sparse/0/points3D.bin",
           mutate_colmap_bin("points3D"), scene_loader("colmap"), check_scene, "folder"),
    Format("colmap cameras.txt", build_colmap(False), "sparse/0/cameras.txt", mutate_text,
           scene_loader("colmap"), check_scene, "folder"),
    Format("colmap images.txt", build_colmap(False), "sparse/0/images.txt", mutate_text,
           scene_loader("colmap"), check_scene, "folder"),
    Format("colmap points3D.txt", build_colmap(False), "sparse/0/points3D.txt", mutate_text,
           scene_loader("colmap"), check_scene, "folder"),
    Format("transforms.json", build_transforms, "transforms.json", mutate_json,
           scene_loader("transforms"), check_scene, "folder"),
    Format("blender transforms_train.json", build_blender, "transforms_train.json", mutate_json,
           scene_loader("blender"), check_scene, "folder"),
    Format("llff poses_bounds.npy", build_llff, "poses_bounds.npy", mutate_npy,
           scene_loader("llff", downscale=1), check_scene, "folder"),
    Format("camera_path.json", build_camera_path, "camera_path.json", mutate_json,
           lambda folder: camera_path_lib.read_camera_path(
               os.path.join(folder, "camera_path.json")), check_camera_path),
    Format("run.json", build_run, "run.json", mutate_json,
           lambda folder: (runs.load_config(folder, "nerf"), runs.run_scene(folder)),
           check_run, run_named),
    Format("blender view image", build_blender, "train/r_0.png", corpus.mutated_image,
           scene_loader("blender"), check_scene, "folder"),
    Format("view image (read_image)", build_images, "view.png", corpus.mutated_image,
           lambda folder: images_lib.read_image(os.path.join(folder, "view.png")),
           check_image),
    Format("style image (read_style_image)", build_images, "style.jpg", corpus.mutated_image,
           lambda folder: images_lib.read_style_image(os.path.join(folder, "style.jpg")),
           lambda image: check_image(image, images_lib.STYLE_MIN_SIDE)),
    Format("upload (decode_image)", build_images, "style.jpg", corpus.mutated_image,
           lambda folder: images_lib.decode_image(
               open(os.path.join(folder, "style.jpg"), "rb").read(),
               os.path.join(folder, "style.jpg")), check_image),
    Format("stylized manifest.json", build_stylized, "stylized/manifest.json", mutate_json,
           lambda folder: stylized_lib.load_stylized(os.path.join(folder, "stylized"),
                                                     progress=False), check_stylized, "folder"),
    Format("stylized poses.npy", build_stylized, "stylized/poses.npy",
           mutate_npy,
           lambda folder: stylized_lib.load_stylized(os.path.join(folder, "stylized"),
                                                     progress=False), check_stylized, "folder"),
    Format("style_vector.npy", build_stylized, "stylized/red/style_vector.npy",
           mutate_npy,
           lambda folder: stylized_lib.load_stylized(os.path.join(folder, "stylized"),
                                                     progress=False), check_stylized, "folder"),
    Format("content_stats.npy", build_stylized, "stylized/content_stats.npy",
           mutate_npy,
           lambda folder: stylized_lib.read_content_stats(os.path.join(folder, "stylized")),
           check_stats),
    Format("paint sample_cache.npz", build_cache, paint_data.CACHE_FILE, mutate_npz,
           lambda folder: paint_data.read_cache(os.path.join(folder, paint_data.CACHE_FILE),
                                                CACHE_SOURCE), check_cache),
]
BY_NAME = {f.name: f for f in FORMATS}


@pytest.fixture(scope="module")
def valid_inputs(tmp_path_factory):
  """name -> a folder holding the format's valid input (built once; each case writes its
  file there and puts the valid one back)."""
  root = tmp_path_factory.mktemp("fuzz")
  folders, built = {}, {}
  for fmt in FORMATS:
    if fmt.build not in built:
      folder = str(root / f"f{len(built)}")
      os.makedirs(folder)
      fmt.build(folder)
      built[fmt.build] = folder
    folders[fmt.name] = built[fmt.build]
  return folders


def fuzz(fmt, folder, examples):
  """Runs `examples` hypothesis cases of one format; returns the number of cases run."""
  valid = open(os.path.join(folder, fmt.file), "rb").read()
  start = COUNTS.get(fmt.name, 0)

  @fuzz_settings(examples)
  @given(fmt.mutate(valid))
  def run(data):
    check_case(fmt, folder, data)

  run()
  return COUNTS[fmt.name] - start


# ----------------------------------------------------------------------------- regressions
# What hypothesis found (each a traceback or a result failing the checks before the readers
# were fixed), reduced to an edit of the valid file: (format, edit(valid bytes) -> bytes,
# what the error message says now).


def json_set(*path_value):
  """An edit setting path_value[:-1] (keys) of a JSON file to path_value[-1] (DELETE: removes)."""
  *path, value = path_value

  def edit(valid):
    doc = json.loads(valid)
    parent = doc
    for key in path[:-1]:
      parent = parent[key]
    if value is DELETE:
      del parent[path[-1]]
    else:
      parent[path[-1]] = value
    return json.dumps(doc).encode()
  return edit


DELETE = object()


def colmap_field(name, fmt, index, value):
  """An edit of a COLMAP binary file: its index-th field of struct format `fmt` set."""
  def edit(valid):
    offset = [o for o, f in corpus.colmap_fields(name, valid) if f == fmt][index]
    data = bytearray(valid)
    struct.pack_into("<" + fmt, data, offset, value)
    return bytes(data)
  return edit


def npy_of(array):
  return lambda valid: corpus.npy_bytes(np.asarray(array))


def npy_changed(change):
  def edit(valid):
    array = np.load(io.BytesIO(valid)).copy()
    change(array)
    return corpus.npy_bytes(array)
  return edit


def null_in_npy_header(valid):
  assert valid[10:11] == b"{"
  return valid[:10] + b"\0" + valid[11:]  # the header's "{" (SyntaxError, TokenError)


def npz_without(key):
  def edit(valid):
    members = dict(np.load(io.BytesIO(valid)))
    del members[key]
    buffer = io.BytesIO()
    np.savez(buffer, **members)
    return buffer.getvalue()
  return edit


def npz_member_bytes(key, data):
  def edit(valid):
    import zipfile  # pylint: disable=g-import-not-at-top
    members = {k + ".npy": corpus.npy_bytes(v) for k, v in np.load(io.BytesIO(valid)).items()}
    members[key + ".npy"] = data(members[key + ".npy"])
    buffer = io.BytesIO()
    with zipfile.ZipFile(buffer, "w") as z:
      for k, v in members.items():
        z.writestr(k, v)
    return buffer.getvalue()
  return edit


def long_npy_header(valid):
  """A version 2 .npy file of the same array with 20000 bytes of header padding."""
  array = np.load(io.BytesIO(valid))
  header = repr({"descr": np.lib.format.dtype_to_descr(array.dtype), "fortran_order": False,
                 "shape": array.shape}).encode()
  header += b" " * (20_000 - len(header)) + b"\n"
  return b"\x93NUMPY\x02\x00" + struct.pack("<I", len(header)) + header + array.tobytes()


def float_tiff(value, size=4):
  """A float (mode F) TIFF of size x size pixels, one of them `value`."""
  pixels = np.full((size, size), 0.5, np.float32)
  pixels[0, 0] = value
  buffer = io.BytesIO()
  Image.fromarray(pixels, "F").save(buffer, format="TIFF")
  return buffer.getvalue()


def deep_json(valid):
  return b"[" * corpus.DEEP + valid


REGRESSIONS = [
    # Deep nesting: RecursionError out of json.load (every JSON reader).
    ("blender transforms_train.json", deep_json, "nested too deeply"),
    ("run.json", deep_json, "nested too deeply"),
    ("stylized manifest.json", deep_json, "nested too deeply"),
    ("camera_path.json", deep_json, "nested too deeply"),
    # A 5000-digit number: ValueError (int conversion limit), not a JSONDecodeError.
    ("transforms.json", lambda valid: valid.replace(b'"fl_x": 14.0', b'"fl_x": ' + b"9" * 5000),
     "malformed JSON"),
    # A 10**400 in a pose matrix: OverflowError converting to float64.
    ("transforms.json", json_set("frames", 0, "transform_matrix", 0, 0, 10 ** 400),
     "not a numeric"),
    ("blender transforms_train.json", json_set("frames", 0, "transform_matrix", 0, 0, 10 ** 400),
     "not numeric"),
    # COLMAP: a NaN lens coefficient reached the scene; fx 1e300 gave K = inf and a denormal
    # fx 1e-320 gave focal 0 in float32; 2^63 points: ValueError (array too big).
    ("colmap cameras.bin", colmap_field("cameras", "d", 7, float("nan")), "must be finite"),
    ("colmap cameras.bin", colmap_field("cameras", "d", 0, 1e300), "out of range"),
    ("colmap cameras.bin", colmap_field("cameras", "d", 0, 1e-320), "out of range"),
    ("colmap cameras.txt", lambda valid: valid.replace(b"-0.12", b"nan"), "must be finite"),
    ("colmap points3D.bin", colmap_field("points3D", "Q", 0, 2 ** 63), "truncated"),
    # COLMAP text: a point id of 20 digits (OverflowError converting to int64).
    ("colmap images.txt", lambda valid: re.sub(rb"\n1\.0 2\.0 \d+", b"\n1.0 2.0 " + b"9" * 20,
                                               valid, count=1), "out of range"),
    ("colmap points3D.txt", lambda valid: valid.replace(b" 0.5 ", b" 0.5 " + b"9" * 20 + b" 0 ",
                                                        1), "out of range"),
    # LLFF: a NUL in the .npy header (SyntaxError); strings (TypeError in isfinite); a
    # near bound of 1e-310 (the normalised poses are inf); hwf height 0 (focal inf).
    ("llff poses_bounds.npy", null_in_npy_header, "not a readable .npy array"),
    ("llff poses_bounds.npy", lambda valid: corpus.npy_bytes(
        np.load(io.BytesIO(valid)).astype("U4")), "expected numbers"),
    ("llff poses_bounds.npy", npy_changed(lambda a: a.__setitem__((slice(None), 15), 1e-310)),
     "cannot be normalised"),
    ("llff poses_bounds.npy", npy_changed(lambda a: a.__setitem__((0, 4), 0.0)),
     "no usable focal length"),
    # (slow run) a focal length of 1e-300: positive, but 0 as float32 in K.
    ("llff poses_bounds.npy", npy_changed(lambda a: a.__setitem__((0, 14), 1e-300)),
     "no usable focal length"),
    # camera_path.json: 10**400 in a matrix (OverflowError), a width of 2^64 (TypeError in
    # isfinite), a width of 0.5 (a camera 0 pixels wide), a fov of 1e-300 (K = inf).
    ("camera_path.json", json_set("camera_path", 0, "camera_to_world", 0, 10 ** 400),
     "not numeric"),
    ("camera_path.json", json_set("render_width", 2 ** 64), "render_width"),
    ("camera_path.json", json_set("render_width", 0.5), "whole number"),
    ("camera_path.json", json_set("camera_path", 0, "fov", 1e-300), "no usable focal"),
    # (slow run) a matrix entry of 1e308: finite, but inf in the float32 camera.
    ("camera_path.json", json_set("camera_path", 0, "camera_to_world", 0, 1e308),
     "16 finite numbers"),
    # run.json: null settings (TypeError in detect_format, in validate), a 10**400 float
    # setting (OverflowError), an empty data path, a format "" (a `--format` message).
    ("run.json", json_set("data", "path", None), "should be str"),
    ("run.json", json_set("config", "net_depth", None), "should be int"),
    ("run.json", json_set("config", "optim", "lr_init", 10 ** 400), "should be float"),
    ("run.json", json_set("config", "lr_init", 0.1), "unknown NerfConfig keys ['lr_init']"),
    ("run.json", json_set("data", "path", ""), "path is empty"),
    ("run.json", json_set("data", "format", ""), "run.json: data: format"),
    # The stylized manifest: splits of nested lists (ValueError), None (TypeError,
    # AttributeError), n_views null (TypeError), two styles of one name; the .npy files: a
    # NUL in the header, strings, float64 beyond float32 (inf after the cast).
    ("stylized manifest.json", json_set("splits", "train", [[0, 1], 2]), "splits"),
    ("stylized manifest.json", json_set("splits", "train", None), "splits"),
    ("stylized manifest.json", json_set("splits", None), "splits"),
    ("stylized manifest.json", json_set("n_views", None), "n_views"),
    ("stylized manifest.json", lambda valid: json_set("styles", json.loads(valid)["styles"] * 2)(
        valid), "distinct"),
    ("stylized poses.npy", null_in_npy_header, "not a valid .npy array"),
    ("style_vector.npy", npy_of(np.zeros(1024, "U4")), "expected numbers"),
    ("style_vector.npy", npy_of(np.full(1024, 1e300)), "beyond float32"),
    ("content_stats.npy", npy_of(np.full((2, 8), 1e300)), "beyond float32"),
    # The paint cache: a member missing (loaded as a cache), a member that is not .npy
    # (bytes: AttributeError), a broken member header (TokenError), a truncated zip
    # (BadZipFile).
    ("paint sample_cache.npz", npz_without("accumulation"), "expected accumulation"),
    ("paint sample_cache.npz", npz_member_bytes("weights", lambda v: b"not npy"),
     "not a .npy array"),
    ("paint sample_cache.npz", npz_member_bytes("pixel", null_in_npy_header),
     "not a sample cache"),
    ("paint sample_cache.npz", lambda valid: valid[:4], "not a sample cache"),
    # (slow run) a member's .npy header of 20000 bytes: numpy's message spans three lines.
    ("paint sample_cache.npz", npz_member_bytes("pixel", long_npy_header), "is large"),
    ("content_stats.npy", long_npy_header, "is large"),
    # (slow run) a float TIFF with a NaN pixel: NaN in the image (np.clip keeps NaN).
    ("view image (read_image)", lambda valid: float_tiff(np.nan), "NaN"),
    ("style image (read_style_image)", lambda valid: float_tiff(np.nan, 20), "NaN"),
    ("upload (decode_image)", lambda valid: float_tiff(np.nan), "NaN"),
]


@pytest.mark.parametrize("name, edit, needle", REGRESSIONS,
                         ids=[f"{r[0]}-{n}" for n, r in enumerate(REGRESSIONS)])
def test_found_cases_are_user_errors(name, edit, needle, valid_inputs):
  fmt = BY_NAME[name]
  folder = valid_inputs[name]
  message = check_case(fmt, folder, edit(open(os.path.join(folder, fmt.file), "rb").read()))
  assert message is not None and needle in message, message


@pytest.mark.parametrize("name", list(BY_NAME))
def test_valid_input_loads(name, valid_inputs):
  fmt = BY_NAME[name]
  folder = valid_inputs[name]
  assert check_case(fmt, folder, open(os.path.join(folder, fmt.file), "rb").read()) is None


@pytest.mark.parametrize("name", list(BY_NAME))
def test_fuzzed_input_loads_or_is_a_user_error(name, valid_inputs):
  count = fuzz(BY_NAME[name], valid_inputs[name], EXAMPLES)
  assert count >= min(EXAMPLES, 50), count


@pytest.mark.slow
@pytest.mark.parametrize("name", list(BY_NAME))
def test_many_fuzzed_inputs(name, valid_inputs):
  """SLOW_EXAMPLES cases of one format (run with -s: the counts are printed)."""
  count = fuzz(BY_NAME[name], valid_inputs[name], SLOW_EXAMPLES)
  print(f"\nfuzzed {name}: {count} cases", flush=True)
  assert count >= SLOW_EXAMPLES // 2, count


@pytest.fixture(scope="module", autouse=True)
def report_counts():
  """Prints how many cases the module ran (every call of check_case), with -s."""
  yield
  print(f"\nfuzz cases run in all: {sum(COUNTS.values())} ({len(COUNTS)} formats)", flush=True)


# ----------------------------------------------------------------------------- truncation


@pytest.mark.parametrize("name", ["cameras", "images", "points3D"])
def test_every_truncation_of_a_binary_model(name, tmp_path):
  """A small binary model (2 images) cut at every byte of each file."""
  root = str(tmp_path / "capture")
  cams = {1: ("PINHOLE", 16, 12, (14.0, 14.0, 8.0, 6.0))}
  from test_captures import write_colmap  # pylint: disable=g-import-not-at-top
  poses = orbit_poses(2)
  write_colmap(os.path.join(root, "sparse", "0"), cams,
               [(1, poses[0], 1, "a.png"), (2, poses[1], 1, "b.png")],
               [(np.zeros(3), [1, 2]), (np.ones(3), [2])])
  folder = os.path.join(root, "sparse", "0")
  path = os.path.join(folder, f"{name}.bin")
  valid = open(path, "rb").read()
  cut = []
  for n in range(len(valid)):
    open(path, "wb").write(valid[:n])
    with pytest.raises(UserError) as e:
      colmap.read_model(folder)
    assert str(e.value).startswith(path + ":"), str(e.value)
    cut.append(n)
  open(path, "wb").write(valid)
  assert len(colmap.read_model(folder).images) == 2 and len(cut) == len(valid)


# ----------------------------------------------------------------------------- the CLI


CLI_FORMATS = ["blender transforms_train.json", "transforms.json", "colmap images.bin",
               "llff poses_bounds.npy"]


@pytest.mark.parametrize("name", CLI_FORMATS)
def test_cli_reports_fuzzed_files_in_one_line(name, valid_inputs, tmp_path, capsys):
  """A few fuzzed scenes the reader refuses, through `msnerf nerf train`: exit code 2 and the
  reader's message as the last stderr line, nothing written into the scene."""
  fmt = BY_NAME[name]
  folder = valid_inputs[name]
  path = os.path.join(folder, fmt.file)
  valid = open(path, "rb").read()
  checked = []

  @fuzz_settings(6)
  @given(fmt.mutate(valid))
  def run(data):
    message = check_case(fmt, folder, data)
    if message is None or len(checked) >= 3:
      return
    open(path, "wb").write(data)
    try:
      before = files_of(folder)
      capsys.readouterr()
      out = str(tmp_path / f"run{len(checked)}")
      code = cli.main(["nerf", "train", "--data", folder, "--out", out, "--steps", "1"]
                      + (["--downscale", "1"] if "llff" in name else []))
      err = capsys.readouterr().err
      assert code == 2, err
      assert err.strip().splitlines()[-1] == f"msnerf: error: {message}"
      assert files_of(folder) == before
      checked.append(message)
    finally:
      open(path, "wb").write(valid)

  run()
  assert checked, "no fuzzed case was refused"
