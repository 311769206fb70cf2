"""Shared fixtures: the real data folder (MSNERF_DATA) and small synthetic scenes."""

import json
import os

import numpy as np
import pytest
from PIL import Image

REPO = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
DATA = os.environ.get("MSNERF_DATA", os.path.join(REPO, "..", "shared", "data"))


def data_path(*parts):
  path = os.path.join(DATA, *parts)
  if not os.path.exists(path):
    pytest.skip(f"{path} not available (set MSNERF_DATA)")
  return path


@pytest.fixture
def lego():
  return data_path("nerf_synthetic", "lego")


@pytest.fixture
def fern():
  return data_path("nerf_llff_data", "fern")


def write_blender_scene(folder, n_train=4, n_val=2, size=16, rng=None):
  """A tiny valid Blender-format scene of RGBA PNGs with cameras on a circle."""
  from msnerf_jax.data.blender import pose_spherical  # pylint: disable=g-import-not-at-top
  rng = rng or np.random.default_rng(0)
  os.makedirs(folder, exist_ok=True)
  for split, n in (("train", n_train), ("val", n_val)):
    os.makedirs(os.path.join(folder, split), exist_ok=True)
    frames = []
    for i in range(n):
      rgba = (rng.random((size, size, 4)) * 255).astype(np.uint8)
      Image.fromarray(rgba, "RGBA").save(os.path.join(folder, split, f"r_{i}.png"))
      pose = pose_spherical(360.0 * i / n + (7 if split == "val" else 0), -30.0, 4.0)
      frames.append({"file_path": f"./{split}/r_{i}", "transform_matrix": pose.tolist()})
    with open(os.path.join(folder, f"transforms_{split}.json"), "w") as f:
      json.dump({"camera_angle_x": 0.69, "frames": frames}, f)
  return folder


@pytest.fixture
def tiny_blender(tmp_path):
  return write_blender_scene(str(tmp_path / "scene"))
