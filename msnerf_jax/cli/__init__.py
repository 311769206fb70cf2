"""The `msnerf` command: one verb per stage. Each verb only parses and calls the library."""

import argparse
import sys
from typing import List, Optional

from msnerf_jax import __version__
from msnerf_jax.cli.config_args import Formatter as _Formatter
from msnerf_jax.cli.config_args import given_options
from msnerf_jax.errors import UserError


def build_parser() -> argparse.ArgumentParser:
  # pylint: disable=g-import-not-at-top
  from msnerf_jax.cli import adain as adain_cli
  from msnerf_jax.cli import demo as demo_cli
  from msnerf_jax.cli import multistyle as multistyle_cli
  from msnerf_jax.cli import nerf as nerf_cli
  from msnerf_jax.cli import pipeline as pipeline_cli
  parser = argparse.ArgumentParser(
      prog="msnerf", formatter_class=_Formatter,
      description="Multi-style NeRF with AdaIN: learn a scene once, render it in any style.")
  parser.add_argument("--version", action="version", version=f"msnerf-jax {__version__}")
  commands = parser.add_subparsers(dest="command", metavar="COMMAND", required=True)
  nerf_cli.register(commands, _Formatter)
  adain_cli.register(commands, _Formatter)
  multistyle_cli.register(commands, _Formatter)
  pipeline_cli.register(commands, _Formatter)
  demo_cli.register(commands, _Formatter)
  return parser


def main(argv: Optional[List[str]] = None) -> int:
  parser = build_parser()
  args = parser.parse_args(argv)
  args.given = given_options(parser, argv)  # what --config does not override
  try:
    args.func(args)
  except UserError as e:
    print(f"msnerf: error: {e}", file=sys.stderr)
    return 2
  except KeyboardInterrupt:
    print("msnerf: interrupted; re-run the same command to resume", file=sys.stderr)
    return 130
  except OSError as e:  # permission denied, disk full ... on a file the user named
    where = f"{e.filename}: " if getattr(e, "filename", None) else ""
    print(f"msnerf: error: {where}{e.strerror or e}", file=sys.stderr)
    return 2
  except MemoryError:
    print("msnerf: error: out of memory; lower --chunk/--batch or the resolution", file=sys.stderr)
    return 2
  return 0


def run() -> None:
  sys.exit(main())


if __name__ == "__main__":
  run()
