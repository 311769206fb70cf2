"""A headless viewer client: it speaks viser's websocket protocol as the browser does, so that
tests and scripts can move a camera, use the controls, upload a style image and receive the
frames without a browser.

Outgoing messages are viser's own message classes, msgpack-encoded as the web client sends
them; incoming windows are viser's wire format (8-byte sizes, zstd-compressed msgpack, raw
binary buffers appended).
"""

import io
import threading
import time
import uuid
from typing import Any, Dict, List, Optional, Sequence

import msgspec
import numpy as np
import viser
import viser.transforms  # pylint: disable=unused-import
import zstandard
from PIL import Image
from viser import _messages
from websockets.sync.client import connect


def decode_window(raw: bytes) -> List[Dict[str, Any]]:
  """The messages (dicts with a "type") of one server -> client websocket frame."""
  inner_size = int.from_bytes(raw[:8], "little")
  compressed_size = int.from_bytes(raw[8:16], "little")
  payload = msgspec.msgpack.decode(zstandard.ZstdDecompressor().decompress(
      raw[16:16 + compressed_size], max_output_size=inner_size))
  offset, buffers = 16 + compressed_size, []
  for length in payload.get("binaryBufferLengths", ()):
    offset += (8 - offset % 8) % 8
    buffers.append(raw[offset:offset + length])
    offset += length
  return [_resolve(m, buffers) for m in payload["messages"]]


def _resolve(value, buffers):
  if isinstance(value, dict):
    if "__binary_index" in value and "dtype" in value:
      return np.frombuffer(buffers[value["__binary_index"]], value["dtype"])
    return {k: _resolve(v, buffers) for k, v in value.items()}
  if isinstance(value, list):
    return [_resolve(v, buffers) for v in value]
  return value


class Probe:
  """One client of a viewer at `url` (http://host:port). Frames and messages are collected
  by a reader thread; `close()` disconnects."""

  def __init__(self, url: str, timeout: float = 60.0):
    ws_url = url.replace("http://", "ws://", 1)
    self._ws = connect(ws_url, subprotocols=[f"viser-v{viser.__version__}"],
                       max_size=64 * 1024 * 1024, open_timeout=timeout)
    self._cond = threading.Condition()
    self.frames: List[np.ndarray] = []
    self.frame_times: List[float] = []  # time.monotonic() of each frame
    self.components: Dict[str, Dict[str, Any]] = {}  # label -> latest creation message
    self.notifications: List[Dict[str, Any]] = []
    self.downloads: List[str] = []
    self.camera_updates: List[Dict[str, Any]] = []
    self.closed = False
    self.error: Optional[BaseException] = None
    self._reader = threading.Thread(target=self._read, daemon=True)
    self._reader.start()

  def _read(self) -> None:
    try:
      for raw in self._ws:
        for message in decode_window(raw):
          self._handle(message)
    except Exception as e:  # pylint: disable=broad-except  # callers see `closed`, `error`.
      self.error = e
    with self._cond:
      self.closed = True
      self._cond.notify_all()

  def _handle(self, message: Dict[str, Any]) -> None:
    kind = message.get("type", "")
    with self._cond:
      if kind == "BackgroundImageMessage" and message.get("rgb_data") is not None:
        data = message["rgb_data"]
        data = data.tobytes() if isinstance(data, np.ndarray) else bytes(data)
        self.frames.append(np.asarray(Image.open(io.BytesIO(data)).convert("RGB")))
        self.frame_times.append(time.monotonic())
      elif (kind.startswith("Gui") and isinstance(message.get("props"), dict)
            and "label" in message["props"]):
        self.components[message["props"]["label"]] = message
      elif kind == "GuiUpdateMessage":
        for comp in self.components.values():
          if comp["uuid"] == message["uuid"]:
            comp.setdefault("props", {}).update(
                {k: v for k, v in message["updates"].items() if k != "value"})
            if "value" in message["updates"]:
              comp["value"] = message["updates"]["value"]
      elif kind == "NotificationShowMessage":
        self.notifications.append(message["props"])  # {"title", "body", ...}
      elif kind == "FileTransferStartDownload":
        self.downloads.append(message["filename"])
      elif kind.startswith("SetCamera"):
        self.camera_updates.append(message)
      self._cond.notify_all()

  def _send(self, message) -> None:
    self._ws.send(msgspec.msgpack.encode(message.as_serializable_dict()))

  def wait_for(self, predicate, timeout: float = 60.0, what: str = "") -> None:
    """Blocks until predicate() (under the lock) or raises TimeoutError."""
    deadline = time.monotonic() + timeout
    with self._cond:
      while not predicate():
        left = deadline - time.monotonic()
        if left <= 0 or self.closed:
          raise TimeoutError(f"viewer probe: no {what or 'update'} within {timeout:g} s"
                             + (f" (connection closed: {self.error!r})" if self.closed else ""))
        self._cond.wait(left)

  def camera(self, wxyz: Sequence[float], position: Sequence[float], fov: float,
             width: int, height: int, look_at: Optional[Sequence[float]] = None,
             up: Sequence[float] = (0.0, 0.0, 1.0)) -> None:
    """Sends a camera as the browser does (viser's OpenCV pose, vertical fov in radians)."""
    if look_at is None:  # a point ahead: the camera's +z (OpenCV) axis.
      forward = viser.transforms.SO3(np.asarray(wxyz, np.float64)).as_matrix()[:, 2]
      look_at = np.asarray(position, np.float64) + forward
    self._send(_messages.ViewerCameraMessage(
        tuple(float(x) for x in wxyz), tuple(float(x) for x in position), float(fov), 0.01,
        1000.0, int(height), int(width), tuple(float(x) for x in look_at),
        tuple(float(x) for x in up)))

  def set(self, label: str, value: Any) -> None:
    """Sets a control (slider, dropdown, button: True) by its label, as a user would."""
    self.wait_for(lambda: label in self.components, what=f"control {label!r}")
    with self._cond:  # the page shows its own change (the server echoes it to others only)
      self.components[label]["value"] = value
    self._send(_messages.GuiUpdateMessage(self.components[label]["uuid"], {"value": value}))

  def click(self, label: str) -> None:
    self.set(label, True)

  def upload(self, label: str, filename: str, data: bytes, part: int = 1 << 20) -> None:
    """Uploads `data` as file `filename` through the upload button `label`."""
    self.wait_for(lambda: label in self.components, what=f"control {label!r}")
    source, transfer = self.components[label]["uuid"], uuid.uuid4().hex
    parts = [data[i:i + part] for i in range(0, len(data), part)]
    self._send(_messages.FileTransferStartUpload(source, transfer, filename,
                                                 "application/octet-stream", len(parts),
                                                 len(data)))
    for i, content in enumerate(parts):
      self._send(_messages.FileTransferPart(source, transfer, i, content))

  def frame_count(self) -> int:
    with self._cond:
      return len(self.frames)

  def next_frame(self, after: int, timeout: float = 60.0) -> np.ndarray:
    """The first frame received after `after` frames (uint8 [H, W, 3])."""
    self.wait_for(lambda: len(self.frames) > after, timeout, "frame")
    with self._cond:
      return self.frames[after]

  def frame_of_size(self, height: int, width: int, after: int, timeout: float = 60.0
                    ) -> np.ndarray:
    """The first frame of that size received after `after` frames."""
    found = []

    def ready():
      found[:] = [f for f in self.frames[after:] if f.shape[:2] == (height, width)]
      return bool(found)
    self.wait_for(ready, timeout, f"{width}x{height} frame")
    return found[0]

  def close(self) -> None:
    try:
      self._ws.close()
    except Exception:  # pylint: disable=broad-except
      pass
    self._reader.join(5.0)
