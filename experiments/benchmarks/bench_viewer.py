"""Viewer latency: how long after a camera move the page gets its low-resolution frame and
its full frame, and after a slider change its new full frame, measured through the real
server and protocol (msnerf_jax.viewer.probe as the browser), against the same frames
rendered directly in the same run.

Usage:
  python experiments/benchmarks/bench_viewer.py --run RUN [--moves 20] [--exact] [--full-side N]

RUN: a NeRF or multi-style run folder (the issue's target: a lego 100x100 multi-style run).
Targets (issue 18, 2-core CPU): low frame < 0.3 s after a move, full 100x100 frame < 2 s.
"""

import argparse
import os
import platform
import time

import jax
import numpy as np

from msnerf_jax.viewer import probe as probe_lib
from msnerf_jax.viewer.frames import Request
from msnerf_jax.viewer import server as server_lib


def median_max(values):
  return f"median {np.median(values):.3f} s, max {np.max(values):.3f} s"


def main():
  parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
  parser.add_argument("--run", required=True)
  parser.add_argument("--moves", type=int, default=20)
  parser.add_argument("--width", type=int, default=800, help="the page's viewport")
  parser.add_argument("--height", type=int, default=800)
  parser.add_argument("--exact", action="store_true",
                      help="draw with the exact renderer, not a fast run's baked scene")
  parser.add_argument("--full-side", type=int, default=None,
                      help="full frames of up to N x N pixels at the viewport's shape "
                           "(`msnerf view --full-side`; default: the training images' size)")
  args = parser.parse_args()
  print(f"# {platform.machine()} {os.cpu_count()} cores, jax {jax.__version__}, "
        f"{jax.devices()[0].platform}; run {args.run}")
  viewer = server_lib.open_viewer(args.run, "/tmp/msnerf_bench_viewer", port=0, log=print,
                                  exact=args.exact, full_side=args.full_side)
  frames = viewer.frames
  scene = frames.scene
  poses = scene.render_poses
  views = [frames.view_of(poses[i * len(poses) // args.moves], args.width / args.height)
           for i in range(args.moves)]
  # Baseline: the same frames rendered directly, no server.
  direct = {level: [] for level in ("low", "full")}
  for view in views[:5]:
    request = Request(view, frames.start_request().style)
    for level in direct:
      start = time.perf_counter()
      frames.render(request, level)
      direct[level].append(time.perf_counter() - start)
  sizes = {level: frames.camera(views[0], level) for level in ("low", "full")}
  for level, seconds in direct.items():
    print(f"direct render, {level} {sizes[level].width}x{sizes[level].height}: "
          f"{median_max(seconds)}")

  probe = probe_lib.Probe(viewer.url)
  low_s, full_s, style_s = [], [], []
  try:
    probe.camera(views[0].wxyz, views[0].position, views[0].fov, args.width, args.height)
    probe.wait_for(lambda: "frame" in probe.components, 60, "controls")
    probe.frame_of_size(sizes["full"].height, sizes["full"].width, 0)
    for view in views[1:]:
      n = probe.frame_count()
      start = time.perf_counter()
      probe.camera(view.wxyz, view.position, view.fov, args.width, args.height)
      probe.frame_of_size(sizes["low"].height, sizes["low"].width, n)
      low_s.append(time.perf_counter() - start)
      probe.frame_of_size(sizes["full"].height, sizes["full"].width, n)
      full_s.append(time.perf_counter() - start)
    if frames.has_styles:
      names = list(frames.styles)
      for i in range(6 if len(names) > 1 else 0):
        n = probe.frame_count()
        start = time.perf_counter()
        probe.set("style", names[(i + 1) % len(names)])  # differs from the current one
        probe.frame_of_size(sizes["full"].height, sizes["full"].width, n)
        style_s.append(time.perf_counter() - start)
  finally:
    probe.close()
    viewer.stop()
  print(f"through the server, {len(low_s)} camera moves at {args.width}x{args.height}:")
  print(f"  low frame after a move:  {median_max(low_s)}  (target < 0.3 s)")
  print(f"  full frame after a move: {median_max(full_s)}  (target < 2 s; includes the "
        f"{viewer.scheduler._settle:.2f} s the camera must rest)")  # pylint: disable=protected-access
  if style_s:
    print(f"  full frame after a style change: {median_max(style_s)}")


if __name__ == "__main__":
  main()
