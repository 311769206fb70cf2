"""Writing what people look at: MP4/GIF videos, image grids, depth maps (atomic writes)."""

import contextlib
import errno
import os
import resource
import warnings
from typing import List, Optional, Sequence

import imageio.v2 as imageio
import numpy as np

from msnerf_jax.core import files
from msnerf_jax.data.images import to_uint8, write_image
from msnerf_jax.core.errors import UserError


def depth_to_image(depth: np.ndarray, accumulation: Optional[np.ndarray] = None,
                   near: Optional[float] = None, far: Optional[float] = None) -> np.ndarray:
  """Depth [H, W] -> grayscale RGB [H, W, 3] in [0, 1], near bright, far/empty dark."""
  depth = np.asarray(depth, np.float32)
  valid = np.ones_like(depth, bool) if accumulation is None else np.asarray(accumulation) > 0.5
  if not valid.any():
    return np.zeros((*depth.shape, 3), np.float32)
  lo = np.percentile(depth[valid], 1) if near is None else near
  hi = np.percentile(depth[valid], 99) if far is None else far
  value = 1.0 - np.clip((depth - lo) / max(hi - lo, 1e-6), 0.0, 1.0)
  value = np.where(valid, 0.15 + 0.85 * value, 0.0)
  return np.repeat(value[..., None], 3, -1)


def write_video(path: str, frames: Sequence[np.ndarray], fps: int = 24) -> List[str]:
  """Writes frames [H, W, 3] (float [0, 1] or uint8) as `path` (.mp4 or .gif) atomically.

  Returns the list of written paths.
  """
  frames = [f if f.dtype == np.uint8 else to_uint8(f) for f in frames]
  if not frames:
    raise UserError(f"{path}: no frames to write")
  ext = os.path.splitext(path)[1].lower()
  if ext not in (".gif", ".mp4"):
    raise UserError(f"{path}: video must end in .mp4 or .gif")
  if ext == ".gif":  # encoded in memory: the file is written at once, or not at all
    data = imageio.mimwrite("<bytes>", frames, format="GIF", duration=1000.0 / fps, loop=0)
    files.atomic_write_bytes(path, data)
    return [path]
  # Even sizes for yuv420p; macro_block_size=1 keeps odd sizes from being resized.
  frames = [f[: f.shape[0] // 2 * 2, : f.shape[1] // 2 * 2] for f in frames]
  with files.atomic_path(path) as tmp, _ffmpeg_forks():
    with imageio.get_writer(tmp, format="FFMPEG", fps=fps, codec="libx264", quality=8,
                            macro_block_size=1, pixelformat="yuv420p",
                            ffmpeg_log_level="quiet") as writer:
      for f in frames:
        writer.append_data(f)
    _check_complete(tmp, len(frames), path)
  return [path]


@contextlib.contextmanager
def _ffmpeg_forks():
  """A context in which JAX's warning that os.fork() was called is not shown: imageio starts
  ffmpeg with subprocess, whose child runs nothing of this process before it execs."""
  with warnings.catch_warnings():
    warnings.filterwarnings("ignore", r"os\.fork\(\) was called", RuntimeWarning)
    yield


def _check_complete(tmp: str, n_frames: int, path: str) -> None:
  """ffmpeg's exit status is not checked by imageio: a full disk leaves a truncated MP4 and
  no error. Reads the file's frame count back (a stream copy, no decoding) and raises
  OSError(ENOSPC) when the disk is (nearly) full, OSError(EFBIG) when the file reached this
  process's file-size limit, else UserError, unless all frames are there (`atomic_path`
  names `path`)."""
  import imageio_ffmpeg  # pylint: disable=g-import-not-at-top
  try:
    count = imageio_ffmpeg.count_frames_and_secs(tmp)[0]
  except (RuntimeError, OSError):
    count = -1
  if count != n_frames:
    if files.free_bytes(tmp) < files.MB:
      raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC), tmp)
    limit = resource.getrlimit(resource.RLIMIT_FSIZE)[0]
    if limit != resource.RLIM_INFINITY and os.path.getsize(tmp) >= limit:
      raise OSError(errno.EFBIG, os.strerror(errno.EFBIG), tmp)  # ffmpeg inherits the limit
    raise UserError(f"{path}: the video encoder (ffmpeg) wrote {max(count, 0)} of "
                    f"{n_frames} frames")


def write_videos(stem: str, frames: Sequence[np.ndarray], fps: int = 24) -> List[str]:
  """Writes stem.mp4 and stem.gif."""
  return write_video(stem + ".mp4", frames, fps) + write_video(stem + ".gif", frames, fps)


def grid(images: Sequence[Sequence[np.ndarray]], pad: int = 2) -> np.ndarray:
  """Rows of equally sized images [h, w, 3] -> one image with `pad` white pixels between."""
  rows = []
  for row in images:
    h = row[0].shape[0]
    sep = np.ones((h, pad, 3), np.float32)
    cells = []
    for i, im in enumerate(row):
      cells += ([sep] if i else []) + [np.asarray(im, np.float32)]
    rows.append(np.concatenate(cells, 1))
  width = max(r.shape[1] for r in rows)
  out = []
  for i, r in enumerate(rows):
    if r.shape[1] < width:
      r = np.concatenate([r, np.ones((r.shape[0], width - r.shape[1], 3), np.float32)], 1)
    out += ([np.ones((pad, width, 3), np.float32)] if i else []) + [r]
  return np.concatenate(out, 0)


def write_grid(path: str, images: Sequence[Sequence[np.ndarray]], pad: int = 2) -> str:
  write_image(path, grid(images, pad))
  return path


def text_image(text: str, width: int, height: int, size: int) -> np.ndarray:
  """[height, width, 3] white image with `text` (font size `size` px) in black, at its left
  and centred vertically, clipped to the image."""
  from PIL import Image, ImageDraw, ImageFont  # pylint: disable=g-import-not-at-top
  image = Image.new("RGB", (max(1, width), max(1, height)), (255, 255, 255))
  ImageDraw.Draw(image).text((2, height / 2), text, fill=(0, 0, 0), anchor="lm",
                             font=ImageFont.load_default(size=size))
  return np.asarray(image, np.float32) / 255.0


def labelled_grid(rows: Sequence[Sequence[Sequence[np.ndarray]]], row_labels: Sequence[str],
                  group_labels: Sequence[str], pad: int = 2) -> np.ndarray:
  """A grid whose rows are named on the left and whose column groups are named on top.

  rows[r][g] is the list of equally sized images [h, w, 3] of row r in column group g;
  groups are set 3 * pad apart (one pad between images) under their label.
  """
  h, w = np.shape(rows[0][0][0])[:2]
  size = max(8, min(14, h // 4))
  text_h = size + size // 2
  label_w = max(len(t) for t in row_labels) * size * 6 // 10 + 6
  header = [text_image("", label_w, text_h, size)]
  for g, label in enumerate(group_labels):
    n = len(rows[0][g])
    header += ([np.ones((text_h, pad, 3), np.float32)] if g else []) + [
        text_image(label, n * w + (n - 1) * pad, text_h, size)]
  gap = np.ones((h, pad, 3), np.float32)
  body = [[text_image(label, label_w, h, size)]
          + [x for g, images in enumerate(groups) for x in ([gap] if g else []) + list(images)]
          for label, groups in zip(row_labels, rows)]
  return grid([header] + body, pad)
