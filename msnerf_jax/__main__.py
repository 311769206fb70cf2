"""`python -m msnerf_jax` = the `msnerf` command."""
from msnerf_jax.cli import run

run()
