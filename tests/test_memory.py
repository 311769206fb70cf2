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
