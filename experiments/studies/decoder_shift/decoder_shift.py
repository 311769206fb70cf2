"""How much of AdaIN's frame-to-frame change comes from the relu4_1 cell grid alone.

  python experiments/studies/decoder_shift/decoder_shift.py --decoder ADAIN_RUN --data SCENE \
      [--downscale 8] [--scale 4] [--views 4] --styles A.jpg B.jpg ... [--json OUT.json]

Per-frame AdaIN encodes a frame to relu4_1 cells of 8 x 8 pixels (of the frame enlarged by
the stylize scale) and the decoder paints from those cells. Shift the frame by s pixels: a
stylization method that is equivariant to translation gives the same picture shifted by s.
Here the frame is a training photo (no 3D, no NeRF: a pure 2D translation of the same
pixels), so everything that changes is owed to where the cell grid falls on the content.

For s = 2, 4, 6 (sub-cell) and 8 (a whole cell, the control) enlarged pixels along rows,
columns and the diagonal, the RMSE between the stylization of the shifted window and the
shifted stylization of the window (overlap only, 16-pixel margins dropped), for:
  per-frame:   stylize.stylize_image's AdaIN at the enlarged size (own statistics);
  grid-avg N:  the same, with the cell grid moved by N offsets ({0, 4}^2 for N = 4, the
               diagonal {0, (4, 4)} for N = 2), each decode moved back and the N averaged;
  resampled:   the decoder alone: the unshifted window's AdaIN map resampled bilinearly by
               s / 8 cells (adain_losses.resample_cells, what a feature field's render does
               when the camera moves) and decoded; the encoder's aliasing left out;
and the AdaIN style distance (relu1_1..relu4_1) of each method's unshifted stylization to
the style, against per-frame AdaIN's (what averaging costs). A feature field sampled on the
camera's cell grid inherits exactly this: its features translate with the scene, the grid
does not. Prints the table and the hardware; --json writes it.
"""

import argparse
import json
import os
import platform
import time

import jax
import jax.numpy as jnp
import numpy as np

from msnerf_jax.style import adain
from msnerf_jax.kinds import stylized_scenes
from msnerf_jax.eval import metrics
from msnerf_jax.style import transfer as stylize
from msnerf_jax.core.config import DataConfig
from msnerf_jax.data import images as images_lib
from msnerf_jax.data.scene import load_scene
from msnerf_jax.models import decoder as decoder_lib
from msnerf_jax.models import vgg
from msnerf_jax.train.adain_losses import resample_cells

MARGIN = 16  # enlarged pixels dropped at every border (the decoder's zero/reflect padding).
GRIDS = {"per-frame": [(0, 0)], "grid-avg 2": [(0, 0), (4, 4)],
         "grid-avg 4": [(0, 0), (0, 4), (4, 0), (4, 4)]}


_decode_jit = jax.jit(stylize.decode_with_stats, static_argnames=("upsample",))


def make_stylizer(decoder, encoder):
  def stylize_window(window, s_mean, s_std):
    """[H, W, 3] (multiples of 8) -> [H, W, 3]: AdaIN with the window's own statistics."""
    return _decode_jit(decoder.params, encoder, window[None], s_mean, s_std, 1.0,
                       upsample=decoder.config.upsample)[0]
  return stylize_window


def make_resampled(decoder, encoder):
  @jax.jit
  def resampled(window, s_mean, s_std, shift):
    """[H + 8, W + 8, 3] window, shift (dy, dx) in [0, 8] -> [H, W, 3]: the window's AdaIN map
    moved by the shift (bilinear between cells), decoded."""
    t = adain.adain_from_stats(adain.encode(encoder, window[None])["relu4_1"], s_mean, s_std)
    moved = resample_cells(t, jnp.asarray(shift, jnp.int32)[None])
    return jnp.clip(decoder_lib.Decoder(decoder.config.upsample).apply(decoder.params, moved),
                    0.0, 1.0)[0]
  return resampled


def shift_rmse(unmoved, moved, dy, dx, size):
  """RMSE between `unmoved` moved by (dy, dx) and `moved`, over the overlap, MARGIN dropped."""
  a = unmoved[dy + MARGIN:size - MARGIN, dx + MARGIN:size - MARGIN]
  b = moved[MARGIN:size - MARGIN - dy, MARGIN:size - MARGIN - dx]
  return float(np.sqrt(np.mean(np.square(a - b))))


def stylized(stylize_window, big, top, left, size, offsets, style_stats):
  """The method's stylization of big[top:top + size, left:left + size]: for each offset o
  the window whose cell grid starts o earlier, decoded and moved back by o; the average."""
  outs = []
  for oy, ox in offsets:
    window = big[top - oy:top - oy + size + 8, left - ox:left - ox + size + 8]
    outs.append(np.asarray(stylize_window(jnp.asarray(window), *style_stats))[oy:oy + size,
                                                                               ox:ox + size])
  return np.mean(outs, 0)


def main(argv=None):
  p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
  p.add_argument("--decoder", required=True)
  p.add_argument("--data", required=True)
  p.add_argument("--downscale", type=int, default=8)
  p.add_argument("--scale", type=int, default=4)
  p.add_argument("--views", type=int, default=4)
  p.add_argument("--styles", nargs="+", required=True)
  p.add_argument("--shifts", type=int, nargs="+", default=[2, 4, 6, 8])
  p.add_argument("--grids", nargs="+", choices=list(GRIDS), default=list(GRIDS),
                 help="which cell-grid methods to measure (the resampled map always is)")
  p.add_argument("--json", default=None)
  args = p.parse_args(argv)
  grids = {m: GRIDS[m] for m in args.grids}
  if "per-frame" not in grids:
    grids = {"per-frame": GRIDS["per-frame"], **grids}  # the style distance's reference.
  t0 = time.time()
  scene, _ = load_scene(DataConfig(path=args.data, downscale=args.downscale))
  train = scene.split("train")
  views = [scene.images[i] for i in train[np.linspace(0, len(train) - 1, args.views).astype(int)]]
  decoder, encoder = stylized_scenes.load_decoder(args.decoder), vgg.load_vgg_params()
  stylize_window = make_stylizer(decoder, encoder)
  resampled = make_resampled(decoder, encoder)
  methods = list(grids) + ["resampled"]
  pad = MARGIN + 16
  rows = []
  for style_path in args.styles:
    style = images_lib.read_image(style_path, max_side=1024)
    rmse = {m: {s: [] for s in args.shifts} for m in methods}
    dist = {m: [] for m in grids}
    for view in views:
      h, w = view.shape[:2]
      big = images_lib.resize(view, h * args.scale, w * args.scale)
      size = (min(big.shape[:2]) - 2 * pad) // 8 * 8 - 8
      big = np.pad(big, ((pad, pad), (pad, pad), (0, 0)), mode="reflect").astype(np.float32)
      crop = images_lib.cover_crop(style, size, size)
      s_mean, s_std = adain.channel_stats(adain.encode(encoder, jnp.asarray(crop[None]))["relu4_1"])
      base = {m: stylized(stylize_window, big, pad, pad, size, o, (s_mean, s_std))
              for m, o in grids.items()}
      for m in grids:
        dist[m].append(float(metrics.style_distance(
            encoder, jnp.asarray(base[m][None]), jnp.asarray(crop[None]))["adain"][0]))
      window = jnp.asarray(big[pad:pad + size + 8, pad:pad + size + 8])
      whole = np.asarray(resampled(window, s_mean, s_std, (0, 0)))
      for s in args.shifts:
        for dy, dx in ((s, 0), (0, s), (s, s)):
          for m, o in grids.items():
            moved = stylized(stylize_window, big, pad + dy, pad + dx, size, o, (s_mean, s_std))
            rmse[m][s].append(shift_rmse(base[m], moved, dy, dx, size))
          moved = np.asarray(resampled(window, s_mean, s_std, (dy, dx)))
          rmse["resampled"][s].append(shift_rmse(whole, moved, dy, dx, size))
    name = os.path.splitext(os.path.basename(style_path))[0]
    row = {"style": name}
    for m in grids:
      row[m] = {"rmse": {s: float(np.mean(rmse[m][s])) for s in args.shifts},
                "style_distance": float(np.mean(dist[m]))}
    row["resampled"] = {"rmse": {s: float(np.mean(rmse["resampled"][s])) for s in args.shifts}}
    rows.append(row)
    print(name, json.dumps(row), flush=True)
  seconds = time.time() - t0
  print(f"\nshift RMSE (enlarged pixels; {len(views)} views of {args.data} at 1/{args.downscale}, "
        f"stylize scale {args.scale}, decoder {args.decoder})")
  print("| style | method | " + " | ".join(f"s={s}" for s in args.shifts)
        + " | style distance / per-frame |")
  print("|---|---|" + "---|" * (len(args.shifts) + 1))
  for row in rows:
    for m in grids:
      r = row[m]
      print(f"| {row['style']} | {m} | " + " | ".join(f"{r['rmse'][s]:.4f}" for s in args.shifts)
            + f" | {r['style_distance'] / row['per-frame']['style_distance']:.2f} |")
    r = row["resampled"]["rmse"]
    print(f"| {row['style']} | resampled map | " + " | ".join(f"{r[s]:.4f}" for s in args.shifts)
          + " | - |")
  hardware = f"{os.cpu_count()} cores {platform.processor() or platform.machine()}, " \
             f"jax {jax.__version__} {jax.default_backend()}"
  print(f"\n{seconds:.0f} s on {hardware}")
  if args.json:
    with open(args.json, "w") as f:
      json.dump({"rows": rows, "seconds": seconds, "hardware": hardware, "args": vars(args)},
                f, indent=1)


if __name__ == "__main__":
  main()
