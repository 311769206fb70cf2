"""msnerf-jax: multi-style neural radiance fields with AdaIN, in JAX/Flax.

The public surface (`msnerf_jax.api`, listed in `__all__`) is importable from here:

    import msnerf_jax as ms
    run = ms.load_run("runs/demo/multistyle")

It is loaded on first use, so `import msnerf_jax` (and the command line) stays light.
"""

import importlib.util

__version__ = "0.1.0"


def __getattr__(name):
  """The names of msnerf_jax.api, loaded on first use (PEP 562)."""
  if name.startswith("__") and name != "__all__":
    raise AttributeError(name)
  if importlib.util.find_spec(f"{__name__}.{name}") is not None:  # a subpackage: not ours.
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
  from msnerf_jax import api  # pylint: disable=g-import-not-at-top
  if name == "__all__":
    return ["__version__", *api.__all__]
  if name in api.__all__:
    return getattr(api, name)
  raise AttributeError(f"module {__name__!r} has no attribute {name!r}")


def __dir__():
  return sorted(set(globals()) | set(__getattr__("__all__")))
