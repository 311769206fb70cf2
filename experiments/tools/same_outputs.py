"""Checks that a refactor changed no result: the tiny demo (all three trainers, the stylized
dataset, the pipeline's renders) and three `msnerf render` calls (a training style, a blend,
an image file at a strength) run with the code of a git revision and with this checkout, then
every image, .gif frame, .npy array and the trained parameters are compared bit for bit.

  python experiments/tools/same_outputs.py REV [--work DIR]

Prints one line per difference and a summary; exits 1 if anything differs. About 4 minutes on
2 CPU cores.
"""

import argparse
import os
import subprocess
import sys
import tempfile

import imageio.v2 as imageio
import jax
import numpy as np

from msnerf_jax.kinds.runs import load_run

ROOT = os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))

TINY = ["--size", "16", "--views", "4", "--adain-steps", "2", "--adain-size", "16",
        "--nerf-steps", "4", "--nerf-batch-rays", "64", "--ms-steps", "3", "--ms-batch-rays", "32",
        "--frames", "4", "--grid-views", "2", "--no-progress"]


def run_all(code: str, out: str) -> None:
  """The demo and three renders with the package in `code`, outputs under `out`."""
  msnerf = lambda *argv: subprocess.run([sys.executable, "-m", "msnerf_jax", *argv], cwd=code,
                                        check=True, capture_output=True)
  msnerf("demo", "--out", os.path.join(out, "demo"), *TINY)
  run = os.path.join(out, "demo", "multistyle")
  style_dir = os.path.join(out, "demo", "inputs", "styles")
  style = sorted(os.listdir(style_dir))[0]
  common = ["--run", run, "--frames", "3"]
  msnerf("render", *common, "--out", os.path.join(out, "r1"), "--grid-steps", "3")
  msnerf("render", *common, "--out", os.path.join(out, "r2"), "--interp", "original",
         os.path.splitext(style)[0], "--t", "0.3", "--morph", "original",
         os.path.join(style_dir, style))
  msnerf("render", *common, "--out", os.path.join(out, "r3"), "--style",
         os.path.join(style_dir, style), "--strength", "0.5")


def read(path: str) -> np.ndarray:
  if path.endswith(".gif"):
    return np.stack(imageio.mimread(path))
  if path.endswith(".npy"):
    return np.load(path, allow_pickle=False)
  return np.asarray(imageio.imread(path))


def compare(a: str, b: str) -> list:
  """The differences between two output folders (compared files, trained params)."""
  found = []
  files = lambda root: {os.path.relpath(os.path.join(d, f), root)
                        for d, _, names in os.walk(root) for f in names
                        if f.endswith((".png", ".gif", ".npy")) and "checkpoints" not in d}
  in_a, in_b = files(a), files(b)
  found += [f"only in one: {p}" for p in sorted(in_a ^ in_b)]
  for rel in sorted(in_a & in_b):
    x, y = read(os.path.join(a, rel)), read(os.path.join(b, rel))
    if x.shape != y.shape or not np.array_equal(x, y):
      found.append(f"differs: {rel}")
  for kind in ("adain", "nerf", "multistyle", "features"):
    pa, pb = (jax.tree_util.tree_leaves(load_run(os.path.join(r, "demo", kind)).params)
              for r in (a, b))
    if len(pa) != len(pb) or not all(np.array_equal(x, y) for x, y in zip(pa, pb)):
      found.append(f"differs: {kind} parameters")
  print(f"compared {len(in_a & in_b)} files and the params of 4 runs")
  return found


def main():
  parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
  parser.add_argument("rev", help="git revision to compare this checkout with")
  parser.add_argument("--work", default=None, help="folder for both trees' outputs (default: temp)")
  args = parser.parse_args()
  work = args.work or tempfile.mkdtemp(prefix="same_outputs_")
  old_code = os.path.join(work, "code")
  os.makedirs(old_code, exist_ok=True)
  archive = subprocess.run(["git", "-C", ROOT, "archive", args.rev], check=True,
                           capture_output=True).stdout
  subprocess.run(["tar", "-x", "-C", old_code], input=archive, check=True)
  run_all(old_code, os.path.join(work, "old"))
  run_all(ROOT, os.path.join(work, "new"))
  found = compare(os.path.join(work, "old"), os.path.join(work, "new"))
  print("\n".join(found) or f"identical to {args.rev}")
  sys.exit(1 if found else 0)


if __name__ == "__main__":
  main()
