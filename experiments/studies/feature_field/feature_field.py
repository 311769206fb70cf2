"""The feature field (AdaIN in 3D) against per-frame AdaIN, with the same decoder and scale.

  python experiments/studies/feature_field/feature_field.py --features FEATURE_RUN \
      --styles A.jpg B.jpg ... [--frames 40] [--decoder ADAIN_RUN] [--stats rendered|encoded] \
      [--out DIR]
  python experiments/studies/feature_field/feature_field.py --features FEATURE_RUN --only-alpha0 \
      [--heldout 5] ...

Along the scene's render path (its NeRF renders the geometry and the photo-real frames):
  per-frame:  each photo-real frame stylized on its own (stylize.stylize_image, the run's
              stylize scale), the baseline of `msnerf evaluate`;
  feature:    the feature field's render of the frame, AdaIN with the scene's pooled
              statistics, the same decoder.
For each style: the style distance to the style image (AdaIN statistics, relu1_1..relu4_1),
warped RMSE and LPIPS at k = 1 and 7 (msnerf_jax.eval.consistency), and the AdaIN content loss
(relu4_1 of the frame, enlarged to the stylize scale, against AdaIN(encoder features of the
photo-real frame, style)). Then: how distinct the styles stay (mean pairwise AdaIN distance
between the frames of different styles), alpha = 0 (decoding the rendered features with the
scene's own statistics against decoding the encoder's features of the photo-real frame, PSNR
on held-out views; each of the two against the photo-real frame too), and the cost of
switching style (a cached feature render against per-frame AdaIN of the same frame).
Background pixels go back to white on Blender scenes, for both methods, as in `msnerf
evaluate`. Writes OUT/results.md, .json and frames.png (--only-alpha0: OUT/alpha0.json);
prints the hardware and wall time.
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
from msnerf_jax.kinds import stylized_scenes
from msnerf_jax.eval import consistency
from msnerf_jax.eval import metrics
from msnerf_jax.style import transfer as stylize
from msnerf_jax.data import video
from msnerf_jax.kinds import views
from msnerf_jax.data import images as images_lib
from msnerf_jax.style.features import painted_size, style_vector_of_stats
from msnerf_jax.models import vgg
from msnerf_jax.kinds.runs import load_run, load_run_and_scene
from msnerf_jax.kinds.features import CONTENT_STATS, content_stats
def whiten(frame, acc, white):
  return images_lib.over_background(frame, acc[..., None]) if white else frame


def content_loss(encoder, frames, photos, style, scale):
  """Mean over frames of AdaIN's content loss at the stylize scale (relu4_1 MSE)."""
  out = []
  s_mean, s_std = adain.channel_stats(adain.encode(encoder, jnp.asarray(style[None]))["relu4_1"])
  big = lambda x: jnp.asarray(stylize.enlarged(x, scale)[None])
  for f, p in zip(frames, photos):
    target = adain.adain_from_stats(adain.encode(encoder, big(p))["relu4_1"], s_mean, s_std)
    out.append(float(jnp.mean(jnp.square(adain.encode(encoder, big(f))["relu4_1"] - target))))
  return float(np.mean(out))


def psnr(a, b):
  return float(-10.0 * np.log10(np.mean(np.square(np.asarray(a) - np.asarray(b)))))


def alpha0(scene, nerf, run, decoder, encoder, stats, heldout, grids, paint, scale):
  """alpha = 0 on `heldout` evenly spaced held-out views: the decoder's picture of the
  rendered features (the scene's own statistics) against its picture of the encoder's
  features of the photo-real render, and each against that render. Returns
  {"alpha0_psnr": [...], "alpha0_field_vs_photo": [...], "alpha0_encoder_vs_photo": [...]}."""
  held = scene.split("val" if "val" in scene.splits and len(scene.splits["val"]) else "test")
  held = held[np.linspace(0, len(held) - 1, heldout).round().astype(int)]
  plain = style_vector_of_stats(stats)
  out = {"alpha0_psnr": [], "alpha0_field_vs_photo": [], "alpha0_encoder_vs_photo": []}
  for v in held:
    photo = views.render_view(scene, nerf.params, nerf.config, int(v))["rgb"]
    ours = paint(views.feature_maps(scene, run.params, run.config, int(v), grids), plain[None])[0]
    theirs = stylize.stylize_image(decoder, encoder, photo, [photo], alpha=0.0, scale=scale,
                                   content_stats=(stats[0][None], stats[1][None]))
    for key, a, b in (("alpha0_psnr", ours, theirs), ("alpha0_field_vs_photo", ours, photo),
                      ("alpha0_encoder_vs_photo", theirs, photo)):
      out[key].append(psnr(a, b))
  return out


def main():
  parser = argparse.ArgumentParser(description=__doc__,
                                   formatter_class=argparse.RawDescriptionHelpFormatter)
  parser.add_argument("--features", required=True, help="feature run (`msnerf features train`)")
  parser.add_argument("--styles", nargs="+", default=[], help="style images")
  parser.add_argument("--frames", type=int, default=40, help="frames of the render path")
  parser.add_argument("--heldout", type=int, default=5, help="held-out views for alpha = 0")
  parser.add_argument("--decoder", default=None,
                      help="the AdaIN run that paints both methods (default: the feature run's; "
                           "the field's targets are the encoder's, so any decoder of that "
                           "encoder fits, e.g. one trained without some of the styles)")
  parser.add_argument("--stats", choices=("rendered", "encoded"), default="rendered",
                      help="content statistics the field's features are normalised by: of its "
                           "renders of the training views (the library's), or the encoder's "
                           "of the training views (before 2 December 2026)")
  parser.add_argument("--grids", type=int, default=1,
                      help="cell grids each feature-field frame is averaged over "
                           "(views.render_feature_styles' grids: 1, 2 or 4)")
  parser.add_argument("--only-alpha0", action="store_true",
                      help="measure alpha = 0 alone (no path, no styles): OUT/alpha0.json")
  parser.add_argument("--out", default=None, help="output folder (default: RUN/compare)")
  args = parser.parse_args()
  t0 = time.time()
  run, scene = load_run_and_scene(args.features, "features")
  nerf = load_run(run.record["nerf_run"], "nerf")
  decoder_dir = args.decoder or run.record["decoder"]
  decoder = stylized_scenes.load_decoder(decoder_dir)
  encoder = vgg.load_vgg_params()
  stats = content_stats(run) if args.stats == "rendered" else tuple(
      np.load(os.path.join(args.features, CONTENT_STATS)))
  scale = run.config.stylize_scale
  out_dir = args.out or os.path.join(args.features, "compare")
  paint = lambda maps, vecs: views.paint_feature_maps(maps, decoder, stats, vecs, scene.height,
                                                      scene.width, scale)
  hardware = (f"{platform.processor() or platform.machine()}, {os.cpu_count()} cores, "
              f"jax {jax.__version__} on {jax.devices()[0].platform}")
  if args.only_alpha0:
    result = {**alpha0(scene, nerf, run, decoder, encoder, stats, args.heldout, args.grids,
                       paint, scale), "run": os.path.abspath(args.features), "step": run.step,
              "decoder": os.path.abspath(decoder_dir), "stats": args.stats, "grids": args.grids,
              "hardware": hardware, "seconds": time.time() - t0}
    os.makedirs(out_dir, exist_ok=True)
    with open(os.path.join(out_dir, "alpha0.json"), "w") as f:
      json.dump(result, f, indent=2)
    print(json.dumps(result, indent=1))
    return
  if not args.styles:
    parser.error("--styles: required (unless --only-alpha0)")
  lpips_params = metrics.load_lpips_params()
  lp = lambda a, b: np.asarray(metrics.lpips(lpips_params, jnp.asarray(a), jnp.asarray(b)))
  poses = scene.render_poses[np.linspace(0, len(scene.render_poses) - 1, args.frames)
                             .round().astype(int)]
  base = [views.render_view(scene, nerf.params, nerf.config, c2w) for c2w in
          tqdm(poses, desc="NeRF path", leave=False)]
  fmaps = [views.feature_maps(scene, run.params, run.config, c2w, args.grids) for c2w in
           tqdm(poses, desc="feature path", leave=False)]
  ph, pw = painted_size(scene.height, scene.width, scale)
  pictures = [images_lib.read_image(p, max_side=1024) for p in args.styles]
  names = [os.path.splitext(os.path.basename(p))[0] for p in args.styles]
  crops = [stylize.cover_crop(p, ph, pw) for p in pictures]
  vectors = np.stack([np.asarray(adain.style_vector(encoder, c)) for c in crops])
  white = scene.white_background
  rows, figure, rendered = [], [], {}
  for name, picture, crop, vector in tqdm(list(zip(names, pictures, crops, vectors)),
                                           desc="styles"):
    per_frame = [whiten(stylize.stylize_image(decoder, encoder, b["rgb"], [picture],
                                              scale=scale), b["accumulation"], white)
                 for b in base]
    feature = [whiten(paint(f, vector[None])[0], b["accumulation"], white)
               for f, b in zip(fmaps, base)]
    small = stylize.cover_crop(picture, scene.height, scene.width)
    for method, frames in (("feature-field", feature), ("adain-per-frame", per_frame)):
      row = {"method": method, "style": name}
      for k in (1, 7):
        c = consistency.consistency(frames, [b["depth"] for b in base],
                                    [b["accumulation"] for b in base], poses, scene.K,
                                    scene.ndc, k, lp)
        row[f"rmse_k{k}"], row[f"lpips_k{k}"] = c["rmse"], c["lpips"]
      d = metrics.style_distance(encoder, jnp.asarray(np.stack(frames)), jnp.asarray(small)[None])
      row["style_adain"] = float(np.mean(d["adain"]))
      row["content"] = content_loss(encoder, frames, [b["rgb"] for b in base], crop, scale)
      rows.append(row)
      rendered.setdefault(method, []).append(np.stack(frames))
    figure.append([small] + feature[:3] + per_frame[:3])
  # Distinct styles: mean pairwise AdaIN statistics distance between the styles' frames.
  distinct = {}
  for method, per_style in rendered.items():
    stats_of = [adain.style_stats(encoder, jnp.asarray(f)) for f in per_style]
    pairs = [float(adain.style_loss(stats_of[i], stats_of[j]))
             for i in range(len(per_style)) for j in range(i + 1, len(per_style))]
    distinct[method] = float(np.mean(pairs)) if pairs else float("nan")
  # alpha = 0 on held-out views: the decoder's picture of the rendered features against its
  # picture of the encoder's features of the photo-real render.
  zero = alpha0(scene, nerf, run, decoder, encoder, stats, args.heldout, args.grids, paint,
                scale)
  agree = zero["alpha0_psnr"]
  # Cost of switching style on one frame: cached features vs per-frame AdaIN (compiled first).
  f0, photo0 = fmaps[0], base[0]["rgb"]
  def feature_switch():
    return paint(f0, vectors[:1])
  def per_frame_switch():
    return stylize.stylize_image(decoder, encoder, photo0, [pictures[0]], scale=scale)
  timing = {}
  for label, fn in (("feature_switch_s", feature_switch), ("per_frame_s", per_frame_switch)):
    fn()
    t = time.perf_counter()
    for _ in range(3):
      jax.block_until_ready(fn())
    timing[label] = (time.perf_counter() - t) / 3
  os.makedirs(out_dir, exist_ok=True)
  figure_path = video.write_grid(os.path.join(out_dir, "frames.png"), figure)
  by = {(r["method"], r["style"]): r for r in rows}
  ratios = [{"style": n, **{f"{key}_ratio": by[("feature-field", n)][key]
                            / by[("adain-per-frame", n)][key]
                            for key in ("style_adain", "rmse_k1", "lpips_k1", "rmse_k7",
                                        "lpips_k7", "content")}} for n in names]
  result = {"rows": rows, "ratios": ratios, "distinct": distinct,
            "distinct_ratio": distinct["feature-field"] / distinct["adain-per-frame"],
            **zero, "alpha0_psnr_mean": float(np.mean(agree)), **timing,
            "switch_ratio": timing["feature_switch_s"] / timing["per_frame_s"],
            "run": os.path.abspath(args.features), "step": run.step, "frames": args.frames,
            "decoder": os.path.abspath(decoder_dir), "stats": args.stats, "grids": args.grids,
            "hardware": hardware, "seconds": time.time() - t0}
  keys = ("style_adain", "rmse_k1", "lpips_k1", "rmse_k7", "lpips_k7", "content")
  lines = ["| method | style | " + " | ".join(keys) + " |", "|" + "---|" * (len(keys) + 2)]
  lines += [f"| {r['method']} | {r['style']} | " + " | ".join(f"{r[k]:.4f}" for k in keys) + " |"
            for r in rows]
  lines += ["", "| style | " + " | ".join(f"{k} ratio" for k in keys) + " |",
            "|" + "---|" * (len(keys) + 1)]
  lines += [f"| {r['style']} | " + " | ".join(f"{r[k + '_ratio']:.2f}" for k in keys) + " |"
            for r in ratios]
  lines += ["", f"distinct styles (mean pairwise distance): feature-field "
                f"{distinct['feature-field']:.4f}, per-frame {distinct['adain-per-frame']:.4f} "
                f"(ratio {result['distinct_ratio']:.2f})",
            f"alpha = 0 agreement on {len(agree)} held-out views: {result['alpha0_psnr_mean']:.2f} "
            f"dB (to the photo-real render: the field's decode "
            f"{np.mean(zero['alpha0_field_vs_photo']):.2f} dB, the encoder's "
            f"{np.mean(zero['alpha0_encoder_vs_photo']):.2f} dB)", f"switching style: {timing['feature_switch_s']:.3f} s on cached features, "
                   f"{timing['per_frame_s']:.3f} s per-frame AdaIN (ratio "
                   f"{result['switch_ratio']:.2f})",
            f"{result['hardware']}; {result['seconds']:.0f} s"]
  with open(os.path.join(out_dir, "results.md"), "w") as f:
    f.write("\n".join(lines) + "\n")
  with open(os.path.join(out_dir, "results.json"), "w") as f:
    json.dump(result, f, indent=2)
  print("\n".join(lines))
  print(f"written {out_dir}/results.md, results.json, {figure_path}")


if __name__ == "__main__":
  main()
