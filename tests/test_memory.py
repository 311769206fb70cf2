"""core/memory.py: the figures the pipeline's summary prints."""

import numpy as np

from msnerf_jax.core import memory


def test_current_memory_follows_an_allocation_and_its_release():
  before = memory.current_gib()
  block = np.ones(40_000_000)  # 0.30 GiB, touched
  during = memory.current_gib()
  assert 0.25 < during - before < 0.4
  assert memory.peak_gib() >= during - 0.01
  del block
  memory.release()
  assert memory.current_gib() < during - 0.25


def test_release_drops_compiled_programs_only_when_asked():
  import jax  # pylint: disable=g-import-not-at-top
  traced = []

  @jax.jit
  def add_one(x):
    traced.append(1)  # runs when JAX traces (and compiles) the function
    return x + 1

  add_one(1.0)
  memory.release()
  add_one(1.0)
  assert len(traced) == 1  # kept
  memory.release(compiled=True)
  assert float(add_one(1.0)) == 2.0 and len(traced) == 2  # compiled again
