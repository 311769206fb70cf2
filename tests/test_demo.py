"""`msnerf demo` end to end at a tiny size (every stage, real AdaIN training included), its
caching (a re-run skips every finished stage), and the procedural scene and styles."""

import json
import os

import imageio.v2 as imageio
import numpy as np
import pytest
from PIL import Image

from msnerf_jax import cli
from msnerf_jax.pipeline import demo
from msnerf_jax.core.config import DataConfig
from msnerf_jax.data.scene import load_scene

TINY = ["--size", "16", "--views", "4", "--adain-steps", "2", "--adain-size", "16",
        "--nerf-steps", "4", "--nerf-batch-rays", "64", "--ms-steps", "3", "--ms-batch-rays", "32",
        "--features-steps", "3", "--features-batch-cells", "8", "--paint-steps", "4",
        "--frames", "4", "--grid-views", "2", "--no-progress"]
OUTPUTS = ("painted.mp4", "painted.gif", "painted_morph.mp4", "painted_morph.gif", "styles.mp4",
           "styles.gif", "features.mp4", "features.gif", "grid.png")
STAGES = ("adain", "nerf", "stylized", "multistyle", "features", "painted", "renders")


def test_scene_and_styles_are_deterministic_blender_data(tmp_path):
  a = demo.write_scene(str(tmp_path / "a"), size=24, n_train=3, n_val=2, seed=3, progress=False)
  b = demo.write_scene(str(tmp_path / "b"), size=24, n_train=3, n_val=2, seed=3, progress=False)
  for rel in ("train/r_0.png", "val/r_1.png", "transforms_train.json"):
    assert open(os.path.join(a, rel), "rb").read() == open(os.path.join(b, rel), "rb").read()
  scene, data = load_scene(DataConfig(path=a))
  assert data.format == "blender" and scene.images.shape == (5, 24, 24, 3)
  assert (scene.near, scene.far) == (2.0, 6.0)
  cover = scene.alphas.mean() / 255
  assert 0.1 < cover < 0.9  # objects in front of a transparent background
  assert scene.images.std() > 0.1  # textured, not flat
  np.testing.assert_allclose(np.linalg.norm(scene.c2w[:, :, 3], axis=-1), 4.0, atol=1e-5)
  paths = demo.write_styles(str(tmp_path / "styles"), size=64, seed=0)
  pictures = [np.asarray(Image.open(p).convert("RGB"), np.float32) for p in paths]
  assert all(p.shape == (64, 64, 3) for p in pictures)
  means = np.stack([p.mean((0, 1)) for p in pictures])
  assert np.abs(means[:, None] - means[None]).sum(-1)[np.triu_indices(3, 1)].min() > 20


def test_demo_end_to_end_and_rerun_skips(tmp_path, capsys):
  out = str(tmp_path / "demo")
  assert cli.main(["demo", "--out", out, *TINY]) == 0
  first = capsys.readouterr().out
  for stage in STAGES:
    assert f"{stage}: done in" in first
  run_readme_python(out)  # the README's Python example on the demo's multi-style run
  renders = os.path.join(out, "renders")
  for name in OUTPUTS:
    assert os.path.getsize(os.path.join(renders, name)) > 0
  grid = np.asarray(Image.open(os.path.join(renders, "grid.png")), np.float32) / 255
  n_styles = 4  # stripes, mosaic, swirl, original
  # A header line over the methods, a label column, then per style its picture and 2 views of
  # each method (painted, feature field, the paper's model, per-frame AdaIN), groups 6 px
  # apart: the tiles are the rendered frames.
  assert grid.shape[0] == 12 + 2 + n_styles * 16 + (n_styles - 1) * 2
  tile = lambda group, view: grid[14:30, -16 - (3 - group) * 40 - (1 - view) * 18:][:, :16]
  stripes = np.asarray(Image.open(os.path.join(out, "styles", "stripes.png")), np.float32) / 255
  assert np.abs(grid[14:30, -176:-160].mean((0, 1)) - stripes.mean((0, 1))).max() < 0.1
  for group, video_name in enumerate(("painted", "features", "styles")):
    frames = imageio.mimread(os.path.join(renders, video_name + ".gif"))
    # first style, second grid view (frame 2 of 4) of each model: the grid shows its frames
    assert np.abs(tile(group, 1) - frames[2][:, :16, :3] / 255).mean() < 0.03  # (GIF palette)
    assert np.ptp(tile(group, 1)) > 0
    assert len(frames) == 4 and frames[0].shape[:2] == (16, n_styles * 16 + (n_styles - 1) * 2)
  # Per-frame AdaIN: the NeRF's view stylized on its own, unlike the paper's model's frame.
  assert np.ptp(tile(3, 0)) > 0 and np.abs(tile(3, 0) - tile(2, 0)).mean() > 0.01
  morph = imageio.mimread(os.path.join(renders, "painted_morph.gif"))
  assert len(morph) == 4 and morph[0].shape[:2] == (16, 16)
  assert np.ptp(np.stack(morph).astype(np.float32)) > 0
  reader = imageio.get_reader(os.path.join(renders, "painted.mp4"))
  frames = [f for f in reader]
  reader.close()
  assert len(frames) == 4 and frames[0].shape[:2] == (16, n_styles * 16 + (n_styles - 1) * 2)
  assert "painted_morph.mp4 (style morph along the orbit, painted in 3D)" in first
  summary = json.load(open(os.path.join(out, "summary.json")))
  assert {s["stage"]: s["status"] for s in summary["stages"]} == {
      stage: "ran" for stage in STAGES}
  text = open(os.path.join(out, "summary.txt")).read()
  assert "adain" in text
  peaks = [s["peak_memory_gib"] for s in summary["stages"]]
  assert peaks == sorted(peaks) and 0.1 < peaks[-1] < 24  # a running peak, in GiB
  assert f"peak memory so far {peaks[-1]:.2f} GiB" in text

  mtimes = {n: os.path.getmtime(os.path.join(renders, n)) for n in OUTPUTS}
  assert cli.main(["demo", "--out", out, *TINY]) == 0
  second = capsys.readouterr().out
  assert second.count("already complete, skipped") == 7
  assert {n: os.path.getmtime(os.path.join(renders, n)) for n in OUTPUTS} == mtimes
  summary = json.load(open(os.path.join(out, "summary.json")))
  assert {s["stage"]: s["status"] for s in summary["stages"]} == {
      stage: "skipped" for stage in STAGES}


def test_pipeline_bad_input_is_one_line_error(tmp_path, capsys):
  style = demo.write_styles(str(tmp_path / "styles"), size=32)[0]
  assert cli.main(["pipeline", "--data", str(tmp_path / "nope"), "--styles", style,
                   "--out", str(tmp_path / "o")]) == 2
  assert "nope: no such scene folder" in capsys.readouterr().err
  scene = demo.write_scene(str(tmp_path / "scene"), size=16, n_train=2, n_val=1, progress=False)
  assert cli.main(["pipeline", "--data", scene, "--styles", str(tmp_path / "missing.png"),
                   "--out", str(tmp_path / "o")]) == 2
  assert "missing.png: no such style image" in capsys.readouterr().err
  for option, value, problem in (("--paint-crop", "16", "must be 0 (whole views) or at least 32"),
                                 ("--paint-path-views", "-1", "must be >= 0")):
    assert cli.main(["pipeline", "--data", scene, "--styles", style, "--out",
                     str(tmp_path / "o"), option, value]) == 2
    assert f"{option} {value}: {problem}" in capsys.readouterr().err
  assert not os.path.exists(tmp_path / "o")


def test_pipeline_paint_options_reach_the_painted_runs_config():
  from msnerf_jax.pipeline import settings  # pylint: disable=g-import-not-at-top
  base = settings.paint_config(settings.Settings())
  assert (base.crop, base.path_views) == (0, 24)  # paint train's defaults: earlier records hold
  fern = settings.paint_config(settings.Settings(paint_crop=128, paint_path_views=0))
  assert (fern.crop, fern.path_views) == (128, 0)


@pytest.mark.parametrize("verb", ["pipeline", "demo"])
def test_help_describes_every_option_with_its_default(verb):
  import argparse  # pylint: disable=g-import-not-at-top
  commands = next(a for a in cli.build_parser()._actions  # pylint: disable=protected-access
                  if isinstance(a, argparse._SubParsersAction))  # pylint: disable=protected-access
  parser = commands.choices[verb]
  text = " ".join(parser.format_help().split())
  for action in parser._actions:  # pylint: disable=protected-access
    if action.dest == "help":
      continue
    assert action.help, action.dest
    if not action.required:
      assert f"{' '.join(action.help.split())} (default: " in text, action.dest


def code_blocks(path, language):
  """The fenced code blocks of one language in a Markdown file, in order."""
  import re  # pylint: disable=g-import-not-at-top
  text = open(os.path.join(ROOT, path)).read()
  return re.findall(rf"```{language}\n(.*?)```", text, re.S)


ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
DOCUMENTED = ("README.md", "docs/getting-started.md")


def run_readme_python(demo_out):
  """Runs the README's Python blocks on a finished demo folder (they name runs/demo)."""
  blocks = code_blocks("README.md", "python")
  assert blocks, "the README has a Python example"
  for block in blocks:
    exec(compile(block.replace("runs/demo", demo_out), "README.md", "exec"), {})  # pylint: disable=exec-used


@pytest.mark.parametrize("path", DOCUMENTED)
def test_every_documented_command_parses(path):
  """Every `msnerf ...` line of the README's and the getting-started page's shell blocks is
  a command the CLI accepts as written (verbs and options exist); every `pip install` names
  this checkout, not a registry package."""
  import shlex  # pylint: disable=g-import-not-at-top
  parser = cli.build_parser()
  commands = 0
  for block in code_blocks(path, "bash"):
    for line in block.replace("\\\n", " ").splitlines():
      for command in line.split("#")[0].split("&&"):
        argv = shlex.split(command)
        if argv[:2] == ["pip", "install"]:
          assert any(a.startswith(".") for a in argv[2:]) or "jax[cuda12]" in argv, command
        if argv[:1] == ["msnerf"]:
          parser.parse_args(argv[1:])  # argparse exits (a test failure) on a wrong option
          commands += 1
  assert commands >= 2
