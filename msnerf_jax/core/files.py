"""Writing files so that a killed process or a failing disk never leaves a partial one.

Every artefact the project writes (run records, histories, stylized images and vectors,
manifests, videos, grids, evaluation tables, pipeline records) goes through
`atomic_write_bytes` or `atomic_path`: a temporary name in the same folder, fsync, rename,
fsync of the folder. A write that fails because of the machine (full disk, quota, read-only
or failing file system, file-size limit) removes its temporary file and raises `DiskError`,
which the CLI prints as one line with exit code 2; what was there before is untouched.
Checkpoints (orbax) have the same contract in `msnerf_jax.core.checkpoint`.
"""

import contextlib
import errno
import io
import json
import os
import shutil
import tempfile
from typing import Any, Iterator, Optional

import numpy as np

from msnerf_jax.core.errors import UserError

# errno -> what the one-line message says; these are the machine's faults, not the input's.
WRITE_FAULTS = {
    errno.ENOSPC: "no space left on device",
    errno.EDQUOT: "disk quota exceeded",
    errno.EROFS: "read-only file system",
    errno.EIO: "input/output error",
    errno.EFBIG: "file too large (file-size limit of this process or file system)",
}
TEMP_PREFIX = ".tmp-"
MB = 1 << 20


class DiskError(UserError):
  """A write failed because of the machine (full disk ...): one line, exit code 2."""


def free_bytes(path: str) -> int:
  """Free bytes on the file system that holds `path` (or its nearest existing parent)."""
  path = os.path.abspath(path)
  while not os.path.exists(path):
    parent = os.path.dirname(path)
    if parent == path:
      break
    path = parent
  return shutil.disk_usage(path).free


def _mb(n: float) -> str:
  return f"{n / MB:.1f} MB" if n < 100 * MB else f"{n / MB:.0f} MB"


def disk_error(path: str, error: BaseException, needed: Optional[int] = None
               ) -> Optional[DiskError]:
  """The DiskError for `error` if it (or an exception it was raised from, or its message,
  for libraries that wrap OS errors in their own types) is a write fault; else None.

  The message names `path`, the fault and, with `needed` (bytes), the space it needed and
  what is free now.
  """
  fault = None
  seen = set()
  e = error
  while e is not None and id(e) not in seen and fault is None:
    seen.add(id(e))
    if isinstance(e, OSError) and e.errno in WRITE_FAULTS:
      fault = WRITE_FAULTS[e.errno]
    else:
      text = str(e)
      for code, what in WRITE_FAULTS.items():
        if os.strerror(code) in text or what in text:
          fault = what
          break
      if fault is None and "RESOURCE_EXHAUSTED" in text:
        fault = WRITE_FAULTS[errno.ENOSPC]
    e = e.__cause__ or e.__context__
  if fault is None:
    return None
  try:
    free = free_bytes(path)
  except OSError:
    free = None
  detail = []
  if needed:
    detail.append(f"needed about {_mb(needed)}")
  if free is not None:
    detail.append(f"{_mb(free)} free")
  suffix = f" ({', '.join(detail)})" if detail else ""
  full = fault in (WRITE_FAULTS[errno.ENOSPC], WRITE_FAULTS[errno.EDQUOT])
  hint = "; free some space and re-run the same command" if full else ""
  return DiskError(f"{path}: {fault}{suffix}{hint}")


def check_free_space(path: str, needed: int, what: str) -> None:
  """DiskError up front unless the file system holding `path` has `needed` bytes free
  (`what` names the stage: 'nerf training', 'the stylized dataset' ...)."""
  free = free_bytes(path)
  if needed > free:
    raise DiskError(f"{path}: not enough free space for {what} (needs about {_mb(needed)}, "
                    f"{_mb(free)} free); free some space or choose another folder")


def _fsync_folder(folder: str) -> None:
  try:
    fd = os.open(folder, os.O_RDONLY)
  except OSError:  # some file systems do not open folders; the rename is still atomic
    return
  try:
    os.fsync(fd)
  except OSError:
    pass
  finally:
    os.close(fd)


def _umask() -> int:
  mask = os.umask(0o022)
  os.umask(mask)
  return mask


@contextlib.contextmanager
def atomic_path(path: str, needed: Optional[int] = None) -> Iterator[str]:
  """Yields a temporary path beside `path` for a writer that needs a file name (a video
  encoder); when the block ends the file is fsynced and renamed to `path`. On any error
  (or a kill: only a hidden `.tmp-*` file can remain) `path` is untouched; write faults
  become DiskError naming `path` (and `needed`, the bytes it was to write, when known).
  """
  folder = os.path.dirname(os.path.abspath(path))
  try:
    os.makedirs(folder, exist_ok=True)
    fd, tmp = tempfile.mkstemp(dir=folder, prefix=TEMP_PREFIX,
                               suffix=os.path.splitext(path)[1])
    os.close(fd)
    os.chmod(tmp, 0o666 & ~_umask())  # mkstemp's 0600 -> what open() would have made
  except OSError as e:
    raise (disk_error(path, e, needed) or e) from None
  try:
    yield tmp
    with open(tmp, "rb+") as f:
      os.fsync(f.fileno())
    os.replace(tmp, path)
    _fsync_folder(folder)
  except BaseException as e:
    error = disk_error(path, e, needed) if isinstance(e, Exception) else None
    if error is None:
      raise
    raise error from None
  finally:
    if os.path.exists(tmp):
      os.remove(tmp)


def atomic_write_bytes(path: str, data: bytes) -> None:
  """Writes `data` to `path` through a temporary file, fsync and a rename: never a partial
  file; a write fault is a DiskError naming `path` and the size it needed."""
  if len(data) > free_bytes(os.path.dirname(os.path.abspath(path))):  # fail before writing
    raise disk_error(path, OSError(errno.ENOSPC, os.strerror(errno.ENOSPC)), len(data))
  with atomic_path(path, len(data)) as tmp:
    with open(tmp, "wb") as f:
      f.write(data)


def write_json(path: str, value: Any) -> None:
  """Saves a JSON-able value atomically, indented, keys sorted."""
  atomic_write_bytes(path, json.dumps(value, indent=2, sort_keys=True).encode())


def write_npy(path: str, array: np.ndarray) -> None:
  """Saves an array as .npy atomically (no pickles)."""
  buffer = io.BytesIO()
  np.save(buffer, np.asarray(array), allow_pickle=False)
  atomic_write_bytes(path, buffer.getvalue())


def append_lines(path: str, lines) -> None:
  """Appends text lines to `path` by rewriting it atomically (small logs such as a run's
  history): a kill or a full disk leaves the old file, never half a line."""
  try:
    with open(path, "rb") as f:
      old = f.read()
  except FileNotFoundError:
    old = b""
  if old and not old.endswith(b"\n"):  # a torn line from an older, non-atomic writer
    old = old[: old.rfind(b"\n") + 1]
  atomic_write_bytes(path, old + "".join(line + "\n" for line in lines).encode())
