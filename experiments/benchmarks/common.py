"""What the benchmark scripts beside this file share: the repository root, the data folder,
the machine line they print, call timing, synthetic rays and `--set` overrides.

A script run as `python experiments/benchmarks/NAME.py` has this folder on sys.path, so it
imports these as `from common import ...`; msnerf_jax itself is the installed package.
jax and msnerf_jax are imported inside the helpers that use them: bench_parallel's parent
process only needs ROOT and DATA.
"""

import os
import platform
import time

ROOT = os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
"""The repository root (this file is ROOT/experiments/benchmarks/common.py)."""

DATA = os.environ.get("MSNERF_DATA", os.path.normpath(os.path.join(ROOT, "..", "shared", "data")))
"""The shared scenes and styles: $MSNERF_DATA, else the `shared/data` beside the repository."""


def machine() -> str:
  """'<processor>, <n> cores, jax <version> on <platform>', as the benchmarks print it."""
  import jax  # pylint: disable=g-import-not-at-top
  return (f"{platform.processor() or platform.machine()}, {os.cpu_count()} cores, "
          f"jax {jax.__version__} on {jax.devices()[0].platform}")


def call_times(fn, repeats):
  """Wall seconds of each of `repeats` calls of fn() (its result blocked on), after one
  warm-up call (compilation)."""
  import jax  # pylint: disable=g-import-not-at-top
  jax.block_until_ready(fn())
  times = []
  for _ in range(repeats):
    t = time.perf_counter()
    jax.block_until_ready(fn())
    times.append(time.perf_counter() - t)
  return times


def synthetic_rays(n, key):
  """n rays from radius 4 towards the origin, near 2 and far 6, as in the lego set-up."""
  # pylint: disable=g-import-not-at-top
  import jax
  import jax.numpy as jnp
  from msnerf_jax.nerf.rays import ray_bundle
  origins = jnp.tile(jnp.array([0.0, 0.0, 4.0]), (n, 1))
  directions = jnp.array([0.0, 0.0, -1.0]) + 0.2 * jax.random.normal(key, (n, 3))
  return ray_bundle(origins, directions, 2.0, 6.0)


def parse_overrides(items, preset):
  """NerfConfig overrides {key: value} for `preset` from `--set [PRESET:]key=value ...`
  (items without a PRESET: prefix apply to every preset)."""
  # pylint: disable=g-import-not-at-top
  from msnerf_jax.core.config import NerfConfig, flat_fields
  fields = {f.name: f for _, f in flat_fields(NerfConfig)}  # the optimisation block's too
  out = {}
  for item in items:
    name, setting = item.split(":", 1) if ":" in item else (preset, item)
    if name != preset:
      continue
    key, value = setting.split("=", 1)
    kind = type(fields[key].default)
    out[key] = value.lower() in ("1", "true", "yes") if kind is bool else kind(value)
  return out
