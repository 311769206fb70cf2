"""Evaluates an AdaIN decoder on held-out content: style loss of outputs vs unstylized content, grid PNG.

For every held-out content image (RUN_DIR/holdout.txt, written by `msnerf adain train
--holdout-every N`) and every style image, both centre-cropped/cover-cropped to SIZE x SIZE:

  style loss (output)  = sum over relu1_1..relu4_1 of MSE(mean) + MSE(std), output vs style
  style loss (content) = the same for the unstylized content vs the style

and prints their means and ratio (target: below 0.25). Content is kept recognisable when the
content loss (relu4_1 of the output vs the AdaIN target) is small and the edges of output and
content correlate: the script prints the mean Pearson correlation of their Sobel gradient
magnitudes (1 = same edges, ~0 for unrelated images), and writes a grid PNG
(row 1: the styles; then per content: content | outputs).

  python experiments/tools/eval_adain.py --decoder /work/runs/adain_cpu --grid docs/adain_grid.png
"""

import argparse
import json
import os
import sys
import time

import jax
import jax.numpy as jnp
import numpy as np

from msnerf_jax.style import adain as adain_lib
from msnerf_jax.kinds import stylized_scenes
from msnerf_jax.style import transfer as stylize_lib
from msnerf_jax.core import files
from msnerf_jax.data import images as images_lib
from msnerf_jax.models import decoder as decoder_lib
from msnerf_jax.models import vgg


def centre_square(image: np.ndarray, size: int) -> np.ndarray:
  """Resize the shorter side to `size`, then centre-crop size x size."""
  return stylize_lib.cover_crop(image, size, size)


def edge_correlation(a: np.ndarray, b: np.ndarray) -> float:
  """Pearson correlation of the Sobel gradient magnitudes of two images' luminance."""
  def grad(x):
    g = x @ np.array([0.299, 0.587, 0.114], np.float32)
    gx = g[1:-1, 2:] - g[1:-1, :-2]
    gy = g[2:, 1:-1] - g[:-2, 1:-1]
    return np.sqrt(gx ** 2 + gy ** 2).ravel()
  ga, gb = grad(a), grad(b)
  return float(np.corrcoef(ga, gb)[0, 1])


def pick_holdout(paths, per_folder):
  """At most `per_folder` held-out files per folder, evenly spaced."""
  by_folder = {}
  for p in paths:
    by_folder.setdefault(os.path.dirname(p), []).append(p)
  picked = []
  for folder in sorted(by_folder):
    group = by_folder[folder]
    idx = np.linspace(0, len(group) - 1, min(per_folder, len(group))).round().astype(int)
    picked += [group[i] for i in sorted(set(idx))]
  return picked


def main():
  parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
  parser.add_argument("--decoder", required=True, help="AdaIN run folder")
  parser.add_argument("--styles", help="style folder (default: the run's)")
  parser.add_argument("--size", type=int, default=256, help="evaluation crop side")
  parser.add_argument("--per-folder", type=int, default=4,
                      help="at most this many held-out images per content folder")
  parser.add_argument("--grid", default="adain_eval_grid.png", help="grid PNG to write")
  parser.add_argument("--grid-styles", type=int, default=5, help="styles shown in the grid")
  parser.add_argument("--grid-rows", type=int, default=4, help="content rows in the grid")
  parser.add_argument("--cell", type=int, default=192, help="grid cell side in pixels")
  parser.add_argument("--json", help="also write the numbers here")
  args = parser.parse_args()

  decoder = stylized_scenes.load_decoder(args.decoder)
  record = json.load(open(os.path.join(args.decoder, "run.json")))
  holdout_file = os.path.join(args.decoder, "holdout.txt")
  held = [l.strip() for l in open(holdout_file) if l.strip()] if os.path.exists(holdout_file) else []
  if not held:
    sys.exit(f"{holdout_file}: no held-out content (train with --holdout-every N)")
  trained_on = set()
  for folder in record["content"]:
    trained_on.update(images_lib.list_images(folder))
  trained_on -= set(held)
  contents_paths = pick_holdout(held, args.per_folder)
  assert not set(contents_paths) & trained_on
  style_paths = images_lib.list_images(args.styles or record["styles"])
  enc = vgg.load_vgg_params()
  s = args.size

  contents = np.stack([centre_square(images_lib.read_image(p), s) for p in contents_paths])
  styles = np.stack([stylize_lib.cover_crop(images_lib.read_image(p, max_side=4 * s), s, s)
                     for p in style_paths])

  stats_fn = jax.jit(lambda x: adain_lib.style_stats(enc, x))
  upsample = decoder.config.upsample

  @jax.jit
  def stylize_all(content, s_mean, s_std):
    """content [1, S, S, 3], style stats [K, 512] -> outputs [K, S, S, 3], content loss [K]."""
    feats = adain_lib.encode(enc, content)["relu4_1"]
    target = adain_lib.adain_from_stats(jnp.repeat(feats, s_mean.shape[0], 0), s_mean, s_std)
    out = jnp.clip(decoder_lib.Decoder(upsample).apply(decoder.params, target), 0.0, 1.0)
    out_feats = adain_lib.encode(enc, out)
    content_loss = jnp.mean(jnp.square(out_feats["relu4_1"] - target), axis=(1, 2, 3))
    return out, content_loss

  t0 = time.time()
  style_stats = [stats_fn(x[None]) for x in styles]
  style_stats = {name: (jnp.concatenate([st[name][0] for st in style_stats]),
                        jnp.concatenate([st[name][1] for st in style_stats]))
                 for name in vgg.STYLE_LAYERS}

  def per_style_loss(stats):
    """[K] style losses of images with `stats` (batch 1 or K) against each style."""
    return np.array([float(adain_lib.style_loss(
        {n: (stats[n][0][min(k, stats[n][0].shape[0] - 1)][None],
             stats[n][1][min(k, stats[n][1].shape[0] - 1)][None]) for n in stats},
        {n: (style_stats[n][0][k][None], style_stats[n][1][k][None]) for n in style_stats}))
        for k in range(len(styles))])

  loss_out, loss_content, content_losses, edges, outputs = [], [], [], [], []
  for i, content in enumerate(contents):
    out, c_loss = stylize_all(jnp.asarray(content[None]), *style_stats["relu4_1"])
    out = np.asarray(out)
    out_stats = stats_fn(out)
    loss_out.append(per_style_loss(out_stats))
    loss_content.append(per_style_loss(stats_fn(content[None])))
    content_losses.append(np.asarray(c_loss))
    edges.append([edge_correlation(o, content) for o in out])
    outputs.append(out)
    print(f"  {os.path.relpath(contents_paths[i], os.path.dirname(os.path.dirname(contents_paths[i])))}: "
          f"style loss output {loss_out[-1].mean():.3f} vs content {loss_content[-1].mean():.3f}")
  loss_out, loss_content = np.array(loss_out), np.array(loss_content)
  ratio = loss_out.mean() / loss_content.mean()
  # Control for the edge score: a content image against an unrelated held-out content image.
  shuffled = [edge_correlation(contents[i], contents[(i + 1) % len(contents)])
              for i in range(len(contents))]
  numbers = {
      "decoder": args.decoder, "step": decoder.step, "size": s,
      "held_out_contents": len(contents), "styles": len(styles), "pairs": int(loss_out.size),
      "style_loss_output_mean": float(loss_out.mean()),
      "style_loss_content_mean": float(loss_content.mean()),
      "ratio": float(ratio),
      "ratio_median_per_pair": float(np.median(loss_out / loss_content)),
      "pairs_below_0.25": float(np.mean(loss_out / loss_content < 0.25)),
      "content_loss_mean": float(np.mean(content_losses)),
      "edge_correlation_output_vs_content": float(np.mean(edges)),
      "edge_correlation_unrelated_images": float(np.mean(shuffled)),
      "seconds": round(time.time() - t0, 1),
  }
  print(f"held-out contents: {len(contents)} ({', '.join(os.path.basename(p) for p in contents_paths)})")
  print(f"styles: {len(styles)}, pairs: {loss_out.size}, size {s}x{s}, decoder step {decoder.step}")
  print(f"style loss, unstylized content vs style: {loss_content.mean():.4f}")
  print(f"style loss, stylized output  vs style: {loss_out.mean():.4f}")
  print(f"ratio (output / content): {ratio:.4f}  (target < 0.25; median per pair "
        f"{numbers['ratio_median_per_pair']:.4f}, {100 * numbers['pairs_below_0.25']:.0f}% of pairs < 0.25)")
  print(f"content loss (relu4_1 vs AdaIN target): {numbers['content_loss_mean']:.4f}")
  print(f"edge correlation output vs its content: {numbers['edge_correlation_output_vs_content']:.3f} "
        f"(unrelated image pairs: {numbers['edge_correlation_unrelated_images']:.3f})")

  # Grid: first row the styles, then content | stylized outputs for a few contents.
  k = min(args.grid_styles, len(styles))
  style_idx = np.linspace(0, len(styles) - 1, k).round().astype(int)
  rows_idx = np.linspace(0, len(contents) - 1, min(args.grid_rows, len(contents))).round().astype(int)
  cell, gap = args.cell, 4
  def small(x):
    return images_lib.resize(x, cell, cell)
  blank = np.ones((cell, cell, 3), np.float32)
  rows = [[blank] + [small(styles[j]) for j in style_idx]]
  for i in rows_idx:
    rows.append([small(contents[i])] + [small(outputs[i][j]) for j in style_idx])
  def hcat(items):
    sep = np.ones((cell, gap, 3), np.float32)
    return np.concatenate(sum(([x, sep] for x in items), [])[:-1], axis=1)
  lines = [hcat(r) for r in rows]
  hsep = np.ones((gap, lines[0].shape[1], 3), np.float32)
  grid = np.concatenate(sum(([l, hsep] for l in lines), [])[:-1], axis=0)
  images_lib.write_image(args.grid, grid)
  print(f"wrote {args.grid} (top row: styles; rows: held-out content | outputs)")
  if args.json:
    files.atomic_write_bytes(args.json, json.dumps(numbers, indent=2).encode())


if __name__ == "__main__":
  main()
