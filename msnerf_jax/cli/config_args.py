"""Command-line options generated from the config dataclasses: every field reachable."""

import argparse
import dataclasses
from typing import Any, Dict, Iterable, Set, Type

# Help for the fields that have no hand-written option of their own.
HELP = {
    # NerfConfig
    "pos_freqs": "positional-encoding frequencies of the points",
    "dir_freqs": "positional-encoding frequencies of the view directions",
    "skip_layer": "trunk layer whose output gets the encoded input again",
    "lindisp": "sample linearly in inverse depth instead of depth",
    "perturb": "jitter the stratified samples while training",
    "raw_noise_std": "std of the noise added to the raw density while training",
    "lr_init": "initial learning rate",
    "lr_final": "learning rate reached at --lr-decay-steps (exponential decay)",
    "lr_decay_steps": "steps over which the learning rate decays to --lr-final",
    "precrop_steps": "Blender: steps that sample only the central crop of each view",
    "precrop_frac": "side of that central crop, as a fraction of the view",
    "keep_checkpoints": "checkpoints kept in RUN/checkpoints",
    "render_chunk": "rays per jitted rendering call (bounds memory)",
    "mlp_chunk": "samples per MLP call inside a step (0 = all at once)",
    "trunk": "the trunk: mlp (the reference MLP) or hash (multiresolution hash encoding)",
    "hash_levels": "hash trunk: resolution levels",
    "hash_features": "hash trunk: features per level",
    "hash_table_size": "hash trunk: table entries per level (a power of two)",
    "hash_min_res": "hash trunk: coarsest grid resolution",
    "hash_max_res": "hash trunk: finest grid resolution",
    "sampler": "where to sample: hierarchical (coarse + fine networks) or grid (one network, "
               "only in the occupied cells of an occupancy grid)",
    "scene_box": "half side of the scene's box around the origin, for the hash trunk and the "
                 "grid (0 = Blender and NDC 1.5, captures: the farthest camera)",
    "grid_resolution": "grid sampler: cells per side of the occupancy grid",
    "march_steps": "grid sampler: candidate samples per ray across the box",
    "march_segments": "grid sampler: rendering marches in this many segments, a ray stopping "
                      "after one once its transmittance is below 1e-4",
    "samples_per_ray": "grid sampler: sample budget per ray (shared by a batch's rays)",
    "grid_every": "grid sampler: steps between refreshes of the grid",
    "grid_warmup": "grid sampler: steps during which a refresh visits every cell",
    "grid_decay": "grid sampler: decay of a cell's density estimate at each refresh",
    "grid_threshold": "grid sampler: optical depth per step above which a cell is occupied",
    # MultistyleConfig
    "style_dim": "length of the style vectors",
    "style_hidden": "width of the style MLP's first hidden layer",
    "style_hidden2": "width of the style MLP's second hidden layer",
    "normalize_styles": "standardise each style vector before the style MLPs",
    # DataConfig
    "format": "scene format: auto, blender, llff, transforms (nerfstudio / instant-ngp "
              "transforms.json) or colmap (sparse/0 model)",
    "llff_holdout": "LLFF, and captures without a split: every n-th image is held out for "
                    "val/test",
    "layout": "captures: auto, forward-facing (LLFF recentring + NDC) or object (centred on "
              "what the cameras look at, bounds from the data)",
}


def add_config_arguments(parser: argparse.ArgumentParser, cls: Type, defaults: Any,
                         skip: Iterable[str] = (), title: str = "more settings",
                         helps: Dict[str, str] = None) -> None:
  """One option --field-name per field of the dataclass `cls` not in `skip` (those have
  hand-written options), in a group of its own. Each defaults to None, meaning "as
  `defaults` says" (shown in the help); booleans get --x / --no-x. `helps` replaces HELP's
  text for some fields (a name that means something else in this config)."""
  helps = {**HELP, **(helps or {})}
  group = parser.add_argument_group(title)
  for field in dataclasses.fields(cls):
    if field.name in skip or dataclasses.is_dataclass(field.default_factory):
      continue
    value = getattr(defaults, field.name) if defaults is not None else field.default
    shown = "the preset's" if defaults is None else value
    kwargs: Dict[str, Any] = ({"action": argparse.BooleanOptionalAction}
                              if isinstance(field.default, bool) else
                              {"type": type(field.default), "metavar": type(field.default).__name__.upper()})
    group.add_argument("--" + field.name.replace("_", "-"), default=None,
                       help=f"{helps.get(field.name, field.name.replace('_', ' '))} "
                            f"(default: {shown})", **kwargs)


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
  from msnerf_jax.core import config as config_lib  # pylint: disable=g-import-not-at-top
  from msnerf_jax.kinds.runs import load_config  # pylint: disable=g-import-not-at-top
  aliases = aliases or {}
  given = getattr(args, "given", set())
  explicit = {f.name: getattr(built, f.name) for f in dataclasses.fields(built)
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
  return {f.name: getattr(args, f.name) for f in dataclasses.fields(cls)
          if getattr(args, f.name, None) is not None}


class Formatter(argparse.ArgumentDefaultsHelpFormatter, argparse.RawDescriptionHelpFormatter):
  """Appends each option's default to its help, except on required options (which have
  none) and on options whose help already says what None means ("default: the preset's")."""

  def _get_help_string(self, action):
    text = action.help or ""
    if action.required or (action.default is None and "default" in text):
      return text
    return super()._get_help_string(action)
