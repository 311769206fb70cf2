"""msnerf-jax: multi-style neural radiance fields with AdaIN, in JAX/Flax."""

__version__ = "0.1.0"


def load_run(run_dir, kind=None):
  """Loads a saved run (config, latest params, step) without the CLI; `kind` ("nerf",
  "adain" or "multistyle") refuses a run of another kind.

  See `msnerf_jax.kinds.runs.load_run`.
  """
  from msnerf_jax.kinds.runs import load_run as _load_run
  return _load_run(run_dir, kind)


__all__ = ["__version__", "load_run"]
