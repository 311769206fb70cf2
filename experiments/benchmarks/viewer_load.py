"""Load test of `msnerf view`: N clients (default 8) move their cameras at once for a bounded
time against a real server process on 127.0.0.1; the script prints the frames each client
got, the server's memory over time, and whether Ctrl-C stopped it cleanly.

Usage:
  python experiments/benchmarks/viewer_load.py --run RUN [--clients 8] [--seconds 120]

Each client drags its camera around the scene's render path (a camera message every 50 ms,
as a browser sends during a drag) for 2 s, rests 3 s, and so on, out of phase with the
others. Target (issue 18): every client keeps getting frames, the server's memory is flat
after the first minute, nothing crashes.
"""

import argparse
import collections
import os
import re
import signal
import subprocess
import sys
import threading
import time

import numpy as np

from msnerf_jax.kinds import runs
from msnerf_jax.viewer import camera as camera_lib
from msnerf_jax.viewer import probe as probe_lib


def rss_mb(pid: int) -> float:
  with open(f"/proc/{pid}/status") as f:
    for line in f:
      if line.startswith("VmRSS:"):
        return int(line.split()[1]) / 1024
  return float("nan")


def client_loop(url, poses, fov, full, index, stop_at, results):
  probe = probe_lib.Probe(url)
  phase = index * 0.61
  moves = 0
  try:
    step = index * len(poses) // 8
    while time.monotonic() < stop_at:
      moving = ((time.monotonic() + phase) % 5.0) < 2.0
      if moving or moves == 0:
        c2w = poses[step % len(poses)]
        wxyz, position = camera_lib.to_viser_pose(c2w)
        probe.camera(wxyz, position, fov, 800, 800)
        step += 1
        moves += 1
      time.sleep(0.05)
    sizes = [f.shape for f in probe.frames]
  finally:
    probe.close()
  results[index] = {"moves": moves, "frames": len(sizes),
                    "full": sum(1 for s in sizes if s[:2] == full),
                    "error": repr(probe.error) if probe.error and time.monotonic() < stop_at
                    else None, "times": probe.frame_times}


def main():
  parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
  parser.add_argument("--run", required=True)
  parser.add_argument("--clients", type=int, default=8)
  parser.add_argument("--seconds", type=float, default=120.0)
  args = parser.parse_args()
  scene = runs.run_scene(args.run)
  poses = scene.render_poses
  fov = camera_lib.vertical_fov(scene.K, scene.height)
  full = camera_lib.frame_size(1.0, scene.height * scene.width)  # at the clients' 800x800
  # -X faulthandler: a server that hangs is sent SIGABRT below and prints every thread's stack.
  server = subprocess.Popen([sys.executable, "-X", "faulthandler", "-m", "msnerf_jax", "view",
                             "--run", args.run, "--port", "0"], stdout=subprocess.PIPE,
                            stderr=subprocess.STDOUT, text=True)
  url = None
  for line in server.stdout:
    print("  server:", line.rstrip())
    found = re.search(r"serving .* at (http://[0-9.]+:\d+)", line)
    if found:
      url = found.group(1)
      break
  if url is None:
    sys.exit("the server did not start")
  tail = collections.deque(maxlen=300)  # the server's last lines
  threading.Thread(target=lambda: tail.extend(server.stdout), daemon=True).start()
  start = time.monotonic()
  stop_at = start + args.seconds
  results = {}
  threads = [threading.Thread(target=client_loop, args=(url, poses, fov, full, i, stop_at, results))
             for i in range(args.clients)]
  for t in threads:
    t.start()
  memory = []
  while time.monotonic() < stop_at and server.poll() is None:
    memory.append((time.monotonic() - start, rss_mb(server.pid)))
    time.sleep(1.0)
  for t in threads:
    t.join(30)
  alive = server.poll() is None
  server.send_signal(signal.SIGINT)
  try:
    code = server.wait(20)
  except subprocess.TimeoutExpired:
    server.send_signal(signal.SIGABRT)
    time.sleep(3)
    server.kill()
    code = "hung (killed); its last lines and stacks:\n" + "".join(tail)
  print(f"{args.clients} clients for {args.seconds:.0f} s on {os.cpu_count()} cores:")
  for i in sorted(results):
    r = results[i]
    times = np.array(r["times"])
    gap = np.diff(np.concatenate([times, [stop_at]])).max() if len(times) else float("inf")
    print(f"  client {i}: {r['moves']} camera moves, {r['frames']} frames ({r['full']} full), "
          f"first after {times[0] - start:.1f} s, longest wait {gap:.1f} s"
          + (f", error {r['error']}" if r["error"] else ""))
  t, mb = np.array([m[0] for m in memory]), np.array([m[1] for m in memory])
  first = mb[t <= 60]
  after = mb[t > 60]
  print(f"server memory (RSS): {mb[0]:.0f} MB at start, {first.max():.0f} MB peak in the first "
        f"minute" + (f", {after.min():.0f}-{after.max():.0f} MB after it (growth "
                     f"{after.max() - first.max():+.0f} MB)" if len(after) else "")
        + f", {mb.max():.0f} MB peak")
  print(f"server alive at the end: {alive}; exit after Ctrl-C: {code}")
  ok = (alive and code == 0 and len(results) == args.clients
        and all(r["frames"] > 0 and not r["error"] for r in results.values()))
  print("OK" if ok else "FAILED")
  sys.exit(0 if ok else 1)


if __name__ == "__main__":
  main()
