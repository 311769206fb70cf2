"""The NeRF presets against each other: held-out PSNR against training wall-clock, and the
rate of rendering one held-out view, for each (scene, preset), in one run.

Usage:
  python experiments/benchmarks/bench_presets.py [--scenes lego fern] [--presets cpu fast]
      [--minutes 10 15] [--eval-every 250] [--out runs/bench_presets]
      [--set PRESET:key=value ...]   # NerfConfig overrides of one preset

lego is nerf_synthetic/lego at 100x100 (--downscale 8), lego400 the same at 400x400
(--downscale 2) and lego800 at full size (the GPU target: 30 dB within 5 minutes), all
evaluated on their val views; fern is
nerf_llff_data/fern at factor 8 (NDC), evaluated on its held-out views (every 8th). Each
row: step, training seconds (evaluation excluded), PSNR, SSIM; each run ends with the time
of one 100x100 render (mean of 3 after a warm-up) and the best PSNR within the budget.
Writes everything to OUT/bench.json. Targets (issue 16): lego >= 27 dB within 10 minutes,
fern >= 23 dB within 15 minutes on the 2-core CPU; the fast preset renders a lego view
>= 5x faster than cpu, at equal or better PSNR.
"""

import argparse
import json
import os
import shutil
import time

from msnerf_jax.eval import evaluate
from msnerf_jax.core.config import DataConfig, nerf_preset, override
from msnerf_jax.data.scene import load_scene
from msnerf_jax.train import nerf
from msnerf_jax.kinds.views import render_view
from common import DATA, machine, parse_overrides
from timed_training import train_within

SCENES = {"lego": ("nerf_synthetic/lego", 8, "val"), "lego400": ("nerf_synthetic/lego", 2, "val"),
          "lego800": ("nerf_synthetic/lego", 1, "val"), "fern": ("nerf_llff_data/fern", 8, "test")}


def bench(scene_name, preset, minutes, args):
  folder, downscale, split = SCENES[scene_name]
  scene, data_config = load_scene(DataConfig(path=os.path.join(args.data, folder),
                                             downscale=downscale))
  config = nerf_preset(preset, scene.format, checkpoint_every=args.eval_every,
                       **parse_overrides(args.set, preset))
  config = nerf.resolve_config(override(config, steps=10 ** 6), scene)
  run_dir = os.path.join(args.out, f"{scene_name}_{preset}")
  shutil.rmtree(run_dir, ignore_errors=True)
  print(f"# {scene_name} {scene.height}x{scene.width}, preset {preset}: trunk {config.trunk}, "
        f"sampler {config.sampler}, {config.batch_rays} rays a step", flush=True)
  print(f"{'step':>7} {'train_s':>8} {'psnr':>7} {'ssim':>7}", flush=True)
  rows, params = train_within(
      minutes,
      lambda callback: nerf.train(scene, config, data_config, run_dir, progress=False,
                                  callback=callback),
      lambda step, params: evaluate.evaluate_nerf(scene, params, config, split,
                                                  progress=False)[1],
      lambda r: print(f"{r['step']:7d} {r['train_seconds']:8.1f} {r['psnr']:7.2f} "
                      f"{r['ssim']:7.4f}", flush=True))
  view = int(scene.split(split)[0])
  render_view(scene, params, config, view)  # compile
  t = time.time()
  for _ in range(3):
    render_view(scene, params, config, view)
  render_s = (time.time() - t) / 3
  within = [r["psnr"] for r in rows if r["train_seconds"] <= minutes * 60]
  best = max(within, default=float("nan"))
  print(f"# {scene_name} {preset}: best {split} PSNR within {minutes:g} min {best:.2f} dB; "
        f"render of one view {render_s:.3f} s", flush=True)
  return {"scene": scene_name, "preset": preset, "minutes": minutes, "rows": rows,
          "best_psnr": best, "render_seconds": render_s, "config": config.__dict__}


def main():
  parser = argparse.ArgumentParser(description=__doc__,
                                   formatter_class=argparse.RawDescriptionHelpFormatter)
  parser.add_argument("--data", default=DATA)
  parser.add_argument("--scenes", nargs="+", default=["lego", "fern"], choices=sorted(SCENES))
  parser.add_argument("--presets", nargs="+", default=["cpu", "fast"])
  parser.add_argument("--minutes", nargs="+", type=float, default=[10.0, 15.0],
                      help="training budget per scene, in the order of --scenes")
  parser.add_argument("--eval-every", type=int, default=250)
  parser.add_argument("--out", default="runs/bench_presets")
  parser.add_argument("--set", nargs="*", default=[], metavar="PRESET:KEY=VALUE")
  args = parser.parse_args()
  print(f"# machine: {machine()}", flush=True)
  results = []
  for scene_name, minutes in zip(args.scenes, args.minutes * len(args.scenes)):
    for preset in args.presets:
      results.append(bench(scene_name, preset, minutes, args))
  print("\n| scene | preset | best PSNR within budget | render one view | render speed-up |")
  print("|---|---|---|---|---|")
  for r in results:
    base = next((b for b in results if b["scene"] == r["scene"] and b["preset"] == "cpu"), r)
    print(f"| {r['scene']} | {r['preset']} | {r['best_psnr']:.2f} dB in {r['minutes']:g} min | "
          f"{r['render_seconds']:.3f} s | {base['render_seconds'] / r['render_seconds']:.1f}x |")
  os.makedirs(args.out, exist_ok=True)
  with open(os.path.join(args.out, "bench.json"), "w") as f:
    json.dump(results, f, indent=1)


if __name__ == "__main__":
  main()
