"""The multi-style model on each NeRF trunk, at the same training time (issue 16): the heads'
mean PSNR over the stylized dataset's styles on the held-out views against their training
wall-clock, for every NeRF run given, in one run.

Usage:
  python experiments/benchmarks/bench_trunk_multistyle.py --nerf NERF_RUN [NERF_RUN ...] \
      --stylized DIR [--minutes 10] [--eval-every 250] [--out runs/bench_trunk_multistyle]

Each NeRF run (e.g. `bench_presets.py --presets cpu fast`'s lego runs, trained for the same
time) gets fresh multi-style heads (the standard variant, default MultistyleConfig) on the same
stylized dataset. Every `--eval-every` steps the heads are evaluated on the dataset's val views
in every style (`evaluate.evaluate_multistyle`, time not counted); training stops at the first
evaluation past `--minutes`. Each row: step, training seconds, mean PSNR and SSIM over the
styles, PSNR per style. The table at the end gives each trunk's best mean PSNR within the budget
and the mean training step time. Writes OUT/bench.json and OUT/frames.png (rows: the stylized
target, then each run's heads at the end of their budget; per style, the first two val views).
Target (issue 16): the fast trunk's mean PSNR no lower than the MLP trunk's of the same
training time.
"""

import argparse
import json
import os
import shutil

import numpy as np

from msnerf_jax.eval import evaluate
from msnerf_jax.kinds import runs
from msnerf_jax.data import video
from msnerf_jax.core.config import MultistyleConfig, override
from msnerf_jax.data.images import write_image
from msnerf_jax.data.stylized import load_stylized
from msnerf_jax.train import multistyle
from msnerf_jax.kinds.views import render_styles
from common import machine
from timed_training import train_within


def bench(nerf_dir, stylized, minutes, args):
  nerf_run, scene = runs.load_run_and_scene(nerf_dir, "nerf")
  config = override(MultistyleConfig(nerf=nerf_run.config), steps=10 ** 6,
                    checkpoint_every=args.eval_every, keep_checkpoints=1)
  nerf_psnr = evaluate.evaluate_nerf(scene, nerf_run.params, nerf_run.config, "val",
                                     progress=False)[1]["psnr"]
  name = os.path.basename(os.path.normpath(nerf_dir))
  run_dir = os.path.join(args.out, name)
  shutil.rmtree(run_dir, ignore_errors=True)
  print(f"# {name}: trunk {nerf_run.config.trunk}, sampler {nerf_run.config.sampler}, NeRF val "
        f"PSNR {nerf_psnr:.2f} dB; heads on {len(stylized.names)} styles, "
        f"{config.batch_rays} rays a step", flush=True)
  print(f"{'step':>7} {'train_s':>8} {'psnr':>7} {'ssim':>7}  " +
        " ".join(f"{s[:12]:>12}" for s in stylized.names), flush=True)

  def figures(step, params):
    means = evaluate.evaluate_multistyle(scene, stylized, params, config, "val",
                                         progress=False)[1]
    return {**means["mean"], "per_style": {s: means[s]["psnr"] for s in stylized.names}}

  rows, params = train_within(
      minutes,
      lambda callback: multistyle.train(config, nerf_dir, stylized, run_dir, progress=False,
                                        callback=callback),
      figures,
      lambda r: print(f"{r['step']:7d} {r['train_seconds']:8.1f} {r['psnr']:7.2f} "
                      f"{r['ssim']:7.4f}  " + " ".join(f"{r['per_style'][s]:12.2f}"
                                                       for s in stylized.names), flush=True))
  views = scene.split("val")[:2]
  frames = [render_styles(scene, params, config, int(v), stylized.vectors)["rgb"]
            for v in views]  # [K, H, W, 3] each
  within = [r for r in rows if r["train_seconds"] <= minutes * 60] or rows[:1]
  best = max(within, key=lambda r: r["psnr"])
  last = rows[-1]
  step_s = last["train_seconds"] / last["step"]
  print(f"# {name}: best mean PSNR within {minutes:g} min {best['psnr']:.2f} dB (step "
        f"{best['step']}); {step_s:.3f} s a step", flush=True)
  return {"nerf": nerf_dir, "name": name, "trunk": nerf_run.config.trunk,
          "sampler": nerf_run.config.sampler, "nerf_val_psnr": nerf_psnr, "minutes": minutes,
          "rows": rows, "best": best, "step_seconds": step_s,
          "frames": [[np.clip(f[m], 0, 1) for f in frames] for m in range(len(stylized.names))],
          "views": [int(v) for v in views]}


def main():
  parser = argparse.ArgumentParser(description=__doc__,
                                   formatter_class=argparse.RawDescriptionHelpFormatter)
  parser.add_argument("--nerf", nargs="+", required=True, help="NeRF run folders")
  parser.add_argument("--stylized", required=True, help="stylized dataset of their scene")
  parser.add_argument("--minutes", type=float, default=10.0)
  parser.add_argument("--eval-every", type=int, default=250)
  parser.add_argument("--out", default="runs/bench_trunk_multistyle")
  args = parser.parse_args()
  print(f"# machine: {machine()}", flush=True)
  stylized = load_stylized(args.stylized, progress=False)
  results = [bench(path, stylized, args.minutes, args) for path in args.nerf]
  print(f"\n| NeRF run | trunk | sampler | NeRF val PSNR | heads: s a step | mean PSNR over "
        f"{len(stylized.names)} styles within {args.minutes:g} min | step |")
  print("|---|---|---|---|---|---|---|")
  for r in results:
    print(f"| {r['name']} | {r['trunk']} | {r['sampler']} | {r['nerf_val_psnr']:.2f} dB | "
          f"{r['step_seconds']:.3f} | {r['best']['psnr']:.2f} dB | {r['best']['step']} |")
  os.makedirs(args.out, exist_ok=True)
  views = results[0]["views"]
  target = [[stylized.images[m, v].astype(np.float32) / 255.0 for v in views]
            for m in range(len(stylized.names))]
  figure = video.labelled_grid([target] + [r.pop("frames") for r in results],
                               ["target"] + [f"{r['trunk']} trunk" for r in results],
                               list(stylized.names))
  write_image(os.path.join(args.out, "frames.png"), figure)
  print(f"# figure: {os.path.join(args.out, 'frames.png')}")
  with open(os.path.join(args.out, "bench.json"), "w") as f:
    json.dump(results, f, indent=1)


if __name__ == "__main__":
  main()
