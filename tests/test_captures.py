"""Users' own captures: camera models, COLMAP and transforms.json readers, normalisation,
camera-path files, the real phone captures of MSNERF_DATA, and their bad input."""

import json
import os
import shutil
import struct

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from PIL import Image

from msnerf_jax import cli
from msnerf_jax.nerf import cameras
from msnerf_jax.nerf import rays as rays_lib
from msnerf_jax.core.config import DataConfig
from msnerf_jax.data import camera_path, captures, colmap
from msnerf_jax.data.scene import load_scene

from conftest import data_path
from test_bad_input import run_error

W, H = 40, 30
PHONE = np.array([-0.12, 0.05, 0.004, -0.003, -0.01])  # k1 k2 p1 p2 k3 of a phone lens


# ----------------------------------------------------------------------------- camera model


def test_ray_directions_project_back_to_their_pixels():
  K = cameras.intrinsics(31.5, 29.0, 19.2, 14.7)
  rows, cols = jnp.meshgrid(jnp.arange(H, dtype=jnp.float32), jnp.arange(W, dtype=jnp.float32),
                            indexing="ij")
  for coeffs in (None, jnp.asarray(PHONE, jnp.float32)):
    dirs = cameras.pixel_directions(K, cols, rows, coeffs)
    u, v, depth = cameras.project(K, dirs * 2.5, coeffs)
    np.testing.assert_allclose(u, cols, atol=1e-4)
    np.testing.assert_allclose(v, rows, atol=1e-4)
    np.testing.assert_allclose(depth, 2.5, rtol=1e-6)
  # The lens moves the corner pixels' rays by pixels, so undistortion is not a no-op.
  moved = cameras.pixel_directions(K, cols, rows, jnp.asarray(PHONE)) - \
      cameras.pixel_directions(K, cols, rows)
  assert float(jnp.abs(moved[..., 0]).max()) * 31.5 > 0.5


def test_undistortion_inverts_distortion_and_jits_and_vmaps():
  rng = np.random.default_rng(0)
  x, y = (jnp.asarray(rng.uniform(-0.6, 0.6, 100), jnp.float32) for _ in range(2))
  xd, yd = cameras.distort(x, y, jnp.asarray(PHONE, jnp.float32))
  ux, uy = jax.jit(cameras.undistort)(xd, yd, jnp.asarray(PHONE, jnp.float32))
  np.testing.assert_allclose(ux, x, atol=1e-6)
  np.testing.assert_allclose(uy, y, atol=1e-6)
  # A batch of lenses, one per point (per-view coefficients of training batches).
  coeffs = jnp.asarray(rng.uniform(-0.05, 0.05, (100, 5)), jnp.float32)
  bx, by = jax.vmap(cameras.distort)(x, y, coeffs)
  vx, vy = jax.vmap(cameras.undistort)(bx, by, coeffs)
  np.testing.assert_allclose(vx, x, atol=1e-6)
  np.testing.assert_allclose(vy, y, atol=1e-6)


def test_pixel_rays_with_per_view_cameras_equal_whole_image_rays():
  rng = np.random.default_rng(1)
  Ks = np.stack([cameras.intrinsics(30 + i, 28 + i, 19.5, 14.5) for i in range(3)])
  coeffs = np.stack([PHONE * (i + 1) / 3 for i in range(3)]).astype(np.float32)
  poses = np.stack([np.eye(4)[:3] + rng.normal(0, 0.1, (3, 4)) for _ in range(3)])
  which = jnp.asarray([0, 2, 1, 2])
  rows, cols = jnp.asarray([0, 5, 29, 17]), jnp.asarray([39, 0, 13, 22])
  o, d = rays_lib.pixel_rays(jnp.asarray(Ks)[which], jnp.asarray(poses)[which], rows, cols,
                             jnp.asarray(coeffs)[which])
  for n in range(4):
    v = int(which[n])
    fo, fd = rays_lib.get_rays(H, W, Ks[v], poses[v], coeffs[v])
    np.testing.assert_allclose(d[n], fd[int(rows[n]), int(cols[n])], rtol=1e-5, atol=1e-6)
    np.testing.assert_allclose(o[n], fo[int(rows[n]), int(cols[n])], atol=1e-6)


# ----------------------------------------------------------------------------- COLMAP


def rotation_to_qvec(R):
  """(w, x, y, z) of a rotation matrix (test-side inverse of colmap.qvec_to_rotation)."""
  w = np.sqrt(max(0.0, 1 + np.trace(R))) / 2
  x = np.copysign(np.sqrt(max(0.0, 1 + R[0, 0] - R[1, 1] - R[2, 2])) / 2, R[2, 1] - R[1, 2])
  y = np.copysign(np.sqrt(max(0.0, 1 - R[0, 0] + R[1, 1] - R[2, 2])) / 2, R[0, 2] - R[2, 0])
  z = np.copysign(np.sqrt(max(0.0, 1 - R[0, 0] - R[1, 1] + R[2, 2])) / 2, R[1, 0] - R[0, 1])
  return np.array([w, x, y, z])


def look_at(position, target=(0.0, 0.0, 0.0), up=(0.0, 0.0, 1.0)):
  """OpenGL camera-to-world [3, 4] at `position` looking at `target`."""
  back = np.asarray(position, float) - target
  back /= np.linalg.norm(back)
  right = np.cross(up, back)
  right /= np.linalg.norm(right)
  return np.stack([right, np.cross(back, right), back, np.asarray(position, float)], 1)


def orbit_poses(n=6, radius=3.0):
  return [look_at((radius * np.cos(a), radius * np.sin(a), 1.0 + 0.2 * np.sin(3 * a)))
          for a in np.linspace(0, 2 * np.pi, n, endpoint=False)]


def write_images(folder, names, rng):
  os.makedirs(folder, exist_ok=True)
  for name in names:
    Image.fromarray(rng.integers(0, 255, (H, W, 3), dtype=np.uint8)).save(
        os.path.join(folder, name))


def write_colmap(folder, cams, images, points, binary=True, model_ids=None):
  """A COLMAP model: cams {id: (model name, w, h, params)}; images [(id, c2w OpenGL [3, 4],
  camera id, name)]; points [(xyz, [image ids])]."""
  os.makedirs(folder, exist_ok=True)
  w2c = []
  for _, c2w, _, _ in images:
    R_cv = c2w[:, :3] * np.array([1, -1, -1])  # OpenGL -> OpenCV camera axes
    R = R_cv.T
    w2c.append((rotation_to_qvec(R), -R @ c2w[:, 3]))
  if binary:
    with open(os.path.join(folder, "cameras.bin"), "wb") as f:
      f.write(struct.pack("<Q", len(cams)))
      for cid, (model, w, h, params) in cams.items():
        model_id = (model_ids or {}).get(cid, colmap.MODEL_IDS.get(model, (99,))[0])
        f.write(struct.pack("<iiQQ", cid, model_id, w, h) + struct.pack(f"<{len(params)}d",
                                                                          *params))
    with open(os.path.join(folder, "images.bin"), "wb") as f:
      f.write(struct.pack("<Q", len(images)))
      for (iid, _, cid, name), (q, t) in zip(images, w2c):
        f.write(struct.pack("<I7dI", iid, *q, *t, cid) + name.encode() + b"\0")
        seen = [k for k, (_, ids) in enumerate(points) if iid in ids]
        f.write(struct.pack("<Q", len(seen)))
        for k in seen:
          f.write(struct.pack("<ddq", 1.0, 2.0, k + 1))
    with open(os.path.join(folder, "points3D.bin"), "wb") as f:
      f.write(struct.pack("<Q", len(points)))
      for k, (xyz, ids) in enumerate(points):
        f.write(struct.pack("<Q3d3BdQ", k + 1, *xyz, 200, 100, 50, 0.5, len(ids)))
        for iid in ids:
          f.write(struct.pack("<ii", iid, 0))
  else:
    with open(os.path.join(folder, "cameras.txt"), "w") as f:
      f.write("# Camera list\n")
      for cid, (model, w, h, params) in cams.items():
        f.write(f"{cid} {model} {w} {h} " + " ".join(repr(float(p)) for p in params) + "\n")
    with open(os.path.join(folder, "images.txt"), "w") as f:
      f.write("# Image list with two lines of data per image\n")
      for (iid, _, cid, name), (q, t) in zip(images, w2c):
        f.write(f"{iid} " + " ".join(repr(float(v)) for v in [*q, *t]) + f" {cid} {name}\n")
        seen = [k for k, (_, ids) in enumerate(points) if iid in ids]
        f.write(" ".join(f"1.0 2.0 {k + 1}" for k in seen) + "\n")
    with open(os.path.join(folder, "points3D.txt"), "w") as f:
      for k, (xyz, ids) in enumerate(points):
        f.write(f"{k + 1} " + " ".join(repr(float(v)) for v in xyz) + " 200 100 50 0.5 "
                + " ".join(f"{i} 0" for i in ids) + "\n")


def colmap_capture(root, binary=True, rng=None):
  """A 6-image object capture with three camera models; returns (folder, cams, images)."""
  rng = rng or np.random.default_rng(0)
  cams = {1: ("SIMPLE_PINHOLE", W, H, (33.0, 20.0, 15.0)),
          2: ("OPENCV", W, H, (34.0, 32.5, 19.5, 15.5, *PHONE[:4])),
          3: ("SIMPLE_RADIAL", W, H, (31.0, 20.5, 14.5, -0.08))}
  names = [f"{n}.png" for n in (1, 10, 2, 3, 4, 5)]  # not zero-padded, as the cup's
  images = [(i + 1, c2w, 1 + i % 3, names[i]) for i, c2w in enumerate(orbit_poses())]
  points = [(rng.normal(0, 0.3, 3), [1 + j for j in range(6) if (k + j) % 4]) for k in range(40)]
  write_colmap(os.path.join(root, "sparse", "0"), cams, images, points, binary)
  write_images(os.path.join(root, "images"), names, rng)
  return str(root), cams, images


@pytest.mark.parametrize("binary", [True, False])
def test_colmap_model_reads_back_exactly(tmp_path, binary):
  folder, cams, images = colmap_capture(tmp_path, binary)
  model = colmap.read_model(os.path.join(folder, "sparse", "0"))
  assert {cid: (c.model, c.width, c.height, c.params) for cid, c in model.cameras.items()} == \
      {cid: (m, w, h, tuple(float(p) for p in params)) for cid, (m, w, h, params) in cams.items()}
  assert [(im.id, im.camera_id, im.name) for im in model.images] == \
      [(i, c, n) for i, _, c, n in images]
  for image, (_, c2w, _, _) in zip(model.images, images):
    np.testing.assert_allclose(colmap.opengl_c2w(image), c2w, atol=1e-12)
  assert len(model.points) == 40 and all(len(t) for t in model.tracks)


def test_colmap_capture_has_per_view_intrinsics_and_lenses(tmp_path):
  folder, cams, _ = colmap_capture(tmp_path)
  scene, data = load_scene(DataConfig(path=folder))
  assert data.format == "colmap" and data.layout == "object" and data.downscale == 1
  names = [os.path.basename(p) for p in scene.image_paths]
  assert names == sorted(names) == ["1.png", "10.png", "2.png", "3.png", "4.png", "5.png"]
  # view 0 is 1.png (camera 1: SIMPLE_PINHOLE), view 1 is 10.png (image 2: camera 2, OPENCV).
  np.testing.assert_allclose(scene.intrinsics[0], cameras.intrinsics(33, 33, 19.5, 14.5))
  np.testing.assert_allclose(scene.intrinsics[1], cameras.intrinsics(34, 32.5, 19, 15))
  np.testing.assert_allclose(scene.distortion[1], np.r_[PHONE[:4], 0], rtol=1e-6)
  np.testing.assert_allclose(scene.distortion[0], 0)
  np.testing.assert_allclose(scene.distortion[2], [-0.08, 0, 0, 0, 0], rtol=1e-6)
  # A view's rays are its own camera's (intrinsics and lens), through its pose.
  rays = scene.camera_rays(1)
  _, d = rays_lib.get_rays(H, W, scene.intrinsics[1], scene.c2w[1], scene.distortion[1])
  np.testing.assert_allclose(rays["directions"], d)


def test_cup_colmap_model_reproduces_its_poses_bounds():
  folder = data_path("captures", "cup")
  capture = captures.read_colmap_capture(folder)
  pb = np.load(os.path.join(folder, "poses_bounds.npy"))
  poses = pb[:, :15].reshape(-1, 3, 5)
  opengl = np.concatenate([poses[:, :, 1:2], -poses[:, :, 0:1], poses[:, :, 2:4]], 2)
  np.testing.assert_allclose(capture.c2w, opengl, atol=1e-6)
  np.testing.assert_allclose(capture.bounds, pb[:, 15:], atol=1e-6)
  assert abs(capture.cameras[0]["fx"] - poses[0, 2, 4]) < 1e-6
  focals = np.array([c["fx"] for c in capture.cameras])
  assert focals.max() / focals.min() > 1.1  # the per-image focals LLFF's file drops


def test_cup_colmap_and_llff_forms_give_the_same_rays():
  folder = data_path("captures", "cup")
  llff, _ = load_scene(DataConfig(path=folder, format="llff", downscale=4))
  model, data = load_scene(DataConfig(path=folder, format="colmap", downscale=4,
                                      layout="forward-facing"))
  assert data.layout == "forward-facing" and model.ndc and llff.ndc
  np.testing.assert_array_equal(model.images, llff.images)  # both read images_4/
  np.testing.assert_allclose(model.c2w, llff.c2w, atol=1e-5)
  assert (model.near, model.far) == pytest.approx((llff.near, llff.far), rel=1e-6)
  assert model.focal == pytest.approx(llff.focal, rel=1e-6)
  # The only difference of view 0's camera is COLMAP's pixel convention (centres at +0.5),
  # which the reference code's LLFF loader ignores: half a pixel of principal point.
  np.testing.assert_allclose(model.intrinsics[0][:2, 2] + 0.5, llff.K[:2, 2])
  shifted = model.intrinsics[0] + np.array([[0, 0, 0.5], [0, 0, 0.5], [0, 0, 0]], np.float32)
  rays = llff.camera_rays(0)
  o, d = rays_lib.get_rays(llff.height, llff.width, shifted, model.c2w[0])
  mine = model.bundle(o, d)
  for key in ("origins", "directions", "viewdirs"):
    np.testing.assert_allclose(mine[key], rays[key], atol=1e-5)


# ----------------------------------------------------------------------------- transforms.json


def write_transforms(folder, meta, frames):
  os.makedirs(folder, exist_ok=True)
  with open(os.path.join(folder, "transforms.json"), "w") as f:
    json.dump({**meta, "frames": frames}, f)
  return str(folder)


def transforms_frames(paths, poses):
  return [{"file_path": p, "transform_matrix": np.vstack([c2w, [0, 0, 0, 1]]).tolist()}
          for p, c2w in zip(paths, poses)]


def test_nerfstudio_and_instant_ngp_files_give_the_same_rays(tmp_path):
  rng = np.random.default_rng(3)
  poses = orbit_poses(8)
  names = [f"frame_{i:05d}.png" for i in range(8)]
  fx, fy, cx, cy = 33.0, 31.0, 20.3, 14.8
  lens = dict(k1=PHONE[0], k2=PHONE[1], p1=PHONE[2], p2=PHONE[3])
  ns = write_transforms(tmp_path / "ns", dict(camera_model="OPENCV", fl_x=fx, fl_y=fy, cx=cx,
                                               cy=cy, w=W, h=H, **lens),
                        transforms_frames([f"images/{n}" for n in names], poses))
  write_images(os.path.join(ns, "images"), names, rng)
  angle_x, angle_y = 2 * np.arctan(W / (2 * fx)), 2 * np.arctan(H / (2 * fy))
  ngp = write_transforms(tmp_path / "ngp", dict(camera_angle_x=angle_x, camera_angle_y=angle_y,
                                                 cx=cx, cy=cy, k3=0, k4=0, is_fisheye=False,
                                                 aabb_scale=16, **lens),
                         transforms_frames([f"./shots/{n[:-4]}" for n in names][::-1],
                                           poses[::-1]))
  shutil.copytree(os.path.join(ns, "images"), os.path.join(ngp, "shots"))
  a, data_a = load_scene(DataConfig(path=ns))
  b, data_b = load_scene(DataConfig(path=ngp))
  assert data_a.format == data_b.format == "transforms"
  np.testing.assert_array_equal(a.images, b.images)
  for view in range(8):
    ra, rb = a.camera_rays(view), b.camera_rays(view)
    for key in ("origins", "directions"):
      np.testing.assert_allclose(ra[key], rb[key], atol=1e-5)
  assert a.distortion is not None and a.splits["val"].tolist() == [0]


def test_per_frame_intrinsics_override_the_files(tmp_path):
  rng = np.random.default_rng(4)
  poses = orbit_poses(4)
  frames = transforms_frames([f"images/{i}.png" for i in range(4)], poses)
  frames[2].update(fl_x=40.0, fl_y=41.0, cx=18.0, k1=0.1)
  folder = write_transforms(tmp_path, dict(fl_x=30.0, cx=W / 2, cy=H / 2, w=W, h=H,
                                           camera_model="OPENCV"), frames)
  write_images(os.path.join(folder, "images"), [f"{i}.png" for i in range(4)], rng)
  scene, _ = load_scene(DataConfig(path=folder))
  np.testing.assert_allclose(scene.intrinsics[2], cameras.intrinsics(40, 41, 17.5, 14.5))
  np.testing.assert_allclose(scene.intrinsics[1], cameras.intrinsics(30, 30, 19.5, 14.5))
  np.testing.assert_allclose(scene.distortion[:, 0], [0, 0, 0.1, 0], atol=1e-7)


def test_downscaled_folders_and_box_downscaling_keep_the_cameras(tmp_path):
  rng = np.random.default_rng(5)
  poses = orbit_poses(4)
  frames = transforms_frames([f"images/{i}.png" for i in range(4)], poses)
  folder = write_transforms(tmp_path, dict(fl_x=30.0, cx=21.0, cy=14.0, w=W, h=H), frames)
  write_images(os.path.join(folder, "images"), [f"{i}.png" for i in range(4)], rng)
  reduced, data = load_scene(DataConfig(path=folder, downscale=2))
  assert reduced.images.shape[1:3] == (H // 2, W // 2) and data.downscale == 2
  np.testing.assert_allclose(reduced.K, cameras.intrinsics(15, 15, 10.0, 6.5))
  os.makedirs(os.path.join(folder, "images_2"))
  for i in range(4):  # nerfstudio's images_2: a copy at half size, here in another colour
    Image.new("RGB", (W // 2, H // 2), (0, 0, 255)).save(os.path.join(folder, "images_2",
                                                                       f"{i}.png"))
  copy, _ = load_scene(DataConfig(path=folder, downscale=2))
  np.testing.assert_allclose(copy.images[..., 2], 1.0)
  np.testing.assert_allclose(copy.K, reduced.K)


# ----------------------------------------------------------------------------- layouts


def test_object_layout_centres_the_cameras_focus_and_orbits_it(tmp_path):
  rng = np.random.default_rng(6)
  shift, scale = np.array([5.0, -2.0, 7.0]), 2.5
  poses = [np.concatenate([c2w[:, :3], scale * c2w[:, 3:] + shift[:, None]], 1)
           for c2w in orbit_poses(8)]
  frames = transforms_frames([f"images/{i}.png" for i in range(8)], poses)
  folder = write_transforms(tmp_path, dict(fl_x=30.0, w=W, h=H), frames)
  write_images(os.path.join(folder, "images"), [f"{i}.png" for i in range(8)], rng)
  scene, data = load_scene(DataConfig(path=folder))
  assert data.layout == "object" and not scene.ndc and "object" in scene.layout
  distance = np.linalg.norm(scene.c2w[:, :, 3], axis=1)
  assert np.median(distance) == pytest.approx(4.0, rel=1e-5)
  # Every camera and every path camera looks at the origin; up is +z.
  for pose in list(scene.c2w) + list(scene.render_poses):
    forward = -pose[:, 2]
    miss = pose[:, 3] - (pose[:, 3] @ forward) * forward
    assert np.linalg.norm(miss) < 1e-4
  assert scene.c2w[:, 2, 1].mean() > 0.9
  assert scene.near < distance.min() - 1 and scene.far > distance.max() + 1


def test_forward_facing_captures_get_ndc(tmp_path):
  rng = np.random.default_rng(7)
  poses = [look_at((x, y, 4.0), (0, 0, 0), (0, 1, 0)) for x in (-0.5, 0, 0.5) for y in (-0.3, 0.3)]
  frames = transforms_frames([f"images/{i}.png" for i in range(6)], poses)
  folder = write_transforms(tmp_path, dict(fl_x=30.0, w=W, h=H), frames)
  write_images(os.path.join(folder, "images"), [f"{i}.png" for i in range(6)], rng)
  scene, data = load_scene(DataConfig(path=folder))
  assert data.layout == "forward-facing" and scene.ndc and len(scene.render_poses) == 120
  object_scene, data = load_scene(DataConfig(path=folder, layout="object"))
  assert data.layout == "object" and not object_scene.ndc


def test_real_captures_load_with_their_layout():
  fruit, data = load_scene(DataConfig(path=data_path("captures", "fruit")))
  assert (data.format, data.layout, data.downscale) == ("transforms", "object", 4)
  assert fruit.images.shape == (81, 202, 152, 3) and fruit.distortion is not None
  assert fruit.splits["val"].tolist() == list(range(0, 81, 8))
  cup, data = load_scene(DataConfig(path=data_path("captures", "cup"), format="colmap"))
  assert (data.layout, data.downscale) == ("object", 2) and cup.images.shape[1:3] == (300, 400)
  assert cup.Ks is not None and cup.distortion is None


# ----------------------------------------------------------------------------- camera paths


def test_camera_path_files_round_trip(tmp_path):
  poses = np.stack(orbit_poses(5)).astype(np.float32)
  K = cameras.intrinsics(30.0, 30.0, W / 2 - 0.5, H / 2 - 0.5)
  path = str(tmp_path / "camera_path.json")
  camera_path.write_camera_path(path, poses, K, H, W, fps=12)
  read, fps = camera_path.read_camera_path(path)
  assert fps == 12 and len(read) == 5
  for camera, c2w in zip(read, poses):
    np.testing.assert_allclose(camera.c2w, c2w, atol=1e-6)
    np.testing.assert_allclose(camera.K, K, rtol=1e-5)
    assert (camera.height, camera.width) == (H, W)


def test_render_a_50_frame_camera_path_in_one_command(tmp_path, tiny_blender, capsys):
  from conftest import untrained_nerf_run  # pylint: disable=g-import-not-at-top
  from test_train_nerf import TINY  # pylint: disable=g-import-not-at-top
  run = untrained_nerf_run(str(tmp_path / "run"), DataConfig(path=str(tiny_blender)), TINY)
  path = str(tmp_path / "path.json")
  assert cli.main(["nerf", "camera-path", "--run", run, "--out", path]) == 0
  scene = load_scene(DataConfig(path=str(tiny_blender)))[0]
  written, _ = camera_path.read_camera_path(path)
  np.testing.assert_allclose(np.stack([c.c2w for c in written]), scene.render_poses, atol=1e-6)
  # A user's own flythrough: 50 cameras at another size.
  poses = [look_at((4 * np.cos(a), 4 * np.sin(a), 2.0)) for a in np.linspace(0, np.pi, 50)]
  camera_path.write_camera_path(path, poses, cameras.intrinsics(14, 14, 6, 4), 8, 12, fps=10)
  assert cli.main(["nerf", "render", "--run", run, "--out", str(tmp_path / "fly"),
                   "--camera-path", path]) == 0
  assert "50 of 12x8" in capsys.readouterr().out
  import imageio_ffmpeg  # pylint: disable=g-import-not-at-top
  assert imageio_ffmpeg.count_frames_and_secs(str(tmp_path / "fly.mp4")) == (50, 5.0)


# ----------------------------------------------------------------------------- bad input


def _bad_transforms(tmp_path, meta_update=None, frame_update=None, pose=None):
  rng = np.random.default_rng(9)
  frames = transforms_frames([f"images/{i}.png" for i in range(4)], orbit_poses(4))
  if frame_update:
    frames[1].update(frame_update)
  if pose is not None:
    frames[2]["transform_matrix"] = pose
  meta = dict(fl_x=30.0, w=W, h=H)
  meta.update(meta_update or {})
  meta = {k: v for k, v in meta.items() if v is not None}
  folder = write_transforms(tmp_path / "scene", meta, frames)
  write_images(os.path.join(folder, "images"), [f"{i}.png" for i in range(4)], rng)
  return folder


def _skewed():
  pose = np.vstack([orbit_poses(4)[2], [0, 0, 0, 1]])
  pose[:3, 0] *= 1.2
  return pose.tolist()


@pytest.mark.parametrize("case,needles", [
    ("missing_image", ("images/9.png: missing", "transforms.json")),
    ("no_focal", ("transforms.json", "no focal length")),
    ("zero_focal", ("transforms.json", "focal length 0")),
    ("negative_focal", ("frame 1", "must be positive")),
    ("skewed_rotation", ("transforms.json", "2.png", "not orthonormal")),
    ("fisheye", ("transforms.json", "OPENCV_FISHEYE is not supported")),
])
def test_bad_transforms_files(tmp_path, capsys, case, needles):
  kwargs = {
      "missing_image": dict(frame_update={"file_path": "images/9.png"}),
      "no_focal": dict(meta_update={"fl_x": None}),
      "zero_focal": dict(meta_update={"fl_x": 0}),
      "negative_focal": dict(frame_update={"fl_y": -3.0}),
      "skewed_rotation": dict(pose=_skewed()),
      "fisheye": dict(meta_update={"camera_model": "OPENCV_FISHEYE"}),
  }[case]
  folder = _bad_transforms(tmp_path, **kwargs)
  out = tmp_path / "run"
  run_error(capsys, ["nerf", "train", "--data", folder, "--out", out, "--steps", "2"], *needles)
  assert not out.exists()


def _truncate(path):
  with open(path, "rb") as f:
    data = f.read()
  with open(path, "wb") as f:
    f.write(data[:len(data) - 7])


@pytest.mark.parametrize("case,needles", [
    ("unknown_model", ("cameras.bin", "unknown camera model id 42")),
    ("fisheye_model", ("camera 1", "OPENCV_FISHEYE is not supported")),
    ("unregistered", ("images/7.png", "not registered")),
    ("truncated_images", ("images.bin", "truncated")),
    ("truncated_points", ("points3D.bin", "truncated")),
    ("missing_image", ("images/10.png", "missing")),
])
def test_bad_colmap_models(tmp_path, capsys, case, needles):
  folder, cams, images = colmap_capture(tmp_path / "scene")
  sparse = os.path.join(folder, "sparse", "0")
  if case in ("unknown_model", "fisheye_model"):
    cams = dict(cams)
    cams[1] = ("OPENCV_FISHEYE", W, H, (33.0, 33.0, 20.0, 15.0, 0, 0, 0, 0))
    write_colmap(sparse, cams, images, [((0, 0, 0), [1, 2, 3, 4, 5, 6])],
                 model_ids={1: 42} if case == "unknown_model" else None)
  elif case == "unregistered":
    write_images(os.path.join(folder, "images"), ["7.png"], np.random.default_rng(0))
  elif case == "truncated_images":
    _truncate(os.path.join(sparse, "images.bin"))
  elif case == "truncated_points":
    _truncate(os.path.join(sparse, "points3D.bin"))
  elif case == "missing_image":
    os.remove(os.path.join(folder, "images", "10.png"))
  out = tmp_path / "run"
  run_error(capsys, ["nerf", "train", "--data", folder, "--out", out, "--steps", "2"], *needles)
  assert not out.exists()


@pytest.mark.parametrize("edit,needles", [
    (lambda m: m.update(camera_path=[]), ("is empty",)),
    (lambda m: m.update(camera_type="fisheye"), ("camera_type 'fisheye'",)),
    (lambda m: m["camera_path"][1].update(fov=0), ("camera_path[1]", "fov")),
    (lambda m: m["camera_path"][0].update(camera_to_world=[1, 2]), ("16 finite numbers",)),
    (lambda m: m.pop("render_width"), ("render_width",)),
])
def test_bad_camera_path_files(tmp_path, capsys, tiny_blender, edit, needles):
  from conftest import untrained_nerf_run  # pylint: disable=g-import-not-at-top
  from test_train_nerf import TINY  # pylint: disable=g-import-not-at-top
  run = untrained_nerf_run(str(tmp_path / "run"), DataConfig(path=str(tiny_blender)), TINY)
  path = str(tmp_path / "path.json")
  camera_path.write_camera_path(path, np.stack(orbit_poses(3)), cameras.intrinsics(
      20, 20, 8, 8), 16, 16)
  meta = json.load(open(path))
  edit(meta)
  with open(path, "w") as f:
    json.dump(meta, f)
  run_error(capsys, ["nerf", "render", "--run", run, "--out", tmp_path / "fly",
                     "--camera-path", path], "path.json", *needles)
  assert not (tmp_path / "fly.mp4").exists()


def test_nerfstudio_split_lists_are_used(tmp_path):
  rng = np.random.default_rng(10)
  frames = transforms_frames([f"images/{i}.png" for i in range(5)], orbit_poses(5))
  folder = write_transforms(tmp_path, dict(fl_x=30.0, w=W, h=H,
                                           train_filenames=[f"images/{i}.png" for i in (0, 1, 3)],
                                           val_filenames=["./images/4.png", "images/2.png"]),
                            frames)
  write_images(os.path.join(folder, "images"), [f"{i}.png" for i in range(5)], rng)
  scene, _ = load_scene(DataConfig(path=folder))
  assert scene.splits["train"].tolist() == [0, 1, 3]
  assert scene.splits["val"].tolist() == scene.splits["test"].tolist() == [2, 4]


def test_partial_captures_get_a_path_along_their_arc():
  azimuths = np.radians([100, 120, 150, 170, 200])
  start, arc = captures.covered_arc(azimuths)
  assert np.degrees(start) == pytest.approx(100) and np.degrees(arc) == pytest.approx(100)
  assert captures.covered_arc(np.radians(np.arange(0, 360, 45)))[1] == pytest.approx(2 * np.pi)
  poses = np.stack([look_at((3 * np.cos(a), 3 * np.sin(a), 1.0)) for a in azimuths])
  path = captures.normalise(poses, None, "object")[4]
  seen = np.degrees(np.arctan2(path[:, 1, 3], path[:, 0, 3]))
  centre = np.degrees(np.arctan2(np.sin(azimuths).mean(), np.cos(azimuths).mean()))
  assert np.abs((seen - centre + 180) % 360 - 180).max() < 60  # within the 100-degree arc
