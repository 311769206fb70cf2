"""Browser check of `msnerf view`: headless Chromium (the system's, driven by Playwright)
clicks through the page as a user would and compares what the page shows with
`render.render_image` of the same camera and style after every step:

  load      open the page, wait for the full frame
  orbit     drag the scene with the mouse
  style     choose another style in the menu
  strength  click the strength slider (the blend slider for a run without 'original')
  upload    upload a style image through the page's file input
  save      click "save view as PNG": the download, the saved file and the render agree

Each step's screenshot is compared with the expected frame scaled to the window (the page
draws the frame bilinearly; the control panel and the axes gizmo are masked): the mean
absolute difference must be small and well below the difference to the step before's frame,
so a step that showed a stale frame fails. Screenshots of every step land in --out.

Usage:
  python experiments/tools/viewer_browser.py --run RUN --out DIR [--style-image IMG]

Needs `pip install playwright` and a Chromium (Debian: `apt install chromium`; or set
CHROMIUM=/path/to/chrome). Exit code 0 when every step passed, 1 when one failed, 77 when
no browser is available (the reason printed).
"""

import argparse
import dataclasses
import importlib.util
import io
import os
import shutil
import sys
import tempfile
import time
from typing import Dict, List, Optional

import jax.numpy as jnp
import numpy as np
from PIL import Image

from msnerf_jax.data.images import to_uint8
from msnerf_jax.nerf import render as render_lib
from msnerf_jax.viewer import server as server_lib

SKIP = 77
# Mean absolute difference (0-255) a screenshot may have from its expected frame: the page's
# bilinear scaling against PIL's (measured: 0.1-0.4 on Debian's Chromium 156 with
# SwiftShader, where a stale frame differs by 23-67), and the largest fraction of the difference to the frame before.
TOLERANCE = 4.0
STALE_RATIO = 0.5
# Chromium as root in a closed network: no sandbox, no GPU, no background connections.
CHROMIUM_ARGS = ["--no-sandbox", "--disable-gpu", "--use-angle=swiftshader",
                 "--enable-unsafe-swiftshader", "--ignore-gpu-blocklist",
                 "--disable-background-networking", "--disable-component-update",
                 "--disable-sync", "--no-first-run"]


def chromium_path() -> Optional[str]:
  for path in (os.environ.get("CHROMIUM"), shutil.which("chromium"),
               shutil.which("chromium-browser"), shutil.which("google-chrome")):
    if path and os.path.exists(path):
      return path
  return None


def missing() -> Optional[str]:
  """Why the check cannot run here, or None."""
  if importlib.util.find_spec("playwright") is None:
    return "playwright is not installed (pip install playwright)"
  if chromium_path() is None:
    return "no Chromium found (apt install chromium, or set CHROMIUM)"
  return None


@dataclasses.dataclass
class Step:
  name: str
  error: float  # mean |screenshot - expected| (0-255) outside the panel
  stale: float  # the same against the step before's expected frame (nan for the first)
  problem: str = ""

  @property
  def ok(self) -> bool:
    return not self.problem


def expected_frame(frames, request) -> np.ndarray:
  """uint8 [H, W, 3]: render.render_image of the request's camera and style vector (the
  kind's own style renderer for kinds without a field: feature and painted runs)."""
  if getattr(frames, "field", None) is None:
    return frames.render(request, "full")
  camera = frames.camera(request.view, "full")
  styles = None if request.style is None else jnp.asarray(request.style, jnp.float32)[None]
  out = render_lib.render_image(frames.field, frames.params, frames.scene.camera_rays(camera),
                                frames.config, frames.scene.white_background,
                                frames.chunks["full"], styles)
  return to_uint8(out["rgb"] if styles is None else out["rgb"][0])


def page_difference(shot: np.ndarray, frame: np.ndarray, mask: np.ndarray) -> float:
  """Mean absolute difference (0-255) of a screenshot [H, W, 3] and a frame scaled to it,
  where mask [H, W] is true."""
  scaled = np.asarray(Image.fromarray(frame).resize((shot.shape[1], shot.shape[0]),
                                                     Image.BILINEAR), np.float32)
  return float(np.abs(shot.astype(np.float32) - scaled)[mask].mean())


class Page:
  """One browser tab on a viewer, with its single client on the server."""

  def __init__(self, browser, viewer, size=(1000, 700)):
    self.viewer, self.size = viewer, size
    self.page = browser.new_page(viewport={"width": size[0], "height": size[1]},
                                 accept_downloads=True)
    self.page.goto(viewer.url)
    self.client = self._wait(lambda: next(iter(viewer._clients), None), "a client")  # pylint: disable=protected-access
    self.settle()
    for close in self.page.locator(".mantine-Notification-closeButton").all():
      close.click()  # e.g. "Software WebGL rendering detected"
    time.sleep(1.0)  # its fade-out

  def _wait(self, get, what, timeout=120.0):
    deadline = time.time() + timeout
    while True:
      value = get()
      if value is not None and value is not False:
        return value
      if time.time() > deadline:
        raise TimeoutError(f"timed out waiting for {what}")
      time.sleep(0.05)

  def state(self):
    return self.viewer._clients[self.client]  # pylint: disable=protected-access

  def request(self):
    return self.viewer._current(self.state())  # pylint: disable=protected-access

  def settle(self, quiet=1.0):
    """Waits until the client's latest request has its full frame on the page and nothing
    changed for `quiet` seconds (the camera's damping sends updates after a drag)."""
    scheduler = self.viewer.scheduler
    while True:
      self._wait(lambda: scheduler.settled(self.client), "the full frame")
      view = self.state().view
      time.sleep(quiet)
      if scheduler.settled(self.client) and self.state().view == view:
        return

  def mask(self) -> np.ndarray:
    """Where the render shows: not under the control panel, a notification or the axes
    gizmo (bottom left)."""
    w, h = self.size
    mask = np.ones((h, w), bool)
    covers = (self.page.locator(".mantine-Paper-root").all()
              + self.page.locator(".mantine-Notification-root").all())
    for box in filter(None, (cover.bounding_box() for cover in covers)):
      x0, y0 = max(int(box["x"]) - 8, 0), max(int(box["y"]) - 8, 0)
      mask[y0:int(box["y"] + box["height"]) + 8, x0:int(box["x"] + box["width"]) + 8] = False
    mask[h - 90:, :90] = False
    return mask

  def screenshot(self, path: Optional[str] = None) -> np.ndarray:
    data = self.page.screenshot()
    if path:
      with open(path, "wb") as f:
        f.write(data)
    return np.asarray(Image.open(io.BytesIO(data)).convert("RGB"))

  def slider(self, index: int, at: float) -> None:
    track = self.page.locator(".mantine-Slider-root").nth(index).bounding_box()
    self.page.mouse.click(track["x"] + at * track["width"], track["y"] + track["height"] / 2)
    self.page.mouse.move(5, self.size[1] // 2)  # away, so no tooltip covers the panel

  def choose(self, label: str, option: str) -> None:
    """Picks an option of the dropdown labelled `label` as a user does: open, click."""
    self.page.get_by_label(label, exact=True).click()
    self.page.get_by_role("option", name=option, exact=True).click()
    self.page.mouse.move(5, self.size[1] // 2)

  def orbit(self) -> None:
    w, h = self.size
    self.page.mouse.move(w * 0.3, h * 0.5)
    self.page.mouse.down()
    self.page.mouse.move(w * 0.3 + 120, h * 0.5 - 30, steps=12)
    self.page.mouse.up()
    self.page.mouse.move(5, h // 2)


def run_steps(viewer, browser, out_dir: str, style_image: str,
              log=print) -> List[Step]:
  """Clicks through the page (see the module's docstring); returns every step's result."""
  page = Page(browser, viewer)
  frames = viewer.frames
  has_styles = frames.has_styles
  steps: List[Step] = []
  previous: Dict[str, np.ndarray] = {}

  def check(name: str, changed=True) -> None:
    page.settle()
    time.sleep(0.5)  # the page draws it
    request = page.request()
    expected = expected_frame(frames, request)
    shot = page.screenshot(os.path.join(out_dir, f"{len(steps):02d}_{name}.png"))
    mask = page.mask()
    error = page_difference(shot, expected, mask)
    stale = (page_difference(shot, previous["frame"], mask)
             if "frame" in previous and previous["frame"].shape == expected.shape
             else float("nan"))
    problem = ""
    if error > TOLERANCE:
      problem = f"the page differs from render_image by {error:.1f} > {TOLERANCE}"
    elif changed and "frame" in previous and np.array_equal(expected, previous["frame"]):
      problem = "the step did not change the frame"
    elif changed and np.isfinite(stale) and error > STALE_RATIO * stale:
      problem = f"the page is as close to the frame before ({stale:.1f}) as to this one"
    steps.append(Step(name, error, stale, problem))
    log(f"  {name:9s} {expected.shape[1]}x{expected.shape[0]} frame: "
        f"page - render {error:5.2f}, page - frame before "
        f"{stale:5.2f}  {'ok' if not problem else 'FAILED: ' + problem}")
    previous["frame"] = expected

  check("load", changed=False)
  page.orbit()
  check("orbit")
  if has_styles:
    names = list(frames.styles)
    current = page.state().gui["style"].value
    other = next((n for n in names if n != current and n != "original"), None)
    if other is not None:
      page.choose("style", other)
      check("style")
    strength = "original" in frames.styles
    page.slider(1 if strength else 0, 0.3 if strength else 0.7)
    check("strength" if strength else "blend")
    if "upload" in page.state().gui:
      page.page.locator('input[type="file"]').set_input_files(style_image)
      page._wait(lambda: page.state().gui["style"].value.startswith(  # pylint: disable=protected-access
          server_lib.UPLOAD_PREFIX), "the uploaded style in the menu")
      check("upload")
  saved_before = set(os.listdir(viewer.out_dir)) if os.path.isdir(viewer.out_dir) else set()
  request = page.request()
  with page.page.expect_download() as download:
    page.page.get_by_role("button", name="save view as PNG").click()
  data = open(download.value.path(), "rb").read()
  new = sorted(set(os.listdir(viewer.out_dir)) - saved_before)
  saved = open(os.path.join(viewer.out_dir, new[0]), "rb").read() if len(new) == 1 else b""
  png = np.asarray(Image.open(io.BytesIO(data)).convert("RGB"))
  expected = expected_frame(frames, request)
  error = (float(np.abs(png.astype(int) - expected).max())
           if png.shape == expected.shape else float("inf"))
  problem = ("" if len(new) == 1 and data == saved and error <= 1 else
             f"download {len(data)} bytes, {len(new)} new files, max difference {error}")
  steps.append(Step("save", error, float("nan"), problem))
  log(f"  save      {download.value.suggested_filename}: download = {new}, PNG - render max "
      f"{error:.0f}  {'ok' if not problem else 'FAILED: ' + problem}")
  return steps


def main():
  parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
  parser.add_argument("--run", required=True)
  parser.add_argument("--out", required=True, help="folder for the screenshots")
  parser.add_argument("--style-image", default=None,
                      help="the image to upload (default: a generated striped picture)")
  args = parser.parse_args()
  reason = missing()
  if reason:
    print(f"skipped: {reason}")
    sys.exit(SKIP)
  os.makedirs(args.out, exist_ok=True)
  style_image = args.style_image
  if style_image is None:
    style_image = os.path.join(args.out, "uploaded_style.png")
    stripes = (np.indices((64, 64)).sum(0) // 8 % 2)[..., None] * np.array([230, 180, 20])
    Image.fromarray((stripes + 20).astype(np.uint8)).save(style_image)
  from playwright.sync_api import sync_playwright  # pylint: disable=g-import-not-at-top
  viewer = server_lib.open_viewer(args.run, tempfile.mkdtemp(prefix="msnerf_browser_"),
                                  port=0, log=print)
  try:
    with sync_playwright() as p:
      browser = p.chromium.launch(executable_path=chromium_path(), headless=True,
                                  args=CHROMIUM_ARGS)
      try:
        steps = run_steps(viewer, browser, args.out, style_image)
      finally:
        browser.close()
  finally:
    viewer.stop()
  failed = [s.name for s in steps if not s.ok]
  print(f"{len(steps) - len(failed)} of {len(steps)} steps passed"
        + (f"; failed: {', '.join(failed)}" if failed else "") + f"; screenshots in {args.out}")
  sys.exit(1 if failed else 0)


if __name__ == "__main__":
  main()
