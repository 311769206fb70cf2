"""How well do the stylized views agree with each other? An upper bound for a 3D model.

  python experiments/studies/target_agreement/target_agreement.py --nerf NERF_RUN --stylized DIR \
      [--multistyle RUN]

Each held-out view t of the stylized dataset is predicted from the training views alone,
without any model: the `--neighbours` training cameras nearest to t are warped onto t with the
NeRF's rendered depth (msnerf_jax.eval.consistency.warp: lifted to 3D, reprojected, depth test,
opacity > 0.5 in both), and their colours are averaged per pixel. On the pixels that at least
one neighbour covers, the script reports the PSNR of
  nearest:   the nearest training view alone,
  average:   the average of the warped neighbours,
  model:     the multi-style run's render (with --multistyle),
for every style, and for the photos themselves (the "original" row: the error the warp and
the geometry add on their own). If the views of a style agreed as well as the photos do, its
rows would match the original's; how far they fall short is what no 3D-consistent model
trained on these views can recover. Writes OUT/results.md and .json (default: DIR/agreement)
and prints the hardware and wall time.
"""

import argparse
import json
import os
import platform
import sys
import time

import numpy as np
from tqdm.auto import tqdm

from msnerf_jax.eval import consistency
from msnerf_jax.kinds import views
from msnerf_jax.kinds.runs import load_run
from msnerf_jax.data.stylized import load_stylized
from msnerf_jax.train import multistyle


def masked_psnr(a: np.ndarray, b: np.ndarray, mask: np.ndarray) -> float:
  return float(-10.0 * np.log10(np.mean(np.square(a - b)[mask])))


def main():
  parser = argparse.ArgumentParser(description=__doc__,
                                   formatter_class=argparse.RawDescriptionHelpFormatter)
  parser.add_argument("--nerf", required=True, help="NeRF run (its depth drives the warps)")
  parser.add_argument("--stylized", required=True, help="stylized dataset folder")
  parser.add_argument("--multistyle", default=None, help="multi-style run to score alongside")
  parser.add_argument("--neighbours", type=int, default=4, help="training views per held-out view")
  parser.add_argument("--split", default=None, help="held-out split (default: val, else test)")
  parser.add_argument("--out", default=None, help="output folder (default: STYLIZED/agreement)")
  args = parser.parse_args()
  t0 = time.time()
  nerf_run, scene, _ = multistyle.load_nerf_run(args.nerf)
  data = load_stylized(args.stylized, progress=False)
  multistyle.check_compatible(data, scene, args.nerf)
  split = args.split or ("val" if len(scene.split("val")) else "test")
  held, train = scene.split(split), scene.split("train")
  ms_run = load_run(args.multistyle, "multistyle") if args.multistyle else None

  centres = scene.c2w[:, :, 3]
  geometry = {}

  def geo(i):
    if i not in geometry:
      geometry[i] = views.render_view(scene, nerf_run.params, nerf_run.config, int(i))
    return geometry[i]

  # Every style's view i on the channels of one image [H, W, 3M]: one warp per neighbour.
  stacked = lambda i: np.concatenate(list(data.images[:, i]), -1).astype(np.float32) / 255.0
  sums = {name: {"nearest": [], "average": [], "model": [], "coverage": []} for name in data.names}
  for t in tqdm(held, desc="held-out views"):
    near = train[np.argsort(np.linalg.norm(centres[train] - centres[t], axis=1))[:args.neighbours]]
    gt = geo(t)
    warps = [consistency.warp(stacked(s), gt["depth"], geo(s)["depth"], gt["accumulation"],
                              geo(s)["accumulation"], scene.c2w[t], scene.c2w[s], scene.K,
                              scene.ndc) for s in near]
    warped = np.stack([np.asarray(w) for w, _ in warps])           # [n, H, W, 3M]
    masks = np.stack([np.asarray(m) for _, m in warps])            # [n, H, W]
    covered = masks.any(0)
    if not covered.any():  # no neighbour sees this view's surface (e.g. an untrained NeRF)
      continue
    weights = masks[..., None].astype(np.float32)
    average = (warped * weights).sum(0) / np.maximum(weights.sum(0), 1.0)
    target = stacked(t)
    renders = (views.render_styles(scene, ms_run.params, ms_run.config, int(t),
                                   data.vectors)["rgb"] if ms_run else None)
    for m, name in enumerate(data.names):
      c = slice(3 * m, 3 * m + 3)
      row = sums[name]
      if masks[0].any():
        row["nearest"].append(masked_psnr(warped[0, ..., c], target[..., c], masks[0]))
      row["average"].append(masked_psnr(average[..., c], target[..., c], covered))
      row["coverage"].append(float(covered.mean()))
      if renders is not None:
        row["model"].append(masked_psnr(np.asarray(renders[m]), target[..., c], covered))

  if not sums[data.names[0]]["average"]:
    sys.exit(f"no {split} view has a surface that its neighbours see: is the NeRF trained?")
  rows = [{"style": name, **{k: float(np.mean(v)) for k, v in r.items() if v}}
          for name, r in sums.items()]
  columns = ["style", "nearest", "average"] + (["model"] if ms_run else []) + ["coverage"]
  lines = ["| " + " | ".join(columns) + " |", "|" + "---|" * len(columns)]
  lines += ["| " + " | ".join(r["style"] if c == "style" else f"{r[c]:.2f}" for c in columns)
            + " |" for r in rows]
  footer = (f"{len(sums[data.names[0]]['average'])} {split} views, {args.neighbours} "
            f"neighbours each, PSNR (dB) on the covered pixels; {time.time() - t0:.0f} s on "
            f"{os.cpu_count()} cores, {platform.machine()}")
  out = args.out or os.path.join(args.stylized, "agreement")
  os.makedirs(out, exist_ok=True)
  with open(os.path.join(out, "results.md"), "w") as f:
    f.write("\n".join(lines + ["", footer]) + "\n")
  with open(os.path.join(out, "results.json"), "w") as f:
    json.dump({"rows": rows, "split": split, "neighbours": args.neighbours,
               "nerf": os.path.abspath(args.nerf), "stylized": os.path.abspath(args.stylized),
               "multistyle": os.path.abspath(args.multistyle) if args.multistyle else None,
               "seconds": time.time() - t0}, f, indent=2)
  print("\n".join(lines))
  print(footer)


if __name__ == "__main__":
  main()
