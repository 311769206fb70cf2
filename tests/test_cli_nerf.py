"""`msnerf nerf ...` end to end on the real lego scene, and one-line errors with exit code 2."""

import json
import os
import subprocess
import sys

import pytest

from msnerf_jax.cli import main


def msnerf(*args, timeout=900):
  return subprocess.run([sys.executable, "-m", "msnerf_jax", *args], capture_output=True,
                        text=True, timeout=timeout)


def assert_one_line_error(result, pattern):
  assert result.returncode == 2, result.stdout + result.stderr
  lines = [l for l in result.stderr.strip().splitlines() if l.strip()]
  assert len(lines) == 1 and lines[0].startswith("msnerf: error:"), result.stderr
  assert "Traceback" not in result.stderr
  import re  # pylint: disable=g-import-not-at-top
  assert re.search(pattern, lines[0]), lines[0]


@pytest.mark.slow
@pytest.mark.integration
def test_train_eval_render_lego(lego, tmp_path):
  run = str(tmp_path / "run")
  r = msnerf("nerf", "train", "--data", lego, "--out", run, "--downscale", "16", "--steps", "2",
             "--batch-rays", "256")
  assert r.returncode == 0, r.stderr[-3000:]
  assert "NeRF training done" in r.stdout
  assert os.listdir(os.path.join(run, "checkpoints")) == ["2"]
  r = msnerf("nerf", "eval", "--run", run)
  assert r.returncode == 0, r.stderr[-3000:]
  metrics = json.load(open(os.path.join(run, "eval_val", "metrics.json")))
  assert len(metrics["views"]) == 9 and metrics["step"] == 2
  assert 3 < metrics["mean"]["psnr"] < 40
  assert len([f for f in os.listdir(os.path.join(run, "eval_val")) if f.endswith(".png")]) == 9
  r = msnerf("nerf", "render", "--run", run, "--out", str(tmp_path / "video"), "--frames", "2")
  assert r.returncode == 0, r.stderr[-3000:]
  for name in ("video.mp4", "video.gif", "video_depth.mp4", "video_depth.gif"):
    assert os.path.getsize(tmp_path / name) > 500


@pytest.mark.slow
def test_resume_and_refuse_another_config(tiny_blender, tmp_path):
  run = str(tmp_path / "run")
  common = ["nerf", "train", "--data", tiny_blender, "--out", run, "--preset", "cpu",
            "--batch-rays", "64", "--checkpoint-every", "2"]
  r = msnerf(*common, "--steps", "2")
  assert r.returncode == 0, r.stderr[-3000:]
  r = msnerf(*common, "--steps", "4")  # same command, more steps: resumes
  assert r.returncode == 0 and "resumed from 2" in r.stdout, r.stdout + r.stderr[-2000:]
  assert sorted(os.listdir(os.path.join(run, "checkpoints"))) == ["2", "4"]
  r = msnerf("nerf", "train", "--data", tiny_blender, "--out", run, "--preset", "cpu",
             "--batch-rays", "128")
  assert_one_line_error(r, "another config .*batch_rays")
  assert sorted(os.listdir(os.path.join(run, "checkpoints"))) == ["2", "4"]


@pytest.mark.slow  # 20 s; the flags' parsing is also covered by test_cli_config
def test_architecture_flags_reach_the_config_and_the_model(tiny_blender, tmp_path):
  run = str(tmp_path / "run")
  r = msnerf("nerf", "train", "--data", tiny_blender, "--out", run, "--preset", "cpu",
             "--batch-rays", "32", "--steps", "1", "--net-depth", "4", "--net-width", "24", "--n-coarse", "4",
             "--n-fine", "6")
  assert r.returncode == 0, r.stderr[-3000:]
  config = json.load(open(os.path.join(run, "run.json")))["config"]
  assert (config["net_depth"], config["net_width"], config["skip_layer"]) == (4, 24, 2)
  assert (config["n_coarse"], config["n_fine"]) == (4, 6)
  from msnerf_jax import load_run  # pylint: disable=g-import-not-at-top
  trunk = load_run(run).params["coarse"]["trunk"]
  kernels = sorted((k, v["kernel"].shape) for k, v in trunk.items() if k.startswith("point_"))
  # The skip connection sits in the middle: point_3 sees the encoded input again.
  assert kernels == [("point_0", (63, 24)), ("point_1", (24, 24)), ("point_2", (24, 24)),
                     ("point_3", (63 + 24, 24))]
  assert trunk["view"]["kernel"].shape == (24 + 27, 12)


def test_bad_inputs_exit_2(tmp_path, tiny_blender):
  (tmp_path / "file").write_text("x")
  cases = [
      (["nerf", "train", "--data", str(tmp_path / "nope"), "--out", str(tmp_path / "r")],
       "no such scene folder"),
      (["nerf", "train", "--data", tiny_blender, "--out", str(tmp_path / "file")], "is a file"),
      (["nerf", "eval", "--run", str(tmp_path / "file")], "is a file"),
      (["nerf", "eval", "--run", str(tmp_path)], "run.json: missing"),
      (["nerf", "train", "--data", str(tmp_path), "--out", str(tmp_path / "r")], "not a scene folder"),
  ]
  for argv, pattern in cases:
    r = msnerf(*argv)
    assert_one_line_error(r, pattern)


def test_help_describes_every_option(capsys):
  for argv in (["--help"], ["nerf", "train", "--help"], ["nerf", "eval", "--help"],
               ["nerf", "render", "--help"]):
    with pytest.raises(SystemExit) as e:
      main(argv)
    assert e.value.code == 0
  out = capsys.readouterr().out
  assert "--preset" in out and "default: fast" in out and "--split" in out
