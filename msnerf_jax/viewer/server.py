"""The viewer's page: a viser server whose background image is the run's render of each
browser's camera, with the style controls, uploads and saving of `msnerf view`.

Every client has its own camera and controls; one scheduler renders for all of them. Files
are only written into the output folder, under names the server chooses.
"""

import dataclasses
import json
import math
import os
import threading
import time
from typing import Any, Callable, Dict, Optional, Sequence

import numpy as np
import viser

from msnerf_jax.data.camera_path import read_camera_path
from msnerf_jax.data.stylized import ORIGINAL
from msnerf_jax.core.errors import UserError
from msnerf_jax.kinds.registry import KINDS, get_kind
from msnerf_jax.core.files import atomic_write_bytes
from msnerf_jax.viewer import camera as camera_lib
from msnerf_jax.viewer.network import check_port
from msnerf_jax.viewer.frames import Frames, Request, StyleChoice, View
from msnerf_jax.viewer.scheduler import Scheduler

KEYFRAMES = "camera_path.json"
UPLOAD_PREFIX = "upload: "
MAX_UPLOADS_PER_CLIENT = 8


@dataclasses.dataclass
class _ClientState:
  """One browser tab: its controls, uploaded styles and latest view."""
  handle: Any
  gui: Dict[str, Any]
  table: Dict[str, np.ndarray]  # style name -> vector: the run's styles and this tab's uploads
  view: Optional[View] = None


class ViewerServer:
  """Serves `frames` (a loaded run) at http://host:port; `out_dir` receives saved views and
  keyframes. `stop()` ends it."""

  def __init__(self, frames: Frames, out_dir: str, host: str = "127.0.0.1", port: int = 8080,
               settle: float = 0.15):
    self.frames, self.out_dir = frames, out_dir
    check_port(host, port)
    self._clients: Dict[int, _ClientState] = {}
    self._lock = threading.Lock()
    self._saves = 0
    self.scheduler = Scheduler(frames.render, self._deliver, settle)
    self.server = viser.ViserServer(host=host, port=port, label="msnerf view", verbose=False)
    if port and self.server.get_port() != port:  # taken between the check and the bind.
      self.stop()
      raise UserError(f"{host}:{port}: port in use (choose another with --port)")
    self.host, self.port = host, self.server.get_port()
    self.server.scene.set_up_direction(tuple(camera_lib.scene_up(frames.scene)))
    self._set_initial_camera()
    self.server.on_client_connect(self._connect)
    self.server.on_client_disconnect(self._disconnect)

  @property
  def url(self) -> str:
    return f"http://{self.host}:{self.port}"

  def stop(self) -> None:
    self.scheduler.stop()
    self.server.stop()

  # Rendering.

  def _deliver(self, client_id, frame, level, seconds):
    """Shows a rendered frame (uint8 [H, W, 3]) as the client's background, losslessly."""
    state = self._clients.get(client_id)
    if state is None:
      return
    state.handle.scene.set_background_image(frame, format="png")
    state.gui["frame"].value = (f"{level} {frame.shape[1]}x{frame.shape[0]} in "
                                f"{seconds:.2f} s")

  def _current(self, state: _ClientState) -> Request:
    """The frame a client's view and controls ask for now."""
    style = self.frames.style_vector(self._choice(state), state.table) \
        if self.frames.has_styles else None
    return Request(state.view, style)

  def _request(self, client_id: int) -> None:
    """Queues the client's current view and style."""
    state = self._clients.get(client_id)
    if state is None or state.view is None:
      return
    self.scheduler.update(client_id, self._current(state))

  # Clients.

  def _connect(self, client) -> None:
    state = _ClientState(client, {}, dict(self.frames.styles))
    self._build_gui(client, state)
    with self._lock:
      self._clients[client.client_id] = state
    # The page starts at the server's initial camera (the first training view).
    async def moved(camera):  # on the event loop: camera messages in order.
      self._camera_moved(client.client_id, camera)
    client.camera.on_update(moved)
    self._camera_moved(client.client_id, client.camera)

  async def _disconnect(self, client) -> None:
    # async: runs on viser's event loop, also while the server stops (its thread pool is
    # shut down by then).
    self.scheduler.remove(client.client_id)
    with self._lock:
      self._clients.pop(client.client_id, None)

  def _camera_moved(self, client_id: int, camera) -> None:
    state = self._clients.get(client_id)
    if state is None:
      return
    view = view_of_camera(camera)
    if view is None:  # a malformed camera message: the tab keeps its last view.
      return
    state.view = view
    self._request(client_id)

  def _set_initial_camera(self) -> None:
    c2w = self.frames.scene.c2w[self.frames.first_view()]
    initial = self.server.initial_camera
    initial.position = tuple(float(x) for x in c2w[:3, 3])
    initial.look_at = tuple(camera_lib.look_at_point(self.frames.scene, c2w))
    initial.up = tuple(camera_lib.scene_up(self.frames.scene))
    initial.fov = self.frames.fov

  def _set_camera(self, client, c2w: np.ndarray) -> None:
    """Moves a client's camera to an OpenGL c2w [3, 4] with the scene's field of view."""
    with client.atomic():
      client.camera.position = tuple(float(x) for x in c2w[:3, 3])
      client.camera.look_at = tuple(camera_lib.look_at_point(self.frames.scene, c2w))
      client.camera.up_direction = tuple(camera_lib.scene_up(self.frames.scene))
      client.camera.fov = self.frames.fov

  # The controls.

  def _choice(self, state: _ClientState) -> StyleChoice:
    """The controls' values; names the tab's table lacks and numbers outside [0, 1] (which
    only a client that does not speak for the page sends) read as the first style and the
    nearest end."""
    gui, first = state.gui, next(iter(state.table))
    name = lambda value: value if value in state.table else first
    unit = lambda value, default: min(max(value, 0.0), 1.0) if math.isfinite(value) else default
    return StyleChoice(name(gui["style"].value), name(gui["blend_with"].value),
                       unit(float(gui["blend"].value), 0.0),
                       unit(float(gui["strength"].value), 1.0))

  def _build_gui(self, client, state: _ClientState) -> None:
    gui, frames, scene = client.gui, self.frames, self.frames.scene
    client_id = client.client_id

    async def changed(_):  # async: runs on viser's event loop, in the order of the changes.
      self._request(client_id)
    with gui.add_folder("Style"):
      if frames.has_styles:
        names = list(frames.styles)
        state.gui["style"] = gui.add_dropdown("style", names, initial_value=names[0])
        # The second style, so that the blend slider does something from the start.
        state.gui["blend_with"] = gui.add_dropdown("blend with", names,
                                                   initial_value=names[min(1, len(names) - 1)])
        state.gui["blend"] = gui.add_slider("blend", 0.0, 1.0, 0.01, 0.0,
                                            hint="0: the style, 1: the style blended with")
        state.gui["strength"] = gui.add_slider(
            "strength", 0.0, 1.0, 0.01, 1.0, disabled=ORIGINAL not in frames.styles,
            hint="0: the original scene, 1: the full style" if ORIGINAL in frames.styles
            else "this run has no 'original' style to blend from")
        kind = get_kind(frames.run.kind)
        if kind.paints_any_style:
          gui.add_markdown("A feature field (AdaIN in 3D): it paints any style image. "
                           "Upload one, or give `--styles` to `msnerf view`.")
        if kind.paints_any_style or kind.field is not None:
          state.gui["upload"] = gui.add_upload_button(
              "upload a style image", mime_type="image/*",
              hint="any painting or photo: its style vector is computed here")
          state.gui["upload"].on_upload(lambda event: self._upload(client_id, event))
        else:
          gui.add_markdown(f"A {kind.title} run: its styles are painted on the scene. Add one "
                           f"with `msnerf paint add --run {frames.run.run_dir} --style IMG`.")
        for name in ("style", "blend_with", "blend", "strength"):
          state.gui[name].on_update(changed)
      else:
        gui.add_markdown(f"A {frames.run.kind} run: the scene as trained, no styles.")
    with gui.add_folder("Camera"):
      snap = gui.add_button("snap to nearest training view")
      snap.on_click(lambda _: self._snap(client_id))
      paths = len(scene.render_poses)
      path = gui.add_slider("render path", 0, max(paths - 1, 1), 1, 0, disabled=paths < 2,
                            hint="the scene's render path (what `msnerf render` draws)")
      path.on_update(lambda event: self._set_camera(
          client, scene.render_poses[min(int(event.target.value), paths - 1)]))
    with gui.add_folder("Save"):
      gui.add_button("save view as PNG").on_click(lambda _: self._save_png(client_id))
      gui.add_button("add camera keyframe").on_click(lambda _: self._save_keyframe(client_id))
      gui.add_markdown(f"Into `{self.out_dir}`")
    state.gui["frame"] = gui.add_text("frame", "", disabled=True)

  def _notify(self, client_id: int, title: str, body: str, error: bool = False) -> None:
    state = self._clients.get(client_id)
    if state is not None:
      state.handle.add_notification(title, body, auto_close_seconds=8.0,
                                    color="red" if error else None)

  def _upload(self, client_id: int, event) -> None:
    state = self._clients.get(client_id)
    if state is None:
      return
    upload = event.target.value
    name = os.path.basename(str(upload.name))[:40] or "upload"
    try:
      vector = self.frames.upload_style(upload.content, name)
    except UserError as e:
      self._notify(client_id, "Style image refused", str(e), error=True)
      return
    label = UPLOAD_PREFIX + name
    uploads = [k for k in state.table if k.startswith(UPLOAD_PREFIX) and k != label]
    for old in uploads[:max(0, len(uploads) + 1 - MAX_UPLOADS_PER_CLIENT)]:
      del state.table[old]  # keep the latest few
    state.table[label] = vector
    options = tuple(state.table)
    for name_ in ("style", "blend_with"):
      handle = state.gui[name_]
      keep = handle.value if handle.value in state.table else options[0]
      handle.options = options
      handle.value = keep
    state.gui["style"].value = label
    self._request(client_id)

  def _snap(self, client_id: int) -> None:
    state = self._clients.get(client_id)
    if state is None or state.view is None:
      return
    view = camera_lib.nearest_view(self.frames.scene, state.view.position, state.view.wxyz)
    self._set_camera(state.handle, self.frames.scene.c2w[view])
    self._notify(client_id, "Camera", f"training view {view}")

  def _next_name(self, stem: str, ext: str) -> str:
    with self._lock:
      os.makedirs(self.out_dir, exist_ok=True)
      while True:
        self._saves += 1
        path = os.path.join(self.out_dir, f"{stem}_{self._saves:04d}{ext}")
        if not os.path.exists(path):
          return path

  def _save_png(self, client_id: int) -> None:
    state = self._clients.get(client_id)
    if state is None or state.view is None:
      return
    frame = self.frames.render(self._current(state), "full")
    import imageio.v3 as iio  # pylint: disable=g-import-not-at-top
    data = iio.imwrite("<bytes>", frame, extension=".png")
    try:
      path = self._next_name("view", ".png")
      atomic_write_bytes(path, data)
    except (UserError, OSError) as e:
      self._notify(client_id, "Not saved", str(e), error=True)
      return
    self._notify(client_id, "Saved", path)
    state.handle.send_file_download(os.path.basename(path), data, save_immediately=True)

  def _save_keyframe(self, client_id: int) -> None:
    state = self._clients.get(client_id)
    if state is None or state.view is None:
      return
    camera = self.frames.camera(state.view, "full")
    path = os.path.join(self.out_dir, KEYFRAMES)
    try:
      with self._lock:
        os.makedirs(self.out_dir, exist_ok=True)
        cameras = read_camera_path(path)[0] if os.path.exists(path) else []
        cameras.append(camera)
        atomic_write_bytes(path, json.dumps(camera_lib.keyframes_dict(cameras), indent=1).encode())
    except (UserError, OSError) as e:
      self._notify(client_id, "Keyframe not saved", str(e), error=True)
      return
    self._notify(client_id, "Keyframe saved",
                 f"{len(cameras)} in {path} (render them with `msnerf render --camera-path`)")


def view_of_camera(camera, max_coordinate: float = 1e6) -> Optional[View]:
  """The View of a viser camera (a client's camera handle), or None when its message was
  malformed: a pose, field of view or viewport size that is not finite, out of range or not
  numbers at all."""
  try:
    wxyz = tuple(float(x) for x in np.asarray(camera.wxyz, np.float64).reshape(4))
    position = tuple(float(x) for x in np.asarray(camera.position, np.float64).reshape(3))
    fov, height, width = float(camera.fov), float(camera.image_height), float(camera.image_width)
    aspect = width / height if height > 0 else 1.0
  except (TypeError, ValueError, OverflowError):
    return None
  numbers = np.asarray([*wxyz, *position, fov, aspect])
  if (not np.all(np.isfinite(numbers)) or not 1e-3 < fov < math.pi - 1e-3
      or np.abs(position).max() > max_coordinate or not 1e-3 < np.linalg.norm(wxyz) < 1e3):
    return None
  pixels = width * height  # the window's (0: unknown, a full frame keeps its budget)
  return View(wxyz, position, fov, aspect, int(pixels) if 0 < pixels < 2 ** 31 else 0)


def open_viewer(run_dir: str, out_dir: Optional[str] = None, host: str = "127.0.0.1",
                port: int = 8080, log: Callable[[str], Any] = print,
                style_paths: Sequence[str] = (), decoder_dir: Optional[str] = None,
                grids: Optional[int] = None, exact: bool = False,
                full_side: Optional[int] = None) -> ViewerServer:
  """Loads a run folder (a NeRF, multi-style or feature run), compiles its frames and starts
  serving it; `out_dir` (default RUN/viewer) receives saved views and keyframes. style_paths:
  style images added to the style menus; decoder_dir, grids: the AdaIN run that paints a
  feature run (default: its own) and on how many cell grids (Frames'); exact: draw with the
  exact renderer, not the run's baked scene; full_side: full frames of up to full_side^2
  pixels at the window's shape (Frames'; default: the training images' size).

  Raises:
    UserError for an unreadable run, a run without a scene, a bad style image or decoder, or
    a port that cannot be bound.
  """
  # pylint: disable=g-import-not-at-top
  from msnerf_jax.kinds import runs
  kind = runs.read_run_file(run_dir)["kind"]
  viewable = [name for name, k in KINDS.items() if k.nerf_config is not None]
  if get_kind(kind).nerf_config is None:
    raise UserError(f"{run_dir}: a {kind!r} run has no scene to view (view a "
                    f"{' or '.join(repr(k) for k in viewable)} run)")
  check_port(host, port)
  run = runs.load_run(run_dir, kind)
  scene = runs.scene_of(run)[0]
  frames = Frames(run, scene, style_paths, decoder_dir, grids, exact, log, full_side)
  log(f"{run_dir}: {kind} run at step {run.step}, {scene.width}x{scene.height} frames"
      + (f", styles: {', '.join(frames.styles)}" if frames.has_styles else ""))
  frames.warm_up(log)
  return ViewerServer(frames, out_dir or os.path.join(run_dir, "viewer"), host, port)


def serve_forever(viewer: ViewerServer, should_stop: Callable[[], bool] = lambda: False,
                  poll: float = 0.2) -> None:
  """Blocks until should_stop() or Ctrl-C, then stops the viewer."""
  try:
    while not should_stop():
      time.sleep(poll)
  finally:
    viewer.stop()
