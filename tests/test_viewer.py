"""The viewer (`msnerf view`): a real viser server on a loopback port, driven by a headless
client that speaks viser's protocol (msnerf_jax.viewer.probe), on a tiny untrained run."""

import io
import os
import re
import signal
import socket
import subprocess
import sys
import threading
import time
from types import SimpleNamespace

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from PIL import Image

pytest.importorskip("viser")

# pylint: disable=g-import-not-at-top,wrong-import-position
from msnerf_jax.core import checkpoint
from msnerf_jax.kinds import features as feature_kind
from msnerf_jax.kinds import multistyle as multistyle_kind
from msnerf_jax.kinds import stylized_scenes
from msnerf_jax import cli
from msnerf_jax.core import config as config_lib
from msnerf_jax.nerf import render as render_lib
from msnerf_jax.kinds import runs
from msnerf_jax.data.camera_path import read_camera_path
from msnerf_jax.data.images import to_uint8
from msnerf_jax.models.multistyle import init_multistyle_params
from msnerf_jax.train import state as state_lib
from msnerf_jax.viewer import camera as camera_lib
from msnerf_jax.viewer import frames as frames_lib
from msnerf_jax.viewer import probe as probe_lib
from msnerf_jax.viewer import server as server_lib
from msnerf_jax.viewer.scheduler import Scheduler

from conftest import untrained_nerf_run, write_blender_scene

NERF = config_lib.NerfConfig(net_depth=2, net_width=32, skip_layer=1, n_coarse=8, n_fine=8,
                             pos_freqs=4, dir_freqs=2, render_chunk=128)
STYLES = ("red", "blue", "original")


def multistyle_run(run_dir, data):
  """A multi-style run folder with random params and three random style vectors."""
  config = config_lib.MultistyleConfig(nerf=NERF, style_hidden=32, style_hidden2=16)
  runs.prepare_run_dir(run_dir, "multistyle", {
      "config": config_lib.to_dict(config), "data": config_lib.to_dict(data),
      "styles": list(STYLES)})
  multistyle_kind.save_style_vectors(run_dir, np.random.default_rng(0).normal(
      size=(len(STYLES), 1024)).astype(np.float32) ** 2)
  # Random params of the right tree (tracing, not running, flax's init: a second, not seven).
  rng = np.random.default_rng(1)
  params = jax.tree_util.tree_map(
      lambda leaf: (0.3 * rng.normal(size=leaf.shape)).astype(np.float32),
      jax.eval_shape(lambda: init_multistyle_params(config, jax.random.PRNGKey(1))))
  import optax  # the checkpoint tree of a train state; the heads are what matter here.
  ckpts = checkpoint.Checkpoints(run_dir)
  ckpts.save(3, state_lib.checkpoint_tree(state_lib.create_state(params, optax.adam(1e-3))))
  ckpts.close()
  return run_dir


@pytest.fixture(scope="module")
def world(tmp_path_factory):
  root = tmp_path_factory.mktemp("viewer")
  scene = write_blender_scene(str(root / "scene"), n_train=3, n_val=1, size=16)
  data = config_lib.DataConfig(path=scene)
  run = multistyle_run(str(root / "ms"), data)
  nerf = untrained_nerf_run(str(root / "nerf"), data, NERF)
  viewer = server_lib.open_viewer(run, str(root / "out"), port=0, log=lambda _: None)
  yield {"root": root, "run": run, "nerf": nerf, "viewer": viewer, "out": str(root / "out")}
  viewer.stop()


@pytest.fixture
def client(world):
  probe = probe_lib.Probe(world["viewer"].url)
  yield probe
  probe.close()


def _start(probe, viewer, view=None, width=640, height=480):
  """Connects (the first camera message) and waits for the controls; returns the view."""
  view = view or viewer.frames.start_request().view
  probe.camera(view.wxyz, view.position, view.fov, width, height)
  probe.wait_for(lambda: "frame" in probe.components, 30, "controls")
  return view


def _expected(viewer, view, width, height, style):
  """render_image of the same camera and style vector, as uint8."""
  frames = viewer.frames
  h, w = camera_lib.frame_size(width / height, frames.pixels["full"])
  camera = camera_lib.to_camera(view.wxyz, view.position, view.fov, h, w)
  out = render_lib.render_image(frames.field, frames.params, frames.scene.camera_rays(camera),
                                frames.config, frames.scene.white_background,
                                frames.chunks["full"], jnp.asarray(style, jnp.float32)[None])
  return to_uint8(out["rgb"][0])


def _full_frame(probe, viewer, width, height, after):
  h, w = camera_lib.frame_size(width / height, viewer.frames.pixels["full"])
  return probe.frame_of_size(h, w, after)


def _assert_same(frame, expected):
  # Same rays, params and chunk size; the frame's rays are split into bands (a rounding
  # step at most).
  assert frame.shape == expected.shape
  assert np.abs(frame.astype(int) - expected).max() <= 1


def test_frames_equal_render_image_for_styles_blends_and_uploads(world, client):
  viewer = world["viewer"]
  vectors = viewer.frames.styles
  # A camera of our own (not a training view): a quarter turn around the scene.
  c2w = viewer.frames.scene.render_poses[len(viewer.frames.scene.render_poses) // 4]
  view = viewer.frames.view_of(c2w, 4 / 3)
  _start(client, viewer, view)
  n = client.frame_count()
  client.camera(view.wxyz, view.position, view.fov, 640, 480)  # after the page is up
  _assert_same(_full_frame(client, viewer, 640, 480, n),
               _expected(viewer, view, 640, 480, vectors["red"]))
  # A trained style.
  n = client.frame_count()
  client.set("style", "blue")
  _assert_same(_full_frame(client, viewer, 640, 480, n),
               _expected(viewer, view, 640, 480, vectors["blue"]))
  # A blend of two styles at a strength.
  n = client.frame_count()
  client.set("blend with", "red")
  client.set("blend", 0.25)
  client.set("strength", 0.5)
  client.set("blend", 0.3)
  want = 0.5 * vectors["original"] + 0.5 * (0.7 * vectors["blue"] + 0.3 * vectors["red"])
  _assert_same(_full_frame(client, viewer, 640, 480, n), _expected(viewer, view, 640, 480, want))
  # An uploaded image: its style vector is computed on the spot.
  style = (np.random.default_rng(3).random((40, 56, 3)) * 255).astype(np.uint8)
  data = io.BytesIO()
  Image.fromarray(style).save(data, format="PNG")
  n = client.frame_count()
  client.set("strength", 1.0)
  client.set("blend", 0.0)
  client.upload("upload a style image", "painting.png", data.getvalue())
  client.wait_for(lambda: client.components["style"]["value"] == "upload: painting.png", 120)
  n = client.frame_count()
  client.camera(view.wxyz, view.position, view.fov, 640, 481)  # a new request, same view
  uploaded = viewer.frames.upload_style(data.getvalue(), "painting.png")
  _assert_same(_full_frame(client, viewer, 640, 481, n),
               _expected(viewer, view, 640, 481, uploaded))


def test_low_frame_first_then_full(world, client):
  viewer = world["viewer"]
  view = _start(client, viewer)
  n = client.frame_count()
  client.camera(view.wxyz, view.position, view.fov, 500, 500)
  full = _full_frame(client, viewer, 500, 500, n)
  # A band of the previous (4:3) request may still land after the camera moved; of the
  # new (square) request's frames, the low one comes first.
  sizes = [f.shape[:2] for f in client.frames[n:] if f.shape[0] == f.shape[1]]
  low = camera_lib.frame_size(1.0, viewer.frames.pixels["low"])
  assert sizes[0] == low and full.shape[:2] == (16, 16)
  # The frame time is shown on the page.
  client.wait_for(lambda: client.components["frame"]["value"].startswith("full 16x16"), 10)


def test_bad_uploads_get_a_message_and_the_server_goes_on(world, client, monkeypatch):
  viewer = world["viewer"]
  view = _start(client, viewer)
  tiny = io.BytesIO()
  Image.fromarray(np.zeros((1, 1, 3), np.uint8)).save(tiny, format="PNG")
  monkeypatch.setattr(frames_lib, "MAX_UPLOAD_BYTES", 10_000)
  for name, data, needle in [("notes.txt", b"not an image at all", "not an image"),
                             ("dot.png", tiny.getvalue(), "1x1"),
                             ("huge.png", b"\x89PNG" + bytes(20_000), "MB")]:
    count = len(client.notifications)
    client.upload("upload a style image", name, data)
    client.wait_for(lambda: len(client.notifications) > count, 30, "notification")
    body = client.notifications[-1]["body"]
    assert name in body and needle in body, body
  assert client.components["style"]["value"] in STYLES
  n = client.frame_count()
  client.camera(view.wxyz, view.position, view.fov, 300, 200)
  _full_frame(client, viewer, 300, 200, n)  # still rendering


def test_saves_png_and_keyframes_only_into_the_output_folder(world, client):
  viewer = world["viewer"]
  view = _start(client, viewer)
  n = client.frame_count()
  client.camera(view.wxyz, view.position, view.fov, 400, 400)
  frame = _full_frame(client, viewer, 400, 400, n)
  before = set(os.listdir(world["root"]))
  run_files = sorted(os.listdir(world["run"]))
  count = len(client.notifications)
  client.click("save view as PNG")
  client.wait_for(lambda: len(client.notifications) > count, 30, "notification")
  client.click("add camera keyframe")
  client.wait_for(lambda: len(client.notifications) > count + 1, 30, "notification")
  client.click("add camera keyframe")
  client.wait_for(lambda: len(client.notifications) > count + 2, 30, "notification")
  saved = sorted(os.listdir(world["out"]))
  pngs = [f for f in saved if f.endswith(".png")]
  assert pngs and "camera_path.json" in saved
  assert np.array_equal(np.asarray(Image.open(os.path.join(world["out"], pngs[-1]))), frame)
  assert client.downloads[-1] == pngs[-1]
  assert set(os.listdir(world["root"])) | {"out"} == before | {"out"}
  assert sorted(os.listdir(world["run"])) == run_files
  # The keyframes are a camera path `msnerf render --camera-path` reads: the same camera.
  cameras, _ = read_camera_path(os.path.join(world["out"], "camera_path.json"))
  assert len(cameras) >= 2
  expected = viewer.frames.camera(view, "full")
  np.testing.assert_allclose(cameras[-1].c2w, expected.c2w, atol=1e-6)
  np.testing.assert_allclose(cameras[-1].K, expected.K, rtol=1e-5)


def test_snap_goes_to_the_nearest_training_view(world, client):
  viewer = world["viewer"]
  scene = viewer.frames.scene
  target = int(scene.splits["train"][1])
  # A camera slightly off training view `target`.
  c2w = scene.c2w[target].copy()
  c2w[:3, 3] += 0.05
  view = _start(client, viewer, viewer.frames.view_of(c2w, 1.0))
  client.camera(view.wxyz, view.position, view.fov, 300, 300)
  time.sleep(0.3)
  count = len(client.camera_updates)
  client.click("snap to nearest training view")
  client.wait_for(lambda: any(m["type"] == "SetCameraPositionMessage"
                              for m in client.camera_updates[count:]), 30, "camera move")
  moved = [m for m in client.camera_updates[count:] if m["type"] == "SetCameraPositionMessage"]
  np.testing.assert_allclose(moved[-1]["position"], scene.c2w[target][:3, 3], atol=1e-5)


def test_camera_conversions_round_trip():
  rng = np.random.default_rng(0)
  for _ in range(5):
    q = rng.normal(size=4)
    R = np.asarray(__import__("viser").transforms.SO3(q / np.linalg.norm(q)).as_matrix())
    c2w = np.concatenate([R, rng.normal(size=(3, 1))], 1)
    wxyz, position = camera_lib.to_viser_pose(c2w)
    camera = camera_lib.to_camera(wxyz, position, 0.7, 30, 40)
    np.testing.assert_allclose(camera.c2w, c2w, atol=1e-6)
    assert camera_lib.vertical_fov(camera.K, 30) == pytest.approx(0.7)
  for aspect in (0.5, 1.0, 16 / 9, 4.0):
    h, w = camera_lib.frame_size(aspect, 10_000)
    assert abs(h * w - 10_000) <= h + w and abs(w / h - aspect) <= 1.0 / h


def test_scheduler_latest_request_wins_and_clients_take_turns():
  started, release = threading.Event(), threading.Event()
  rendered, delivered = [], []

  def render(request, level, cancelled):
    if request == ("a", 0):
      started.set()
      release.wait(10)
    rendered.append((request, level))
    return None if cancelled() else request

  scheduler = Scheduler(render, lambda c, f, l, s: delivered.append((c, f, l)), settle=0.05)
  try:
    scheduler.update("a", ("a", 0))
    assert started.wait(10)
    for i in range(1, 6):  # while the worker is busy: only the latest is kept.
      scheduler.update("a", ("a", i))
    scheduler.update("b", ("b", 0))
    release.set()
    deadline = time.time() + 10
    while time.time() < deadline and not {("a", ("a", 5), "full"), ("b", ("b", 0), "full")} \
        <= set(delivered):
      time.sleep(0.01)
    assert ("a", ("a", 5), "full") in delivered and ("b", ("b", 0), "full") in delivered
    assert not any(r[0] in {("a", i) for i in (1, 2, 3, 4)} for r in rendered)
    # After its first (low) frame, "a" waits for its turn: "b" is served before a's next one.
    order = [c for c, _, _ in delivered]
    assert order.index("b") < len(order) - 1 - order[::-1].index("a")
  finally:
    scheduler.stop()


def test_full_frame_is_abandoned_for_a_newer_request():
  calls = []
  gate = threading.Event()

  def render(request, level, cancelled):
    calls.append((request, level))
    if level == "full" and request == 0:
      gate.set()
      for _ in range(200):  # a long frame, checking between "bands"
        if cancelled():
          return None
        time.sleep(0.01)
    return request

  delivered = []
  scheduler = Scheduler(render, lambda c, f, l, s: delivered.append((f, l)), settle=0.0)
  try:
    scheduler.update("a", 0)
    assert gate.wait(10)
    scheduler.update("a", 1)
    deadline = time.time() + 10
    while time.time() < deadline and (1, "full") not in delivered:
      time.sleep(0.01)
    assert (1, "full") in delivered and (0, "full") not in delivered
  finally:
    scheduler.stop()


def _one_line_error(capsys, argv, *needles):
  capsys.readouterr()
  assert cli.main(argv) == 2
  err = capsys.readouterr().err.strip()
  assert len(err.splitlines()) == 1 and "Traceback" not in err, err
  for needle in needles:
    assert needle in err, err
  return err


def test_bad_runs_and_ports_end_with_one_line(world, tmp_path, capsys):
  _one_line_error(capsys, ["view", "--run", str(tmp_path / "nope"), "--port", "0"], "nope")
  (tmp_path / "empty").mkdir()
  _one_line_error(capsys, ["view", "--run", str(tmp_path / "empty"), "--port", "0"],
                  "run.json")
  adain = tmp_path / "adain"
  runs.prepare_run_dir(str(adain), "adain",
                       {"config": config_lib.to_dict(config_lib.AdainConfig())})
  _one_line_error(capsys, ["view", "--run", str(adain), "--port", "0"], "adain", "no scene")
  busy = world["viewer"].port
  _one_line_error(capsys, ["view", "--run", world["run"], "--port", str(busy)], str(busy),
                  "--port")
  _one_line_error(capsys, ["view", "--run", world["run"], "--port", "70000"], "--port")
  with socket.socket() as s:
    s.bind(("127.0.0.1", 0))
    s.listen()
    port = s.getsockname()[1]
    _one_line_error(capsys, ["view", "--run", world["nerf"], "--port", str(port)], str(port))
  assert not os.path.exists(os.path.join(world["nerf"], "viewer"))
  # --styles: a NeRF run has none; a style that is neither a file nor a training style.
  style = str(world["root"] / "scene" / "train" / "r_0.png")
  _one_line_error(capsys, ["view", "--run", world["nerf"], "--port", "0", "--styles", style],
                  "--styles", "NeRF run")
  _one_line_error(capsys, ["view", "--run", world["run"], "--port", "0", "--styles",
                           str(tmp_path / "missing.png")], "missing.png", "image file")


def test_browser_clicks_through_the_page_and_sees_render_image_at_every_step(world, tmp_path):
  """experiments/tools/viewer_browser.py in headless Chromium through Playwright: load,
  orbit, style, strength, upload and save, each frame on the page compared with
  render_image of the same camera (skipped, with the reason, without Playwright or
  Chromium; .ci/run installs both where it can)."""
  script = os.path.join(os.path.dirname(os.path.dirname(__file__)), "experiments",
                        "tools", "viewer_browser.py")
  out = tmp_path / "screens"
  done = subprocess.run([sys.executable, script, "--run", world["run"], "--out", str(out)],
                        capture_output=True, text=True, timeout=600,
                        env=dict(os.environ, PYTHONPATH=os.path.dirname(script) + "/../.."))
  if done.returncode == 77:
    pytest.skip(done.stdout.strip())
  assert done.returncode == 0, done.stdout + done.stderr
  assert "6 of 6 steps passed" in done.stdout, done.stdout
  for step in ("load", "orbit", "style", "strength", "upload"):
    assert re.search(rf"^  {step} .* ok$", done.stdout, re.M), done.stdout
  shots = sorted(p.name for p in out.glob("0*.png"))
  assert shots == ["00_load.png", "01_orbit.png", "02_style.png", "03_strength.png",
                   "04_upload.png"], shots


def test_nerf_run_is_viewed_without_style_controls(world):
  viewer = server_lib.open_viewer(world["nerf"], port=0, log=lambda _: None)
  probe = probe_lib.Probe(viewer.url)
  try:
    view = viewer.frames.start_request().view
    probe.camera(view.wxyz, view.position, view.fov, 320, 320)
    probe.wait_for(lambda: "frame" in probe.components, 30, "controls")
    frame = _full_frame(probe, viewer, 320, 320, 0)
    assert "style" not in probe.components
    frames = viewer.frames
    camera = frames.camera(view, "full")
    out = render_lib.render_image(frames.field, frames.params, frames.scene.camera_rays(camera),
                                  frames.config, frames.scene.white_background,
                                  frames.chunks["full"])
    _assert_same(frame, to_uint8(out["rgb"]))
  finally:
    probe.close()
    viewer.stop()


def test_full_frames_take_the_windows_shape_up_to_full_side(world):
  """`--full-side N`: a resting camera's frame has up to N x N pixels, shaped to the window
  and never more than the window's own; it is render_image of that camera. Low frames keep
  their budget."""
  viewer = server_lib.open_viewer(world["nerf"], port=0, log=lambda _: None, full_side=40)
  probe = probe_lib.Probe(viewer.url)
  try:
    frames = viewer.frames
    assert frames.pixels["full"] == 1600 and frames.pixels["low"] == 16 * 16 // 16
    view = frames.start_request().view
    for width, height, shape in [(640, 480, camera_lib.frame_size(4 / 3, 1600)),
                                 (20, 15, (15, 20))]:  # a window smaller than 40 x 40
      n = probe.frame_count()
      probe.camera(view.wxyz, view.position, view.fov, width, height)
      probe.wait_for(lambda: "frame" in probe.components, 30, "controls")
      frame = probe.frame_of_size(*shape, n)
      sized = server_lib.view_of_camera(SimpleNamespace(
          wxyz=view.wxyz, position=view.position, fov=view.fov, image_width=width,
          image_height=height))
      camera = frames.camera(sized, "full")
      assert (camera.height, camera.width) == shape
      out = render_lib.render_image(frames.field, frames.params,
                                    frames.scene.camera_rays(camera), frames.config,
                                    frames.scene.white_background, frames.chunks["full"])
      _assert_same(frame, to_uint8(out["rgb"]))
  finally:
    probe.close()
    viewer.stop()


def untrained_feature_run(run_dir, nerf_run, decoder, data):
  """A feature run folder as `features train` leaves it (with its rendered statistics), with
  untrained feature params on the NeRF run."""
  # pylint: disable=g-import-not-at-top
  from msnerf_jax.train import features
  config = config_lib.FeatureConfig(nerf=NERF, scene_box=1.5, dim=8, width=16, hash_levels=4,
                                    hash_table_size=2 ** 10, hash_min_res=4, hash_max_res=32,
                                    top_k=4, stylize_scale=2)
  runs.prepare_run_dir(run_dir, "features", {
      "config": config_lib.to_dict(config), "data": config_lib.to_dict(data),
      "nerf_run": os.path.abspath(nerf_run), "decoder": os.path.abspath(decoder)})
  rng = np.random.default_rng(2)
  stats = np.stack([rng.normal(size=512), rng.uniform(0.5, 2.0, size=512)]).astype(np.float32)
  np.save(os.path.join(run_dir, feature_kind.RENDERED_STATS.format(step=2)), stats)
  ckpts = checkpoint.Checkpoints(run_dir)
  ckpts.save(2, state_lib.checkpoint_tree(features.init_state(
      config, runs.load_run(nerf_run, "nerf").params)))
  ckpts.close()
  return run_dir


def test_feature_run_paints_the_given_styles_and_uploads_at_any_strength(world, tmp_path):
  """A feature run: its frames are the feature field's renders stylized in 3D and painted by
  its decoder; --styles images come first in the menus, uploads are cover-cropped as the
  decoder paints, and the strength slider blends towards the scene's own statistics."""
  # pylint: disable=g-import-not-at-top
  from msnerf_jax.data.images import decode_image
  from msnerf_jax.style.vectors import style_vector_of
  from msnerf_jax.models import vgg
  from conftest import fake_decoder
  from test_multistyle import write_style
  decoder = fake_decoder(tmp_path / "decoder")
  run = untrained_feature_run(str(tmp_path / "ff"), world["nerf"], decoder,
                              config_lib.DataConfig(path=str(world["root"] / "scene")))
  red = write_style(tmp_path / "red.png", (200, 30, 30))
  viewer = server_lib.open_viewer(run, port=0, log=lambda _: None, style_paths=[red])
  probe = probe_lib.Probe(viewer.url)
  try:
    frames = viewer.frames
    assert list(frames.styles) == ["red", "original"]
    view = frames.start_request().view
    probe.camera(view.wxyz, view.position, view.fov, 320, 320)
    probe.wait_for(lambda: "strength" in probe.components, 30, "controls")
    stats, original, size = feature_kind.feature_painting(frames.run, frames.scene)
    paint = feature_kind.style_renderer(frames.run, frames.scene,
                                        decoder=stylized_scenes.load_decoder(decoder))
    camera = frames.camera(view, "full")
    _assert_same(_full_frame(probe, viewer, 320, 320, 0),
                 to_uint8(paint(camera, [frames.styles["red"]])[0]))
    # Half strength: half the style's statistics, half the scene's.
    n = probe.frame_count()
    probe.set("strength", 0.5)
    _assert_same(_full_frame(probe, viewer, 320, 320, n),
                 to_uint8(paint(camera, [0.5 * frames.styles["red"] + 0.5 * original])[0]))
    # An upload is cropped to the size the decoder paints, as per-frame AdaIN crops it.
    png = open(write_style(tmp_path / "blue.png", (20, 40, 220)), "rb").read()
    vector = frames.upload_style(png, "blue.png")
    want = style_vector_of(vgg.load_vgg_params(), decode_image(png, "blue.png", max_side=1024),
                           size)
    np.testing.assert_allclose(vector, want, rtol=1e-5, atol=1e-5)
  finally:
    probe.close()
    viewer.stop()


def test_cli_serves_on_loopback_and_ctrl_c_stops_cleanly(world, request, tmp_path):
  from conftest import trainer_env  # pylint: disable=g-import-not-at-top
  # Started with SIGINT ignored, as a script's `cmd &` starts it (a CI run launched in the
  # background hung here until the viewer set its own handlers).
  server = subprocess.Popen(["sh", "-c", 'trap "" INT; exec "$0" "$@"', sys.executable, "-m",
                             "msnerf_jax", "view", "--run", world["run"],
                             "--port", "0", "--out", str(tmp_path / "saved")],
                            stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True,
                            env=trainer_env(request, tmp_path / "cache"))
  try:
    lines = []
    for line in server.stdout:
      lines.append(line)
      if "serving" in line:
        break
    url = re.search(r"at (http://127\.0\.0\.1:\d+) \(this machine only\)", lines[-1])
    assert url, "".join(lines)
    probe = probe_lib.Probe(url.group(1))
    try:
      view = frames_lib.View((1.0, 0.0, 0.0, 0.0), (0.0, 0.0, -4.0), 0.7, 1.0)
      probe.camera(view.wxyz, view.position, view.fov, 200, 200)
      assert probe.next_frame(0).ndim == 3
      server.send_signal(signal.SIGINT)  # with the page still open
      out, _ = server.communicate(timeout=120)
      probe.wait_for(lambda: probe.closed, 10, "disconnect")
    finally:
      probe.close()
    assert server.returncode == 0, out
    assert "msnerf view: stopped" in out and "Traceback" not in out, out
  finally:
    if server.poll() is None:
      server.kill()
