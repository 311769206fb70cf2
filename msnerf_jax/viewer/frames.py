"""Frames of a loaded run: what the viewer renders for one camera and one style, at one of
two levels (a quick low-resolution frame while the camera moves, the full one when it stops).

A frame is `render.render_image` of the camera's rays, cut into bands of one rendering chunk
so that a full frame can be abandoned between bands when a newer request arrives. Every band
is one jitted call of a fixed size per level, so a level compiles once (`warm_up`).

A feature run's frame is its feature map of the camera stylized and painted by its decoder
(its kind's style renderer, `kinds.features.style_renderer`: AdaIN in 3D): any style image, blends and strengths
at once; it is drawn whole (the decoder reads the whole map), so only the steps before and
after the feature render can be abandoned.
"""

import dataclasses
import threading
import time
from typing import Any, Callable, Dict, List, Mapping, Optional, Sequence, Tuple

import jax
import jax.numpy as jnp
import numpy as np

from msnerf_jax.nerf import baked as baked_render
from msnerf_jax.nerf import render as render_lib
from msnerf_jax.style import vectors as styles_lib
from msnerf_jax.data import images as images_lib
from msnerf_jax.data.scene import Scene
from msnerf_jax.data.stylized import ORIGINAL, style_name
from msnerf_jax.style.vectors import style_vector_of
from msnerf_jax.core.errors import UserError
from msnerf_jax.kinds import baked as baked_lib
from msnerf_jax.kinds.registry import get_kind
from msnerf_jax.kinds.renderers import painting_decoder
from msnerf_jax.kinds.runs import Run
from msnerf_jax.viewer import camera as camera_lib

LEVELS = ("low", "full")
LOW_LEVEL_DIVISOR = 16  # the low level has 1/16 of the pixels (a quarter of each side),
BAKED_LOW_LEVEL_DIVISOR = 4  # 1/4 (half of each side) when drawn from a baked scene.
MAX_UPLOAD_BYTES = 20 * 1024 * 1024
UPLOAD_MAX_SIDE = 1024  # an uploaded style image is decoded at most this large.


@dataclasses.dataclass(frozen=True)
class StyleChoice:
  """The style controls: style `a` blended towards `b` by t (0: a, 1: b), at `strength`
  between the original scene (0) and that blend (1). Names are keys of the style table."""
  a: str
  b: str
  t: float = 0.0
  strength: float = 1.0


@dataclasses.dataclass(frozen=True, eq=False)
class View:
  """A browser camera: viser pose (OpenCV wxyz [4], position [3]), vertical fov (radians),
  the viewport's aspect ratio (width / height) and its pixels (0: not known)."""
  wxyz: Tuple[float, ...]
  position: Tuple[float, ...]
  fov: float
  aspect: float
  pixels: int = 0


@dataclasses.dataclass(frozen=True, eq=False)
class Request:
  """One frame to draw: a view and a style vector [D] (None for a NeRF run)."""
  view: View
  style: Optional[np.ndarray]


class Frames:
  """Renders a loaded run's frames, from any thread; one band at a time (a lock).

  Attributes:
    run, scene: the loaded run and its scene.
    styles: name -> style vector [D] of the run's training styles (empty for a NeRF run).
    pixels: {"low": n, "full": n} pixel budgets of the two levels.
  """

  def __init__(self, run: Run, scene: Scene, style_paths: Sequence[str] = (),
               decoder_dir: Optional[str] = None, grids: Optional[int] = None,
               exact: bool = False, report: Callable[[str], Any] = print,
               full_side: Optional[int] = None):
    """style_paths: style images added to the style table (any run with styles); decoder_dir:
    the AdaIN run that paints a feature run (default: the one it was trained with); grids:
    the cell grids its full frames are painted on (views.render_feature_styles'; low frames,
    drawn while the camera moves, use one). A NeRF or multi-style run on the occupancy grid
    is drawn from its baked scene (kinds.baked, baked on first use), unless `exact`.
    full_side: full frames get up to full_side^2 pixels, shaped to the window and never more
    than its own (default: as many as the training images; low frames keep theirs)."""
    self.run, self.scene = run, scene
    self._painted_size = None  # what a style picture is cover-cropped to (feature runs).
    self._paint = None
    kind = get_kind(run.kind)
    if kind.nerf_config is None:
      raise UserError(f"{run.run_dir}: a {run.kind!r} run has no scene to view")
    self.config = kind.nerf_config(run.config)
    self.styles: Dict[str, np.ndarray] = {}
    if kind.style_table is not None:
      # A painting kind's "original" is the scene's own statistics: the strength slider
      # blends towards it.
      self.styles, self._painted_size = kind.style_table(run, scene)
    if kind.paints_any_style or kind.field is None:
      # Kinds drawn by their own style renderer (a feature run: low frames, drawn while the
      # camera moves, are painted on one cell grid; a painted run).
      decoder = painting_decoder(run, decoder_dir)
      self._paint = {level: kind.style_renderer(run, scene, None,
                                                1 if level == "low" else grids, decoder)
                     for level in LEVELS}
    else:
      self.field = kind.field(run.config)
    self.baked = None
    if not exact and self._paint is None and baked_lib.why_not_baked(run) is None:
      self.baked = jax.device_put(baked_lib.baked_scene(run, report))
    if style_paths and not self.styles:
      raise UserError(f"--styles: {run.run_dir} is a NeRF run, it has no styles")
    # Given style images first: the page opens in the first one (named for its file, apart
    # from a training style of that name).
    cache: Dict[str, Any] = {}
    given = {}
    for path in style_paths:
      name = style_name(path) if style_name(path) not in self.styles else path
      given[name] = styles_lib.resolve_style(path, self.styles, cache, self._painted_size)
    self.styles = {**given, **{k: v for k, v in self.styles.items() if k not in given}}
    self._encoder = cache.get("encoder")
    self.params = jax.device_put(run.params)
    self.pixels, self.chunks = self._budgets(full_side)
    # Re-entrant: between two bands the scheduler may draw other clients' low frames.
    self._lock = threading.RLock()

  def _budgets(self, full_side: Optional[int]) -> Tuple[Dict[str, int], Dict[str, int]]:
    """({level: pixels}, {level: rays a band}) of the two levels."""
    trained = self.scene.height * self.scene.width
    full = trained if full_side is None else full_side ** 2
    # A baked run's low frames have 1/4 of the pixels (half of each side): it draws them in
    # about the time the exact renderer draws 1/16.
    divisor = BAKED_LOW_LEVEL_DIVISOR if self.baked is not None else LOW_LEVEL_DIVISOR
    pixels = {"low": max(1, trained // divisor), "full": full}
    # Frame sizes round to the aspect ratio: a frame has at most pixels + 2 sqrt(pixels) + 1.
    slack = lambda n: n + 2 * int(np.ceil(np.sqrt(n))) + 1
    # One band for a low frame; a full frame in equal bands of at most render_chunk rays
    # (little padding in the last band).
    bands = -(-slack(full) // self.config.render_chunk)
    return pixels, {"low": slack(pixels["low"]), "full": -(-slack(full) // bands)}

  @property
  def has_styles(self) -> bool:
    return bool(self.styles)

  def style_vector(self, choice: StyleChoice, table: Mapping[str, np.ndarray]) -> np.ndarray:
    """The style vector [D] of the controls, names looked up in `table`."""
    vector = styles_lib.blend(table[choice.a], table[choice.b], choice.t)
    if ORIGINAL in table and choice.strength < 1.0:
      vector = styles_lib.blend(table[ORIGINAL], vector, choice.strength)
    return vector

  def upload_style(self, data: bytes, name: str) -> np.ndarray:
    """The style vector [D] of an uploaded image file's bytes.

    Raises:
      UserError (the message for the page) when the file is too large, not an image, or
      smaller than 16x16.
    """
    if len(data) > MAX_UPLOAD_BYTES:
      raise UserError(f"{name}: {len(data) / 2**20:.1f} MB, more than the "
                      f"{MAX_UPLOAD_BYTES // 2**20} MB a style image may have")
    image = images_lib.decode_image(data, name, max_side=UPLOAD_MAX_SIDE)
    if min(image.shape[:2]) < 16:
      raise UserError(f"{name}: style image is {image.shape[1]}x{image.shape[0]}, need at "
                      "least 16x16")
    with self._lock:
      if self._encoder is None:
        from msnerf_jax.models import vgg  # pylint: disable=g-import-not-at-top
        self._encoder = vgg.load_vgg_params()
      return style_vector_of(self._encoder, image, self._painted_size)

  def camera(self, view: View, level: str):
    """The library camera (cameras.Camera) of a view at a level's pixel budget (a full frame:
    at most the window's pixels)."""
    pixels = self.pixels[level]
    if level == "full" and view.pixels:
      pixels = max(self.pixels["low"], min(pixels, view.pixels))
    height, width = camera_lib.frame_size(view.aspect, pixels)
    return camera_lib.to_camera(view.wxyz, view.position, view.fov, height, width)

  def render(self, request: Request, level: str,
             cancelled: Callable[[], bool] = lambda: False) -> Optional[np.ndarray]:
    """The frame of a request at a level: uint8 [H, W, 3], or None when `cancelled()` became
    true between two bands."""
    if self._paint is not None:
      return self._render_features(request, level, cancelled)
    rays = self.scene.camera_rays(self.camera(request.view, level))
    shape = rays["origins"].shape[:-1]
    flat = {k: np.asarray(v).reshape(-1, *v.shape[len(shape):]) for k, v in rays.items()}
    styles = None if request.style is None else jnp.asarray(request.style, jnp.float32)[None]
    chunk = self.chunks[level]
    bands: List[np.ndarray] = []
    with self._lock:
      for start in range(0, flat["origins"].shape[0], chunk):
        if cancelled():
          return None
        band = {k: v[start:start + chunk] for k, v in flat.items()}
        if self.baked is not None:
          out = baked_render.render_baked_image(self.baked, self.field, self.params, band,
                                                self.config, self.scene.white_background,
                                                chunk, styles, shade_chunk=4 * chunk)
        else:
          out = render_lib.render_image(self.field, self.params, band, self.config,
                                        self.scene.white_background, chunk, styles)
        bands.append(out["rgb"] if styles is None else out["rgb"][0])
    return images_lib.to_uint8(np.concatenate(bands).reshape(*shape, 3))

  def _render_features(self, request: Request, level: str, cancelled: Callable[[], bool]
                       ) -> Optional[np.ndarray]:
    """The frame of a kind drawn by its style renderer (see render): a feature run's one
    feature render, AdaIN and decode; a painted run's colour fields, mixed."""
    with self._lock:
      if cancelled():
        return None
      frame = self._paint[level](self.camera(request.view, level), [request.style])[0]
    return None if cancelled() else images_lib.to_uint8(frame)

  def start_request(self) -> Request:
    """The first training view, in the first style (what a new page shows)."""
    view = self.view_of(self.scene.c2w[self.first_view()], self.scene.width / self.scene.height)
    return Request(view, self.style_vector(self.default_choice(), self.styles)
                   if self.has_styles else None)

  def first_view(self) -> int:
    views = self.scene.splits.get("train", np.arange(len(self.scene.c2w)))
    return int(views[0])

  def default_choice(self) -> StyleChoice:
    first = next(iter(self.styles))
    return StyleChoice(first, first)

  def view_of(self, c2w: np.ndarray, aspect: float) -> View:
    """The View of an OpenGL c2w [3, 4] seen with the scene's render camera."""
    wxyz, position = camera_lib.to_viser_pose(c2w)
    return View(tuple(wxyz), tuple(position), self.fov, aspect)

  @property
  def fov(self) -> float:
    """The render camera's vertical field of view (radians)."""
    return camera_lib.vertical_fov(self.scene.K, self.scene.height)

  def warm_up(self, report: Callable[[str], Any] = print) -> Dict[str, float]:
    """Compiles both levels (one frame each); returns the seconds each took."""
    seconds = {}
    for level in LEVELS:
      start = time.perf_counter()
      self.render(self.start_request(), level)
      seconds[level] = time.perf_counter() - start
      report(f"  {level} frames compiled ({seconds[level]:.1f} s)")
    return seconds
