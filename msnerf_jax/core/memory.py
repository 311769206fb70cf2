"""This process's memory: its peak and current resident size, and handing freed memory back
to the system between the pipeline's stages."""

import ctypes
import gc
import os
import resource
import sys


def peak_gib() -> float:
  """The process's peak resident memory so far, in GiB."""
  peak = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss  # bytes on macOS, KiB on Linux
  return peak / 2**30 if sys.platform == "darwin" else peak / 2**20


def current_gib() -> float:
  """The process's resident memory now, in GiB (its peak where /proc is not there)."""
  try:
    with open("/proc/self/statm") as f:
      return int(f.read().split()[1]) * os.sysconf("SC_PAGE_SIZE") / 2**30
  except (OSError, ValueError, IndexError):
    return peak_gib()


def release(compiled: bool = False) -> None:
  """Frees what nothing refers to any more and, with glibc, returns the free parts of the
  heap to the system (malloc_trim): a stage's buffers would otherwise stay resident under
  the next stage's. With `compiled`, JAX's compiled programs go too (jax.clear_caches;
  what runs next compiles what it needs again)."""
  if compiled:
    import jax  # pylint: disable=g-import-not-at-top
    jax.clear_caches()
  gc.collect()
  try:
    ctypes.CDLL(None).malloc_trim(0)  # the C library this process already has loaded
  except (OSError, AttributeError):  # not glibc
    pass
