"""Every config field is reachable from the command line; --config starts from a saved run."""

import argparse
import json
import os

import pytest

from msnerf_jax import cli
from msnerf_jax.core import config as config_lib
from msnerf_jax.core.config import override
from test_cli_nerf import assert_one_line_error, msnerf


def verb_parser(*path):
  parser = cli.build_parser()
  for name in path:
    sub = next(a for a in parser._actions  # pylint: disable=protected-access
               if isinstance(a, argparse._SubParsersAction))  # pylint: disable=protected-access
    parser = sub.choices[name]
  return parser


def dests(parser):
  return {a.dest for a in parser._actions}  # pylint: disable=protected-access


@pytest.mark.parametrize("path, cls, aliases, fixed", [
    (("nerf", "train"), config_lib.NerfConfig, {}, ()),
    (("nerf", "train"), config_lib.DataConfig, {}, ("path",)),  # --data
    (("multistyle", "train"), config_lib.MultistyleConfig, {"lr_init": "lr"},
     ("nerf",)),  # the NeRF run's config
    (("adain", "train"), config_lib.AdainConfig, {}, ("encoder",)),  # one encoder exists
    (("features", "train"), config_lib.FeatureConfig, {"lr_init": "lr"},
     ("nerf",)),  # the NeRF run's config
])
def test_every_config_field_has_an_option(path, cls, aliases, fixed):
  have = dests(verb_parser(*path))
  missing = [f.name for _, f in config_lib.flat_fields(cls)
             if f.name not in fixed and aliases.get(f.name, f.name) not in have]
  assert not missing, f"{' '.join(path)} lacks options for {missing}"


def test_help_has_no_default_none_on_required_options():
  for path in (("nerf", "train"), ("multistyle", "train"), ("adain", "train"),
               ("features", "train"), ("nerf", "eval")):
    text = " ".join(verb_parser(*path).format_help().split())
    assert "--data DATA (default: None)" not in text
    for action in verb_parser(*path)._actions:  # pylint: disable=protected-access
      if action.required:
        assert f"{' '.join(action.help.split())} (default: None)" not in text, action.dest


@pytest.mark.slow
def test_generated_options_and_config_file_reach_run_json(tiny_blender, tmp_path):
  first = str(tmp_path / "first")
  r = msnerf("nerf", "train", "--data", tiny_blender, "--out", first, "--preset", "cpu",
             "--steps", "1", "--batch-rays", "64", "--net-width", "16", "--n-coarse", "4", "--n-fine", "4",
             "--lr-init", "0.01", "--raw-noise-std", "0.5", "--lindisp", "--keep-checkpoints",
             "1", "--no-perturb", "--pos-freqs", "3", "--llff-holdout", "4")
  assert r.returncode == 0, r.stderr
  saved = json.load(open(os.path.join(first, "run.json")))
  config = saved["config"]
  assert (config["optim"]["lr_init"], config["raw_noise_std"], config["lindisp"],
          config["perturb"], config["optim"]["keep_checkpoints"],
          config["pos_freqs"]) == (0.01, 0.5, True, False, 1, 3)
  assert saved["data"]["llff_holdout"] == 4
  second = str(tmp_path / "second")
  r = msnerf("nerf", "train", "--data", tiny_blender, "--out", second, "--config", first,
             "--net-depth", "2")
  assert r.returncode == 0, r.stderr
  assert "config of" in r.stdout
  again = json.load(open(os.path.join(second, "run.json")))["config"]
  assert again == dict(config, net_depth=2, skip_layer=1)  # the rest from the saved run


def test_bad_config_file_and_values_are_one_line_errors(tiny_blender, tmp_path):
  (tmp_path / "x.txt").write_text("x")
  run = str(tmp_path / "run")
  for argv, pattern in [
      (["--config", str(tmp_path / "nope")], "no such run folder"),
      (["--config", str(tmp_path / "x.txt")], "expected a run folder or its run.json"),
      (["--lr-init", "0"], "--lr-init 0.0: must be positive"),
      (["--keep-checkpoints", "0"], "--keep-checkpoints 0: must be >= 1"),
  ]:
    assert_one_line_error(msnerf("nerf", "train", "--data", tiny_blender, "--out", run, *argv),
                          pattern)
    assert not os.path.exists(run)


def test_given_options_are_what_the_command_line_sets():
  from msnerf_jax.cli.config_args import given_options  # pylint: disable=g-import-not-at-top
  parser = cli.build_parser()
  given = given_options(parser, ["multistyle", "train", "--nerf", "a", "--stylized", "b",
                                 "--out", "c", "--steps", "3000", "--style-hidden", "64"])
  assert {"nerf", "stylized", "out", "steps", "style_hidden"} <= given
  assert not {"batch_rays", "seed", "lr", "density_aware", "config"} & given
  # The defaults are back afterwards.
  args = parser.parse_args(["multistyle", "train", "--nerf", "a", "--stylized", "b", "--out", "c"])
  # (a config option's default is None: "as the config says"; --parallel has its own).
  assert args.steps is None and args.config is None and args.parallel == "shard_map"


@pytest.mark.parametrize("kind, argv, field, value", [
    ("multistyle", ["multistyle", "train", "--nerf", "N", "--stylized", "S", "--out", "O",
                    "--lr", "0.002"], "lr_final", 0.0002),
    ("adain", ["adain", "train", "--content", "C", "--styles", "S", "--out", "O",
               "--batch", "2"], "batch", 2),
])
def test_config_file_keeps_what_the_command_line_does_not_set(kind, argv, field, value,
                                                             tmp_path):
  from msnerf_jax.kinds import runs  # pylint: disable=g-import-not-at-top
  from msnerf_jax.cli.config_args import given_options, start_config  # pylint: disable=g-import-not-at-top
  from msnerf_jax.kinds.registry import get_kind  # pylint: disable=g-import-not-at-top
  cls = get_kind(kind).config_class
  saved = override(cls(), steps=7, seed=5)
  runs.prepare_run_dir(str(tmp_path / "run"), kind, {"config": config_lib.to_dict(saved)})
  parser = cli.build_parser()
  args = parser.parse_args(argv + ["--config", str(tmp_path / "run")])
  args.given = given_options(parser, argv + ["--config", str(tmp_path / "run")])
  built = override(cls(), **{field: value})  # what the options alone build
  config = start_config(args, kind, built, {"lr_init": "lr", "lr_final": "lr"})
  assert [config_lib.setting_of(config, name) for name in ("steps", "seed", field)] == [
      7, 5, value]


@pytest.mark.parametrize("argv, cls, ratio, expected", [
    (["multistyle", "train", "--nerf", "N", "--stylized", "S", "--lr", "0.002"],
     config_lib.MultistyleConfig, 0.1, {"lr_init": 0.002, "lr_final": 0.0002}),
    (["multistyle", "train", "--nerf", "N", "--stylized", "S", "--lr", "0.002", "--lr-final",
      "0.001", "--steps", "9"], config_lib.MultistyleConfig, 0.1,
     {"lr_init": 0.002, "lr_final": 0.001, "steps": 9}),
    (["features", "train", "--nerf", "N", "--decoder", "D", "--lr", "0.5", "--seed", "4"],
     config_lib.FeatureConfig, 0.0, {"lr_init": 0.5, "lr_final": 1e-3, "seed": 4}),
    (["paint", "train", "--nerf", "N", "--styles", "a.jpg", "--lr", "0.3",
      "--keep-checkpoints", "5"], config_lib.PaintConfig, 0.0,
     {"lr_init": 0.3, "lr_final": 0.005, "keep_checkpoints": 5}),
])
def test_trainer_options_set_the_optimisation_block(argv, cls, ratio, expected, tmp_path):
  """--lr and the other optimisation options of the trainers on a NeRF run land in the
  config's `optim` block; the rest of the block keeps the config's own defaults."""
  from msnerf_jax.cli.config_args import trainer_config  # pylint: disable=g-import-not-at-top
  args = cli.build_parser().parse_args(argv + ["--out", str(tmp_path / "run")])
  config, shows = trainer_config(args, cls, "multistyle", ratio)
  assert shows and config == override(cls(), **expected)
