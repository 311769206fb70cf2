"""How steady are the relu4_1 maps the decoder paints from, before it paints them?

  python experiments/studies/feature_map_consistency/feature_map_consistency.py \
      --features FEATURE_RUN [--frames 15] [--components 32] [--per-side 2] [--json OUT.json]

studies/feature_field/feature_field.py measures the decoded frames: along fern's path the
feature field's warped RMSE is 0.95-1.13x per-frame AdaIN's with a decoder fine-tuned on the
field. This script asks where that comes from. Along the same render path (same frames, same
NeRF depth for the warp, consistency.consistency) it compares the maps each method hands the
decoder:
  feature-field:   the field's rendered relu4_1 cells, normalised by the run's content
                   statistics (what stylize_features normalises);
  adain-per-frame: the encoder's relu4_1 cells of the NeRF's photo-real frame (enlarged by
                   the stylize scale, padded to whole cells as stylize_image does), normalised
                   by that frame's own statistics (what per-frame AdaIN normalises).
Both are projected onto the same top principal components (fitted on both methods' cells),
enlarged bilinearly to the frame's pixels (cell centres at 8i + 3.5 enlarged pixels), and
warped like frames. Figures: warped RMSE at k = 1 and 7 relative to the maps' RMS, for each
method, and the photo-real frames' own k = 1 RMSE, also relative to their standard deviation
(the warp's floor: view-dependent colour, occlusion edges, resampling). If the
field's maps change much less than the encoder's while the decoded frames change as much,
the decoder, not the field, is what changes between frames.
"""

import argparse
import json
import os
import platform
import time

import jax
import jax.numpy as jnp
import numpy as np
from tqdm.auto import tqdm

from msnerf_jax.style import adain
from msnerf_jax.eval import consistency
from msnerf_jax.style import transfer as stylize
from msnerf_jax.kinds import views
from msnerf_jax.data import images as images_lib
from msnerf_jax.style.features import CELL
from msnerf_jax.models import vgg
from msnerf_jax.kinds.runs import load_run, load_run_and_scene
from msnerf_jax.kinds.features import content_stats
def encoder_cells(encoder, rgb, scale):
  """relu4_1 [h, w, 512] of a frame enlarged `scale` x and padded to whole cells, normalised
  by its own channel statistics (per-frame AdaIN's content)."""
  h, w = rgb.shape[:2]
  big = images_lib.resize(rgb, h * scale, w * scale) if scale > 1 else rgb
  feats = adain.encode(encoder, jnp.asarray(stylize.pad_to_multiple(big))[None])["relu4_1"]
  mean, std = adain.channel_stats(feats)
  return np.asarray((feats - mean[:, None, None]) / std[:, None, None])[0]


def to_pixels(cells, basis, height, width, scale):
  """[h, w, 512] cells -> [height, width, K]: projected on basis [512, K], enlarged bilinearly
  (half-pixel centres) to the painted size, cropped to the enlarged frame, box-averaged to the
  frame's size (images_lib.resize's box filter, without its clip to [0, 1])."""
  ch, cw = cells.shape[:2]
  low = jnp.asarray(cells.reshape(-1, cells.shape[-1]) @ basis).reshape(ch, cw, -1)
  big = jax.image.resize(low, (ch * CELL, cw * CELL, low.shape[-1]), "bilinear")
  big = big[:height * scale, :width * scale]
  return np.asarray(big.reshape(height, scale, width, scale, -1).mean((1, 3)))


def main():
  parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
  parser.add_argument("--features", required=True, help="feature run (`msnerf features train`)")
  parser.add_argument("--frames", type=int, default=15, help="frames of the render path")
  parser.add_argument("--components", type=int, default=32,
                      help="principal components the maps are compared on")
  parser.add_argument("--per-side", type=int, default=2,
                      help="rays per cell side of the field's render (the renderer's is 2)")
  parser.add_argument("--json", default=None)
  args = parser.parse_args()
  t0 = time.time()
  run, scene = load_run_and_scene(args.features, "features")
  nerf = load_run(run.record["nerf_run"], "nerf")
  encoder = vgg.load_vgg_params()
  mean, std = content_stats(run)
  scale = run.config.stylize_scale
  poses = scene.render_poses[np.linspace(0, len(scene.render_poses) - 1, args.frames)
                             .round().astype(int)]
  base = [views.render_view(scene, nerf.params, nerf.config, c2w) for c2w in
          tqdm(poses, desc="NeRF path", leave=False)]
  cells = {
      "feature-field": [(views.render_feature_map(scene, run.params, run.config, c2w,
                                                   args.per_side)["features"]
                         - mean) / std for c2w in tqdm(poses, desc="feature path", leave=False)],
      "adain-per-frame": [encoder_cells(encoder, b["rgb"], scale) for b in base],
  }
  for method, maps in cells.items():
    shapes = {m.shape for m in maps}
    assert len(shapes) == 1, (method, shapes)
  # One basis for both: the top principal directions of all their cells.
  pooled = np.concatenate([m.reshape(-1, m.shape[-1]) for maps in cells.values() for m in maps])
  pooled = pooled - pooled.mean(0)
  _, _, vt = np.linalg.svd(pooled[::max(1, len(pooled) // 20000)], full_matrices=False)
  basis = vt[:args.components].T.astype(np.float32)
  geometry = ([b["depth"] for b in base], [b["accumulation"] for b in base], poses, scene.K,
              scene.ndc)
  result = {"run": os.path.abspath(args.features), "frames": args.frames,
            "components": args.components, "per_side": args.per_side, "methods": {}}
  for method, maps in cells.items():
    pixels = [to_pixels(m, basis, scene.height, scene.width, scale) for m in maps]
    rms = float(np.sqrt(np.mean(np.stack(pixels) ** 2)))
    row = {"rms": rms}
    for k in (1, 7):
      c = consistency.consistency(pixels, *geometry, k)
      row[f"rmse_k{k}"], row[f"relative_k{k}"] = c["rmse"], c["rmse"] / rms
    result["methods"][method] = row
  photos = [b["rgb"] for b in base]
  result["photo_rmse_k1"] = consistency.consistency(photos, *geometry, 1)["rmse"]
  result["photo_relative_k1"] = result["photo_rmse_k1"] / float(np.std(np.stack(photos)))
  ff, pf = result["methods"]["feature-field"], result["methods"]["adain-per-frame"]
  for k in (1, 7):
    result[f"ratio_k{k}"] = ff[f"relative_k{k}"] / pf[f"relative_k{k}"]
  result["hardware"] = (f"{platform.machine()}, {os.cpu_count()} cores, jax {jax.__version__} on "
                        f"{jax.default_backend()}")
  result["seconds"] = round(time.time() - t0)
  print(f"relu4_1 maps along {args.frames} frames, top {args.components} components, "
        f"{args.per_side}x{args.per_side} rays per field cell:")
  print("| method | map RMS | warped RMSE k=1 (relative) | k=7 (relative) |")
  print("|---|---|---|---|")
  for method, row in result["methods"].items():
    print(f"| {method} | {row['rms']:.3f} | {row['rmse_k1']:.3f} ({row['relative_k1']:.2f}) | "
          f"{row['rmse_k7']:.3f} ({row['relative_k7']:.2f}) |")
  print(f"field / per-frame, relative: k=1 {result['ratio_k1']:.2f}, k=7 {result['ratio_k7']:.2f}")
  print(f"photo-real frames, warped RMSE k=1: {result['photo_rmse_k1']:.4f} "
        f"({result['photo_relative_k1']:.2f} of their standard deviation)")
  print(f"{result['hardware']}; {result['seconds']} s")
  if args.json:
    os.makedirs(os.path.dirname(os.path.abspath(args.json)), exist_ok=True)
    with open(args.json, "w") as f:
      json.dump(result, f, indent=1)


if __name__ == "__main__":
  main()
