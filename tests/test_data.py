"""Scene loading: the real lego and fern scenes, and malformed inputs with clear errors."""

import json
import os

import numpy as np
import pytest
from PIL import Image

from msnerf_jax.core.config import DataConfig
from msnerf_jax.data import images as images_lib
from msnerf_jax.data.scene import load_scene
from msnerf_jax.core.errors import UserError


@pytest.mark.integration
def test_lego_downscaled(lego):
  scene, config = load_scene(DataConfig(path=lego, downscale=8))
  assert config.format == "blender" and config.downscale == 8
  assert scene.images.shape == (109, 100, 100, 3) and scene.images.dtype == np.float32
  assert len(scene.split("train")) == 100 and len(scene.split("val")) == 9
  assert scene.white_background and not scene.ndc and (scene.near, scene.far) == (2.0, 6.0)
  # camera_angle_x of lego is 0.6911: focal = 0.5 * 100 / tan(0.3456) = 138.9
  np.testing.assert_allclose(scene.focal, 138.8889, rtol=1e-4)
  assert scene.images.min() >= 0 and scene.images.max() <= 1
  np.testing.assert_allclose(scene.images[0, 0, 0], 1.0)  # transparent corner -> white
  assert scene.render_poses.shape == (40, 3, 4)
  with pytest.raises(UserError, match="no 'test' split"):
    scene.split("test")


@pytest.mark.integration
def test_fern_factor_8(fern):
  scene, config = load_scene(DataConfig(path=fern))
  assert config.format == "llff" and config.downscale == 8
  assert scene.images.shape == (20, 378, 504, 3)
  assert scene.ndc and list(scene.split("val")) == [0, 8, 16]
  assert len(scene.split("train")) == 17
  np.testing.assert_allclose(scene.focal, 407.5658, rtol=1e-4)  # reference hwf at factor 8
  # Recentred: the average camera is the identity.
  np.testing.assert_allclose(scene.c2w[:, :3, 3].mean(0), 0.0, atol=1e-5)
  assert scene.render_poses.shape == (120, 3, 4)
  rays = scene.camera_rays(scene.c2w[0])
  assert rays["origins"].shape == (378, 504, 3)
  np.testing.assert_allclose(rays["origins"][..., 2], -1.0, atol=1e-4)  # NDC near plane


def test_tiny_blender_scene_and_rgba_composite(tiny_blender):
  scene, _ = load_scene(DataConfig(path=tiny_blender, downscale=2))
  assert scene.images.shape == (6, 8, 8, 3)
  rgba = images_lib.read_image(os.path.join(tiny_blender, "train", "r_0.png"), keep_alpha=True)
  expected = rgba[..., :3] * rgba[..., 3:] + 1 - rgba[..., 3:]
  full, _ = load_scene(DataConfig(path=tiny_blender))
  np.testing.assert_allclose(full.images[0], expected, atol=1e-6)


def _edit_transforms(folder, split, fn):
  path = os.path.join(folder, f"transforms_{split}.json")
  with open(path) as f:
    meta = json.load(f)
  fn(meta)
  with open(path, "w") as f:
    json.dump(meta, f)
  return path


@pytest.mark.parametrize("case, pattern", [
    ("empty folder", "not a scene folder"),
    ("malformed json", "transforms_train.json: malformed JSON"),
    ("missing frames", "missing key 'frames'"),
    ("missing image", "r_1.png: no such file"),
    ("mixed sizes", "r_2.png: image is 4x4, expected 16x16"),
    ("nan pose", "has NaN or inf"),
    ("singular pose", "singular rotation"),
    ("truncated png", "r_0.png: unreadable or truncated"),
    ("bad matrix", "transform_matrix has shape"),
])
def test_bad_blender_inputs(tiny_blender, tmp_path, case, pattern):
  folder = tiny_blender
  if case == "empty folder":
    folder = str(tmp_path / "empty"); os.makedirs(folder)
  elif case == "malformed json":
    with open(os.path.join(folder, "transforms_train.json"), "w") as f:
      f.write('{"camera_angle_x": 0.7, "frames": [')
  elif case == "missing frames":
    _edit_transforms(folder, "train", lambda m: m.pop("frames"))
  elif case == "missing image":
    os.remove(os.path.join(folder, "train", "r_1.png"))
  elif case == "mixed sizes":
    Image.new("RGBA", (4, 4)).save(os.path.join(folder, "train", "r_2.png"))
  elif case == "nan pose":
    _edit_transforms(folder, "val", lambda m: m["frames"][0]["transform_matrix"][0].__setitem__(0, float("nan")))
  elif case == "singular pose":
    _edit_transforms(folder, "train", lambda m: m["frames"][1].__setitem__(
        "transform_matrix", [[0, 0, 0, 1], [0, 0, 0, 1], [0, 0, 0, 1], [0, 0, 0, 1]]))
  elif case == "truncated png":
    path = os.path.join(folder, "train", "r_0.png")
    data = open(path, "rb").read()
    open(path, "wb").write(data[: len(data) // 2])
  elif case == "bad matrix":
    _edit_transforms(folder, "train", lambda m: m["frames"][0].__setitem__("transform_matrix", [[1, 0], [0, 1]]))
  with pytest.raises(UserError, match=pattern):
    load_scene(DataConfig(path=folder))


def _fake_llff(folder, n=3, shape=(n_rows := 9, 12)):
  os.makedirs(os.path.join(folder, "images_8"))
  for i in range(n):
    Image.new("RGB", shape[::-1], (i * 40, 10, 10)).save(os.path.join(folder, "images_8", f"{i}.png"))
  pb = np.zeros((n, 17))
  for i in range(n):
    pose = np.concatenate([np.eye(3), [[0.1 * i], [0.0], [0.0]], [[72], [96], [80]]], 1)
    pb[i, :15] = pose.reshape(-1)
    pb[i, 15:] = [1.0, 10.0]
  np.save(os.path.join(folder, "poses_bounds.npy"), pb)
  return folder


def test_llff_loader_and_bad_poses_bounds(tmp_path):
  folder = _fake_llff(str(tmp_path / "llff"))
  scene, _ = load_scene(DataConfig(path=folder))
  assert scene.images.shape == (3, 9, 12, 3) and scene.ndc
  np.testing.assert_allclose(scene.focal, 80 * 9 / 72)
  np.save(os.path.join(folder, "poses_bounds.npy"), np.zeros((3, 15)))
  with pytest.raises(UserError, match=r"poses_bounds.npy: shape \(3, 15\), expected \[N, 17\]"):
    load_scene(DataConfig(path=folder))
  open(os.path.join(folder, "poses_bounds.npy"), "wb").write(b"not numpy")
  with pytest.raises(UserError, match="not a readable .npy"):
    load_scene(DataConfig(path=folder))


def test_read_image_modes(tmp_path):
  gray = np.arange(12, dtype=np.uint8).reshape(3, 4) * 20
  Image.fromarray(gray, "L").save(tmp_path / "g.png")
  out = images_lib.read_image(str(tmp_path / "g.png"))
  assert out.shape == (3, 4, 3) and np.allclose(out[..., 0], gray / 255.0)
  sixteen = (np.arange(12, dtype=np.uint16).reshape(3, 4) * 5000)
  Image.fromarray(sixteen).save(tmp_path / "s.png")
  out = images_lib.read_image(str(tmp_path / "s.png"))
  np.testing.assert_allclose(out[..., 1], sixteen / 65535.0, atol=1e-6)
  rgba = np.zeros((2, 2, 4), np.uint8); rgba[..., 0] = 255; rgba[0, 0, 3] = 255
  Image.fromarray(rgba, "RGBA").save(tmp_path / "a.png")
  out = images_lib.read_image(str(tmp_path / "a.png"))
  np.testing.assert_allclose(out[0, 0], [1, 0, 0]); np.testing.assert_allclose(out[1, 1], [1, 1, 1])
  (tmp_path / "empty.jpg").write_bytes(b"")
  with pytest.raises(UserError, match="empty file"):
    images_lib.read_image(str(tmp_path / "empty.jpg"))
  (tmp_path / "text.png").write_text("hello")
  with pytest.raises(UserError, match="text.png"):
    images_lib.read_image(str(tmp_path / "text.png"))
  big = Image.new("RGB", (4000, 1000), (0, 128, 255))
  big.save(tmp_path / "big.jpg")
  out = images_lib.read_image(str(tmp_path / "big.jpg"), max_side=500)
  assert max(out.shape[:2]) == 500


def test_an_mp4_is_written_without_jaxs_fork_warning(tmp_path):
  # ffmpeg runs as a subprocess; JAX (its threads started here) warns at every os.fork(),
  # and the pipeline's renders printed that warning once per video.
  import warnings  # pylint: disable=g-import-not-at-top
  import imageio.v2 as imageio  # pylint: disable=g-import-not-at-top
  import jax.numpy as jnp  # pylint: disable=g-import-not-at-top
  from msnerf_jax.data import video  # pylint: disable=g-import-not-at-top
  jnp.ones(3).block_until_ready()
  frames = [np.full((16, 16, 3), 40 * k, np.uint8) for k in range(4)]
  with warnings.catch_warnings(record=True) as caught:
    warnings.simplefilter("always")
    video.write_video(str(tmp_path / "v.mp4"), frames, fps=4)
  assert not [w for w in caught if "fork" in str(w.message)]
  reader = imageio.get_reader(str(tmp_path / "v.mp4"))
  assert len([f for f in reader]) == 4
  reader.close()
