"""Command-line options generated from the config dataclasses: every field reachable."""

import argparse
import os
from typing import Any, Dict, Iterable, Optional, Sequence, Set, Tuple, Type

from msnerf_jax.cli.common import add_parallel_arguments, start_processes
from msnerf_jax.core import config as config_lib
from msnerf_jax.core.config import flat_fields, help_of, setting_of
from msnerf_jax.core.errors import UserError


def add_config_arguments(parser: argparse.ArgumentParser, cls: Type, defaults: Any,
                         names: Optional[Sequence[str]] = None, skip: Iterable[str] = (),
                         title: Optional[str] = None) -> None:
  """One option --field-name per field of the dataclass `cls`: the fields `names`, in that
  order, or else every field not in `skip` (config_lib.flat_fields: the `optim` block's among
  them, other nested configs aside). The help is the field's
  (config.help_of). Each defaults to None, meaning "as `defaults` says" (shown in the help;
  `defaults` None: "the preset's"), so a config is `override(defaults, **config_overrides(
  args, cls))` and --config RUN knows what the command line set; booleans get --x / --no-x.
  `title`: an argument group of its own (None: the parser's own options)."""
  group = parser if title is None else parser.add_argument_group(title)
  fields = {f.name: f for _, f in flat_fields(cls)}
  chosen = ([fields[n] for n in names] if names is not None else
            [f for f in fields.values() if f.name not in skip])
  for field in chosen:
    value = setting_of(defaults if defaults is not None else cls(), field.name)
    shown = "the preset's" if defaults is None else value
    kwargs: Dict[str, Any] = ({"action": argparse.BooleanOptionalAction}
                              if isinstance(field.default, bool) else
                              {"type": type(field.default),
                               "metavar": type(field.default).__name__.upper()})
    group.add_argument("--" + field.name.replace("_", "-"), default=None,
                       help=f"{help_of(field)} (default: {shown})", **kwargs)


def _parsers(parser: argparse.ArgumentParser):
  """The parser and every sub-parser below it."""
  yield parser
  for action in parser._actions:  # pylint: disable=protected-access
    if isinstance(action, argparse._SubParsersAction):  # pylint: disable=protected-access
      for sub in action.choices.values():
        yield from _parsers(sub)


def given_options(parser: argparse.ArgumentParser, argv) -> Set[str]:
  """The dests of the options `argv` sets itself (not left at their default): parses it
  once more with every default suppressed."""
  actions = [a for p in _parsers(parser) for a in p._actions  # pylint: disable=protected-access
             if a.option_strings]
  saved = [a.default for a in actions]
  try:
    for action in actions:
      action.default = argparse.SUPPRESS
    return set(vars(parser.parse_args(argv)))
  finally:
    for action, default in zip(actions, saved):
      action.default = default


def start_config(args: argparse.Namespace, kind: str, built: Any,
                 aliases: Dict[str, str] = None) -> Any:
  """The config a trainer starts from: `built` from the options, or with --config RUN that
  run's config with only the options given on the command line on top. `aliases` maps a
  field to the option dest that sets it (lr_init -> lr)."""
  if getattr(args, "config", None) is None:
    return built
  from msnerf_jax.kinds.runs import load_config  # pylint: disable=g-import-not-at-top
  aliases = aliases or {}
  given = getattr(args, "given", set())
  explicit = {f.name: setting_of(built, f.name) for _, f in flat_fields(type(built))
              if aliases.get(f.name, f.name) in given}
  return config_lib.override(load_config(args.config, kind), **explicit)


def add_config_option(parser: argparse.ArgumentParser, kind: str) -> None:
  """--config RUN: start from a saved run's config."""
  parser.add_argument("--config", default=None, metavar="RUN",
                      help=f"start from the config of a saved {kind} run (its folder or "
                           "run.json); the options given on the command line override it "
                           "(default: none)")


def config_overrides(args: argparse.Namespace, cls: Type) -> Dict[str, Any]:
  """{field: value} of the fields of `cls` given on the command line (not None)."""
  return {f.name: getattr(args, f.name) for _, f in flat_fields(cls)
          if getattr(args, f.name, None) is not None}


def add_trainer_options(parser: argparse.ArgumentParser, cls: Type, main: Sequence[str],
                        lr_after: int, lr_help: str, kind: str, title: str) -> None:
  """The options of a trainer on a NeRF run (features, paint, multistyle) in the order
  `--help` lists them: the fields `main` with --lr (sets lr_init; `lr_help` says how it
  decays) after the first `lr_after` of them, the devices and processes, --config RUN, then
  a group `title` of every other field of `cls`."""
  defaults = cls()
  add_config_arguments(parser, cls, defaults, names=main[:lr_after])
  parser.add_argument("--lr", type=float, default=None,
                      help=f"{lr_help} (default: {defaults.optim.lr_init})")
  add_config_arguments(parser, cls, defaults, names=main[lr_after:])
  add_parallel_arguments(parser)
  add_config_option(parser, kind)
  add_config_arguments(parser, cls, defaults, title=title, skip=tuple(main) + ("lr_init",))


def trainer_config(args: argparse.Namespace, cls: Type, kind: str, lr_final_ratio: float = 0.0
                   ) -> Tuple[Any, bool]:
  """(the config of a trainer of `add_trainer_options`, whether this process prints): joins
  the other processes first, refuses an --out that is a file, and starts from --config RUN
  where given. --lr sets lr_init, and lr_final = lr * `lr_final_ratio` too when the ratio
  is not 0, unless --lr-final is given."""
  shows = start_processes(args)
  if os.path.isfile(args.out):
    raise UserError(f"{args.out}: is a file, expected a run folder")
  lr = {} if args.lr is None else {"lr_init": args.lr}
  aliases = {"lr_init": "lr"}
  if lr and lr_final_ratio:
    lr["lr_final"] = args.lr * lr_final_ratio
    aliases["lr_final"] = "lr_final" if args.lr_final else "lr"
  built = config_lib.override(cls(), **{**lr, **config_overrides(args, cls)})
  return start_config(args, kind, built, aliases), shows


class Formatter(argparse.ArgumentDefaultsHelpFormatter, argparse.RawDescriptionHelpFormatter):
  """Appends each option's default to its help, except on required options (which have
  none) and on options whose help already says what None means ("default: the preset's")."""

  def _get_help_string(self, action):
    text = action.help or ""
    if action.required or (action.default is None and "default" in text):
      return text
    return super()._get_help_string(action)
