"""Browser check of `msnerf view`: headless Chromium (the system's, driven by Playwright)
opens the page, waits for the full frame, clicks a slider (strength, else blend) as
a user would, and waits for the new frame; the two screenshots must differ where the render is.

Usage:
  python experiments/tools/viewer_browser.py --run RUN
      [--out experiments/figures/viewer_browser.png]

Needs `pip install playwright` and a Chromium (Debian: `apt install chromium`; or set
CHROMIUM=/path/to/chrome). Prints the mean pixel change and writes both screenshots side by
side. Exit code 0 when the render changed, 1 when not, 77 when no browser is available.
"""

import argparse
import importlib.util
import io
import os
import shutil
import sys
import time

import numpy as np
from PIL import Image

from msnerf_jax.viewer import server as server_lib

SKIP = 77


def chromium_path():
  for path in (os.environ.get("CHROMIUM"), shutil.which("chromium"),
               shutil.which("chromium-browser"), shutil.which("google-chrome")):
    if path and os.path.exists(path):
      return path
  return None


def full_frames(viewer):
  return sum(n for (_, level), n in viewer.scheduler.frames.items() if level == "full")


def wait_for_full(viewer, after, timeout=120.0):
  deadline = time.time() + timeout
  while full_frames(viewer) <= after:
    if time.time() > deadline:
      raise TimeoutError("no full frame reached the page")
    time.sleep(0.1)
  time.sleep(1.0)  # the page draws it


def check(viewer, out_png=None, size=(1000, 700)):
  """Returns the mean absolute change (0-255) of the screenshots in the render's area."""
  from playwright.sync_api import sync_playwright  # pylint: disable=g-import-not-at-top
  with sync_playwright() as p:
    browser = p.chromium.launch(executable_path=chromium_path(), headless=True,
                                args=["--use-angle=swiftshader", "--enable-unsafe-swiftshader",
                                      "--ignore-gpu-blocklist"])
    try:
      page = browser.new_page(viewport={"width": size[0], "height": size[1]})
      before = full_frames(viewer)
      page.goto(viewer.url)
      wait_for_full(viewer, before)
      before = full_frames(viewer)
      for close in page.locator(".mantine-Notification-closeButton").all():
        close.click()  # e.g. "Software WebGL rendering detected"
      time.sleep(1.0)  # its fade-out
      first = Image.open(io.BytesIO(page.screenshot()))
      # A slider clicked with the mouse (arrow keys would also reach the page's keyboard
      # camera controls): strength at 5% (towards the original scene) when the run has an
      # original style, else the blend slider (the panel's first) at 80%.
      sliders = page.locator(".mantine-Slider-root")
      strength = viewer.frames.styles and "original" in viewer.frames.styles
      track = sliders.nth(1 if strength else 0).bounding_box()
      at = 0.05 if strength else 0.8
      page.mouse.click(track["x"] + at * track["width"], track["y"] + track["height"] / 2)
      page.mouse.move(5, size[1] - 5)  # away, so no tooltip covers the panel
      wait_for_full(viewer, before)
      second = Image.open(io.BytesIO(page.screenshot()))
    finally:
      browser.close()
  a = np.asarray(first.convert("RGB"), np.float32)
  b = np.asarray(second.convert("RGB"), np.float32)
  # The render fills the page behind the control panel (on the right): compare the left.
  change = float(np.abs(a - b)[:, : int(a.shape[1] * 0.6)].mean())
  if out_png:
    side = Image.new("RGB", (first.width * 2 + 10, first.height), "white")
    side.paste(first.convert("RGB"), (0, 0))
    side.paste(second.convert("RGB"), (first.width + 10, 0))
    side.save(out_png)
  return change


def main():
  parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
  parser.add_argument("--run", required=True)
  parser.add_argument("--out", default=None, help="PNG of the two screenshots side by side")
  args = parser.parse_args()
  if importlib.util.find_spec("playwright") is None:
    print("skipped: playwright is not installed (pip install playwright)")
    sys.exit(SKIP)
  if chromium_path() is None:
    print("skipped: no Chromium found (apt install chromium, or set CHROMIUM)")
    sys.exit(SKIP)
  viewer = server_lib.open_viewer(args.run, "/tmp/msnerf_viewer_browser", port=0, log=print)
  try:
    change = check(viewer, args.out)
  finally:
    viewer.stop()
  print(f"mean change of the render area after moving the slider: {change:.1f} / 255")
  if args.out:
    print(f"screenshots: {args.out}")
  sys.exit(0 if change > 1.0 else 1)


if __name__ == "__main__":
  main()
