"""Lego at 100x100 (--downscale 8), preset `cpu`: PSNR on the 9 val views against training wall-clock.

Usage:
  python experiments/benchmarks/bench_lego_cpu.py [--minutes 30] [--eval-every 500]
      [--out runs/bench_lego_cpu]
      [--set key=value ...]   # NerfConfig overrides, e.g. --set net_width=64

Prints one line per evaluation: step, training seconds (evaluation excluded), val PSNR/SSIM,
and writes the table as JSON beside the run. Target (issue 2): >= 24 dB within 30 minutes
on a 2-core CPU.
"""

import argparse
import json
import os
import shutil

from msnerf_jax.eval import evaluate
from msnerf_jax.core.config import DataConfig, nerf_preset, override
from msnerf_jax.data.scene import load_scene
from msnerf_jax.train import nerf
from common import DATA, machine, parse_overrides
from timed_training import train_within


def main():
  parser = argparse.ArgumentParser(description=__doc__,
                                   formatter_class=argparse.RawDescriptionHelpFormatter)
  parser.add_argument("--data", default=os.path.join(DATA, "nerf_synthetic", "lego"))
  parser.add_argument("--minutes", type=float, default=30.0)
  parser.add_argument("--eval-every", type=int, default=500)
  parser.add_argument("--out", default="runs/bench_lego_cpu")
  parser.add_argument("--set", nargs="*", default=[], metavar="KEY=VALUE")
  args = parser.parse_args()

  scene, data_config = load_scene(DataConfig(path=args.data, downscale=8))
  config = nerf_preset("cpu", "blender", checkpoint_every=args.eval_every,
                       **parse_overrides(args.set, "cpu"))
  config = override(config, steps=10**6)
  shutil.rmtree(args.out, ignore_errors=True)
  print(f"# lego 100x100, preset cpu {config}")
  print(f"# machine: {machine()}")
  print(f"{'step':>7} {'train_s':>8} {'val_psnr':>9} {'val_ssim':>9}")
  rows, _ = train_within(
      args.minutes,
      lambda callback: nerf.train(scene, config, data_config, args.out, progress=False,
                                  callback=callback),
      lambda step, params: evaluate.evaluate_nerf(scene, params, config, "val",
                                                  progress=False)[1],
      lambda r: print(f"{r['step']:7d} {r['train_seconds']:8.1f} {r['psnr']:9.2f} "
                      f"{r['ssim']:9.4f}", flush=True))
  best = max(rows, key=lambda r: r["psnr"])
  within = [r for r in rows if r["train_seconds"] <= args.minutes * 60]
  print(f"# best val PSNR {best['psnr']:.2f} dB at step {best['step']} "
        f"({best['train_seconds']:.0f} s); within {args.minutes:g} min: "
        f"{max((r['psnr'] for r in within), default=float('nan')):.2f} dB")
  with open(os.path.join(args.out, "bench.json"), "w") as f:
    json.dump({"config": config.__dict__, "rows": rows}, f, indent=1)


if __name__ == "__main__":
  main()
