"""The hand-written COLMAP reader (msnerf_jax.data.colmap) against COLMAP's own library,
pycolmap (issue 46): the same cameras, poses, intrinsics, lens coefficients and points on the
real cup capture, on the fruit capture's lens and poses written as a COLMAP model, and on
models pycolmap writes (binary and text) with every camera model COLMAP has; the loader's
undistorted pixels are COLMAP's (Camera.cam_from_img / img_from_cam). Measured numbers:
docs/results/colmap_pycolmap.md."""

import json
import os

import numpy as np
import pytest
from PIL import Image

from msnerf_jax.core.config import DataConfig
from msnerf_jax.core.errors import UserError
from msnerf_jax.data import captures, colmap
from msnerf_jax.data.scene import load_scene
from msnerf_jax.nerf import cameras

from conftest import data_path

pycolmap = pytest.importorskip(
    "pycolmap", reason="pycolmap (COLMAP's Python library, in the `test` extra) is not "
    "installed: nothing to compare the COLMAP reader with")
if not hasattr(pycolmap.Reconstruction, "add_camera_with_trivial_rig"):
  pytest.skip(f"pycolmap {pycolmap.__version__} predates COLMAP 3.12's rigs and frames, the API "
              "this test writes models and reads poses with (Image.cam_from_world())",
              allow_module_level=True)

POSE_TOL = 1e-6  # cameras, poses, intrinsics, lens coefficients
PIXEL_TOL = 1e-3  # undistorted / projected pixel positions, in pixels
W, H = 640, 480
# The reader's SUPPORTED camera models with phone-like lenses (pixel convention: COLMAP's).
SUPPORTED = {
    "SIMPLE_PINHOLE": [520.0, 321.3, 239.1],
    "PINHOLE": [520.0, 505.5, 321.3, 239.1],
    "SIMPLE_RADIAL": [520.0, 321.3, 239.1, -0.05],
    "RADIAL": [515.0, 318.2, 242.6, -0.06, 0.012],
    "OPENCV": [520.0, 505.5, 321.3, 239.1, -0.08, 0.03, 0.002, -0.001],
    "FULL_OPENCV": [510.0, 512.5, 322.8, 237.4, -0.09, 0.04, -0.0015, 0.002, -0.006,
                    0.0, 0.0, 0.0],
}
# The other camera models of COLMAP (4.x numbers them 0-17): read, then refused by
# camera_intrinsics. Parameters as pycolmap's defaults for an f = 300 camera.
UNSUPPORTED = [name for name in pycolmap.CameraModelId.__members__
               if name not in SUPPORTED and name != "INVALID"]


def _model_id(name):
  return getattr(pycolmap.CameraModelId, name)


def _pycolmap_camera(camera_id, name, params, width=W, height=H):
  if params is None:
    return pycolmap.Camera.create_from_model_id(camera_id, _model_id(name), 300.0, width,
                                                height)
  return pycolmap.Camera(camera_id=camera_id, model=_model_id(name), width=width,
                         height=height, params=params)


def _look_at_world(centre, rng):
  """cam_from_world (pycolmap.Rigid3d) of a camera at `centre` [3] looking at the origin,
  rolled at random (OpenCV axes: x right, y down, z forward)."""
  z = -np.asarray(centre, np.float64) / np.linalg.norm(centre)
  x = np.cross(z, rng.normal(size=3))
  x /= np.linalg.norm(x)
  R_wc = np.stack([x, np.cross(z, x), z], 1)  # camera -> world
  return pycolmap.Rigid3d(pycolmap.Rotation3d(R_wc.T), -R_wc.T @ centre)


def write_pycolmap_model(cams, n_images_per_camera=2, n_points=30, seed=0,
                         bare_last_image=True):
  """A pycolmap.Reconstruction: cams [(name, params or None)] numbered from 1, each seen by
  n_images_per_camera images named "<id>.png" on a sphere of radius 3 looking at the
  origin, and n_points points near the origin seen by every image, but, with
  bare_last_image, the last one, which has no keypoints (COLMAP then ends images.txt with
  an empty keypoint line)."""
  rng = np.random.default_rng(seed)
  rec = pycolmap.Reconstruction()
  n_images = len(cams) * n_images_per_camera
  for camera_id, (name, params) in enumerate(cams, 1):
    rec.add_camera_with_trivial_rig(_pycolmap_camera(camera_id, name, params))
    for k in range(n_images_per_camera):
      image_id = (camera_id - 1) * n_images_per_camera + k + 1
      bare = bare_last_image and image_id == n_images
      image = pycolmap.Image(name=f"{image_id}.png", camera_id=camera_id, image_id=image_id,
                             keypoints=rng.uniform(0, 400, (0 if bare else n_points, 2)))
      centre = rng.normal(size=3)
      rec.add_image_with_trivial_frame(image, _look_at_world(3.0 * centre / np.linalg.norm(
          centre), rng))
  for k in range(n_points):
    track = pycolmap.Track()
    for image_id in range(1, n_images + (0 if bare_last_image else 1)):
      track.add_element(image_id, k)
    rec.add_point3D(rng.normal(0, 0.3, 3), track)
  return rec


# ----------------------------------------------------------------------------- comparisons


def _c2w_opengl(rigid):
  """OpenGL camera-to-world [3, 4] of a pycolmap cam_from_world."""
  return rigid.inverse().matrix() * np.array([1.0, -1.0, -1.0, 1.0])


def _lens(camera):
  """(fx, fy, cx, cy, coeffs [5] in the library's order k1 k2 p1 p2 k3) of a pycolmap camera,
  read by the names pycolmap gives its parameters (params_info)."""
  names = [n.strip() for n in camera.params_info.split(",")]
  value = dict(zip(names, camera.params))
  k1 = value.get("k1", value.get("k", 0.0))
  coeffs = np.array([k1, value.get("k2", 0.0), value.get("p1", 0.0), value.get("p2", 0.0),
                     value.get("k3", 0.0)])
  return (camera.focal_length_x, camera.focal_length_y, camera.principal_point_x,
          camera.principal_point_y, coeffs)


def model_differences(folder, rec):
  """Max abs differences between colmap.read_model(folder) and the pycolmap Reconstruction
  `rec`: {"cameras" (params), "rotation" (matrix), "quaternion", "translation", "c2w"
  (opengl_c2w vs pycolmap's inverted cam_from_world), "intrinsics" (fx fy cx cy of
  camera_intrinsics), "distortion" (its coeffs), "points"}, with the sets of camera models,
  image names and tracks asserted equal on the way."""
  model = colmap.read_model(folder)
  d = dict.fromkeys(("cameras", "rotation", "quaternion", "translation", "c2w", "intrinsics",
                     "distortion", "points"), 0.0)
  assert sorted(model.cameras) == sorted(rec.cameras)
  for camera_id, camera in model.cameras.items():
    theirs = rec.cameras[camera_id]
    assert (camera.model, camera.width, camera.height) == (theirs.model.name, theirs.width,
                                                           theirs.height)
    assert len(camera.params) == len(theirs.params)
    d["cameras"] = max(d["cameras"], np.abs(np.subtract(camera.params, theirs.params)).max())
    if camera.model in colmap.SUPPORTED:
      fx, fy, cx, cy, coeffs = colmap.camera_intrinsics(camera, "test")
      want = _lens(theirs)
      d["intrinsics"] = max(d["intrinsics"], np.abs(np.subtract((fx, fy, cx, cy),
                                                                want[:4])).max())
      d["distortion"] = max(d["distortion"], np.abs(coeffs - want[4]).max())
    else:
      with pytest.raises(UserError, match="not supported"):
        colmap.camera_intrinsics(camera, "test")
  assert sorted(image.id for image in model.images) == sorted(rec.reg_image_ids())
  for image in model.images:
    theirs = rec.images[image.id]
    assert (image.name, image.camera_id) == (theirs.name, theirs.camera_id)
    pose = theirs.cam_from_world()
    wxyz = pose.rotation.quat[[3, 0, 1, 2]]  # pycolmap: x y z w
    wxyz = wxyz if wxyz @ image.qvec >= 0 else -wxyz
    d["quaternion"] = max(d["quaternion"], np.abs(np.subtract(image.qvec, wxyz)).max())
    d["rotation"] = max(d["rotation"], np.abs(colmap.qvec_to_rotation(image.qvec)
                                              - pose.rotation.matrix()).max())
    d["translation"] = max(d["translation"], np.abs(np.subtract(image.tvec,
                                                                pose.translation)).max())
    d["c2w"] = max(d["c2w"], np.abs(colmap.opengl_c2w(image) - _c2w_opengl(pose)).max())
  ids = sorted(rec.points3D)
  assert len(model.points) == len(ids)
  if ids:  # COLMAP writes points in id order (binary and text): compare in that order
    d["points"] = np.abs(model.points - np.stack([rec.points3D[i].xyz for i in ids])).max()
    for track, i in zip(model.tracks, ids):
      assert sorted(track.tolist()) == sorted(e.image_id for e in rec.points3D[i].track.elements)
  return d


def pixel_differences(fx, fy, cx, cy, coeffs, theirs, step=1, scale=1.0):
  """Max abs differences in pixels between the library's and COLMAP's pixel mapping of one
  camera on every step-th pixel of its grid (and the last row and column): (undistortion:
  cameras.pixel_directions vs theirs.cam_from_img, both as undistorted pinhole pixels;
  distortion: cameras.project vs theirs.img_from_cam of the same camera-space points).

  fx, fy, cx, cy: intrinsics in COLMAP's pixel convention at full size, as the readers give
  them; coeffs [5] or None; scale: the loader's image scale (centre_origin_K's), theirs being
  pycolmap's camera rescaled by it."""
  K = cameras.centre_origin_K(fx, fy, cx, cy, scale, scale)
  cols = np.unique(np.r_[np.arange(0, theirs.width, step), theirs.width - 1])
  rows = np.unique(np.r_[np.arange(0, theirs.height, step), theirs.height - 1])
  cols, rows = (a.astype(np.float32).ravel() for a in np.meshgrid(cols, rows))
  pixels = np.stack([cols + 0.5, rows + 0.5], 1).astype(np.float64)  # COLMAP's grid
  lens = None if coeffs is None else np.asarray(coeffs, np.float32)
  dirs = np.asarray(cameras.pixel_directions(K, cols, rows, lens), np.float64)
  mine = np.stack([dirs[:, 0], -dirs[:, 1]], 1)  # OpenGL (x, y up, z = -1) -> OpenCV
  want = theirs.cam_from_img(pixels)
  f = np.array([theirs.focal_length_x, theirs.focal_length_y])
  undistortion = np.abs((mine - want) * f).max()
  points = np.concatenate([want, np.ones((len(want), 1))], 1) * 2.5  # OpenCV camera space
  u, v, _ = cameras.project(K, (points * np.array([1.0, -1.0, -1.0])).astype(np.float32), lens)
  projected = np.stack([np.asarray(u, np.float64) + 0.5, np.asarray(v, np.float64) + 0.5], 1)
  distortion = np.abs(projected - theirs.img_from_cam(points)).max()
  # The lens moves the outer pixels (so the agreement is not that of two pinholes).
  moved = np.abs(want * f + [theirs.principal_point_x, theirs.principal_point_y]
                 - pixels).max()
  return undistortion, distortion, moved


# ----------------------------------------------------------------------------- written models


@pytest.fixture(scope="module")
def every_model(tmp_path_factory):
  """A model with a camera of each of COLMAP's camera models, written by pycolmap as .bin
  and .txt: (Reconstruction, {"bin": folder, "txt": folder})."""
  rec = write_pycolmap_model([(name, params) for name, params in SUPPORTED.items()]
                             + [(name, None) for name in UNSUPPORTED])
  folders = {}
  for ext in ("bin", "txt"):
    folders[ext] = str(tmp_path_factory.mktemp(f"model_{ext}"))
    (rec.write_binary if ext == "bin" else rec.write_text)(folders[ext])
  return rec, folders


@pytest.mark.parametrize("ext", ["bin", "txt"])
def test_models_pycolmap_writes_read_as_pycolmap_reads_them(every_model, ext):
  rec, folders = every_model
  assert len(UNSUPPORTED) >= 5 and {"OPENCV_FISHEYE", "FOV"} <= set(UNSUPPORTED)
  assert os.path.isfile(os.path.join(folders[ext], f"cameras.{ext}"))
  d = model_differences(folders[ext], rec)
  assert max(d.values()) < POSE_TOL, d
  # The text model ends with the last image's empty keypoint line, which the reader keeps.
  if ext == "txt":
    with open(os.path.join(folders[ext], "images.txt")) as f:
      assert f.read().endswith(".png\n\n")


def test_truncated_binary_model_is_an_error(every_model, tmp_path):
  """The reader names the truncated file (pycolmap 4.2 reads this one without complaint)."""
  _, folders = every_model
  for name in ("cameras", "images", "points3D"):
    folder = tmp_path / name
    folder.mkdir()
    for other in ("cameras", "images", "points3D"):
      with open(os.path.join(folders["bin"], f"{other}.bin"), "rb") as f:
        data = f.read()
      (folder / f"{other}.bin").write_bytes(data[:-7] if other == name else data)
    with pytest.raises(UserError, match=f"{name}.bin: truncated"):
      colmap.read_model(str(folder))


@pytest.fixture(scope="module")
def supported_capture(tmp_path_factory):
  """A capture (sparse/0 written by pycolmap, binary; images/ of grey PNGs) with two images
  of each SUPPORTED camera model: (Reconstruction, folder)."""
  rec = write_pycolmap_model(list(SUPPORTED.items()), seed=1, bare_last_image=False)
  root = tmp_path_factory.mktemp("capture")
  os.makedirs(root / "sparse" / "0")
  rec.write_binary(str(root / "sparse" / "0"))
  os.makedirs(root / "images")
  grey = Image.fromarray(np.full((H, W, 3), 128, np.uint8))
  for image in rec.images.values():
    grey.save(root / "images" / image.name)
  return rec, str(root)


@pytest.mark.parametrize("name", list(SUPPORTED))
def test_undistorted_pixels_are_colmaps(supported_capture, name):
  """Per camera model: the capture reader's camera (intrinsics, lens) maps every pixel as
  COLMAP's camera does, both ways."""
  rec, root = supported_capture
  capture = captures.read_colmap_capture(root)
  views = [n for n, path in enumerate(capture.paths)
           if rec.cameras[rec.find_image_with_name(os.path.basename(path)).camera_id].model.name
           == name]
  assert len(views) == 2
  for n in views:
    image = rec.find_image_with_name(os.path.basename(capture.paths[n]))
    c = capture.cameras[n]
    undistortion, distortion, moved = pixel_differences(
        c["fx"], c["fy"], c["cx"], c["cy"], c["coeffs"], rec.cameras[image.camera_id], step=4)
    assert undistortion < PIXEL_TOL and distortion < PIXEL_TOL, (undistortion, distortion)
    assert (moved > 3.0) == ("PINHOLE" not in name), moved
    np.testing.assert_allclose(capture.c2w[n], _c2w_opengl(image.cam_from_world()),
                               atol=POSE_TOL)


def test_loaded_scene_rays_are_colmaps(supported_capture):
  """End to end: the rays load_scene gives each view (after normalisation), back in that
  camera's frame, point through COLMAP's undistorted positions of their pixels."""
  rec, root = supported_capture
  scene, _ = load_scene(DataConfig(path=root, format="colmap", layout="object", downscale=1))
  assert scene.distortion is not None
  worst = 0.0
  for n, path in enumerate(scene.image_paths):
    theirs = rec.cameras[rec.find_image_with_name(os.path.basename(path)).camera_id]
    d = np.asarray(scene.camera_rays(n)["directions"], np.float64)[::7, ::7]
    rows, cols = np.mgrid[0:H:7, 0:W:7]
    d = d @ np.asarray(scene.c2w[n][:3, :3], np.float64)  # world -> camera (OpenGL)
    mine = np.stack([d[..., 0], -d[..., 1]], -1) / -d[..., 2:]
    want = theirs.cam_from_img(np.stack([cols + 0.5, rows + 0.5], -1).reshape(-1, 2))
    f = np.array([theirs.focal_length_x, theirs.focal_length_y])
    worst = max(worst, np.abs((mine.reshape(-1, 2) - want) * f).max())
  assert worst < PIXEL_TOL, worst


def test_colmap4_camera_models_are_refused_by_name(supported_capture, tmp_path):
  """A COLMAP 4 camera model (ids 11-17) reads, and the loader names it as unsupported."""
  rec = write_pycolmap_model([("SIMPLE_DIVISION", None)])
  rec.write_binary(str(tmp_path))
  model = colmap.read_model(str(tmp_path))
  assert model.cameras[1].model == "SIMPLE_DIVISION"
  with pytest.raises(UserError, match="SIMPLE_DIVISION is not supported"):
    colmap.camera_intrinsics(model.cameras[1], "test")


# ----------------------------------------------------------------------------- the real captures


def test_cup_reads_as_pycolmap_reads_it():
  folder = os.path.join(data_path("captures", "cup"), "sparse", "0")
  rec = pycolmap.Reconstruction(folder)
  assert rec.num_reg_images() == 77 and len(rec.points3D) == 9262
  d = model_differences(folder, rec)
  assert max(d.values()) < POSE_TOL, d
  # The capture reader (sorted by name) and its cameras at full size and at images_4's 1/4.
  capture = captures.read_colmap_capture(os.path.dirname(os.path.dirname(folder)))
  for n in (0, 40, 76):
    image = rec.find_image_with_name(os.path.basename(capture.paths[n]))
    np.testing.assert_allclose(capture.c2w[n], _c2w_opengl(image.cam_from_world()),
                               atol=POSE_TOL)
    c = capture.cameras[n]
    for scale in (1.0, 0.25):
      theirs = pycolmap.Camera(rec.cameras[image.camera_id].todict())
      theirs.rescale(scale)
      undistortion, distortion, _ = pixel_differences(c["fx"], c["fy"], c["cx"], c["cy"],
                                                      None, theirs, step=8, scale=scale)
      assert undistortion < PIXEL_TOL and distortion < PIXEL_TOL, (scale, undistortion,
                                                                   distortion)


def fruit_colmap_model():
  """fruit's transforms.json as COLMAP sees it: (its OPENCV pycolmap camera, the
  transforms reader's capture, a Reconstruction of its poses)."""
  folder = data_path("captures", "fruit")
  with open(os.path.join(folder, "transforms.json")) as f:
    meta = json.load(f)
  capture = captures.read_transforms_capture(folder)
  camera = pycolmap.Camera(camera_id=1, model=pycolmap.CameraModelId.OPENCV,
                           width=int(meta["w"]), height=int(meta["h"]),
                           params=[meta[k] for k in ("fl_x", "fl_y", "cx", "cy", "k1", "k2",
                                                     "p1", "p2")])
  rec = pycolmap.Reconstruction()
  rec.add_camera_with_trivial_rig(camera)
  for n, (path, c2w) in enumerate(zip(capture.paths, capture.c2w), 1):
    R = c2w[:, :3] * np.array([1.0, -1.0, -1.0])  # OpenGL -> OpenCV camera axes
    rec.add_image_with_trivial_frame(
        pycolmap.Image(name=os.path.basename(path), camera_id=1, image_id=n),
        pycolmap.Rigid3d(pycolmap.Rotation3d(R.T), -R.T @ c2w[:, 3]))
  return camera, capture, rec


@pytest.mark.parametrize("ext", ["bin", "txt"])
def test_fruit_written_by_pycolmap_reads_back(tmp_path, ext):
  """fruit's 81 poses and lens, written as a COLMAP model by pycolmap: the reader gives
  back the transforms reader's poses and COLMAP's numbers."""
  _, capture, rec = fruit_colmap_model()
  (rec.write_binary if ext == "bin" else rec.write_text)(str(tmp_path))
  d = model_differences(str(tmp_path), rec)
  assert max(d.values()) < POSE_TOL, d
  model = colmap.read_model(str(tmp_path))
  by_name = {image.name: colmap.opengl_c2w(image) for image in model.images}
  mine = np.stack([by_name[os.path.basename(p)] for p in capture.paths])
  assert np.abs(mine - capture.c2w).max() < POSE_TOL


def test_fruit_lens_undistorts_as_colmaps_opencv():
  camera, capture, _ = fruit_colmap_model()
  c = capture.cameras[0]
  fx, fy, cx, cy, coeffs = _lens(camera)
  assert np.abs(np.subtract((c["fx"], c["fy"], c["cx"], c["cy"]), (fx, fy, cx, cy))).max() \
      < POSE_TOL
  assert np.abs(c["coeffs"] - coeffs).max() < POSE_TOL
  undistortion, distortion, moved = pixel_differences(c["fx"], c["fy"], c["cx"], c["cy"],
                                                      c["coeffs"], camera, step=2)
  assert undistortion < PIXEL_TOL and distortion < PIXEL_TOL, (undistortion, distortion)
  assert moved > 5.0, moved
