"""The `msnerf` command: one verb per stage. Each verb only parses and calls the library."""

import argparse
import os
import sys
from typing import List, Optional

from msnerf_jax import __version__
from msnerf_jax.core import files
from msnerf_jax.cli.config_args import Formatter as _Formatter
from msnerf_jax.cli.config_args import given_options
from msnerf_jax.core.errors import Interrupted, UserError


def build_parser() -> argparse.ArgumentParser:
  # pylint: disable=g-import-not-at-top
  from msnerf_jax.cli import adain as adain_cli
  from msnerf_jax.cli import demo as demo_cli
  from msnerf_jax.cli import evaluate as evaluate_cli
  from msnerf_jax.cli import features as features_cli
  from msnerf_jax.cli import multistyle as multistyle_cli
  from msnerf_jax.cli import nerf as nerf_cli
  from msnerf_jax.cli import paint as paint_cli
  from msnerf_jax.cli import pipeline as pipeline_cli
  from msnerf_jax.cli import render as render_cli
  from msnerf_jax.cli import view as view_cli
  parser = argparse.ArgumentParser(
      prog="msnerf", formatter_class=_Formatter,
      description="Multi-style NeRF with AdaIN: learn a scene once, render it in any style.")
  parser.add_argument("--version", action="version", version=f"msnerf-jax {__version__}")
  commands = parser.add_subparsers(dest="command", metavar="COMMAND", required=True)
  nerf_cli.register(commands, _Formatter)
  adain_cli.register(commands, _Formatter)
  multistyle_cli.register(commands, _Formatter)
  evaluate_cli.register(commands, _Formatter)
  render_cli.register(commands, _Formatter)
  features_cli.register(commands, _Formatter)
  paint_cli.register(commands, _Formatter)
  pipeline_cli.register(commands, _Formatter)
  demo_cli.register(commands, _Formatter)
  view_cli.register(commands, _Formatter)
  return parser


def main(argv: Optional[List[str]] = None) -> int:
  parser = build_parser()
  args = parser.parse_args(argv)
  args.given = given_options(parser, argv)  # what --config does not override
  try:
    sys.stdout.reconfigure(line_buffering=True)  # lines in order with stderr in a log
  except (AttributeError, ValueError):
    pass
  try:
    args.func(args)
  except UserError as e:  # bad input, and the machine's faults (DiskError)
    print(f"msnerf: error: {e}", file=sys.stderr)
    return 2
  except Interrupted as e:
    print(f"msnerf: {e}", file=sys.stderr)
    return 128 + e.signum
  except KeyboardInterrupt:
    print("msnerf: interrupted; re-run the same command to resume", file=sys.stderr)
    return 130
  except BrokenPipeError:  # `msnerf ... | head -1`: the reader left; no traceback
    _silence_stdout()
    return 141
  except OSError as e:  # permission denied, disk full ... on a file the user named
    where = getattr(e, "filename", None)
    fault = files.disk_error(where, e) if where else None
    if fault is not None:
      print(f"msnerf: error: {fault}", file=sys.stderr)
    else:
      print(f"msnerf: error: {where + ': ' if where else ''}{e.strerror or e}", file=sys.stderr)
    return 2
  except MemoryError:
    print("msnerf: error: out of memory; lower --chunk/--batch or the resolution", file=sys.stderr)
    return 2
  return 0


def _silence_stdout() -> None:
  """Points stdout at /dev/null so the interpreter's final flush into a closed pipe does not
  print 'Exception ignored ... BrokenPipeError'."""
  try:
    devnull = os.open(os.devnull, os.O_WRONLY)
    os.dup2(devnull, sys.stdout.fileno())
    os.close(devnull)
  except (OSError, ValueError, AttributeError):
    pass


def run() -> None:
  try:
    code = main()
    sys.stdout.flush()
  except BrokenPipeError:
    _silence_stdout()
    code = 141
  sys.exit(code)


if __name__ == "__main__":
  run()
