"""The paper's style controls on a multi-style run, measured: interpolation, strength, unseen styles.

  python experiments/paper/style_controls.py --run RUN --out DIR interp A B     # A -> B
  python experiments/paper/style_controls.py --run RUN --out DIR strength S     # original -> S
  python experiments/paper/style_controls.py --run RUN --out DIR unseen IMG ... # never trained on

A and B are training styles (names) or image files; S is a training style. Each renders
--views views of the run's camera path and writes DIR/grid.png (rows: views; for unseen: each
style image, then the multi-style views, then per-frame AdaIN of the NeRF's renders), and
DIR/results.md/.json with the style distance (AdaIN statistics loss over relu1_1..relu4_1,
msnerf_jax.eval.metrics.style_distance; lower = closer), averaged over the views:

  interp:   at t in [0, 1]: the distance of the renders to style A and to style B;
  strength: at s in [0, 1]: the distance to the style, and the PSNR against the NeRF's
            photo-real renders (how much of the real scene's look is kept);
  unseen:   per image, the distance of the multi-style renders (style vector of the image,
            computed on the spot) and of per-frame AdaIN (the run's decoder) to the image.

It prints the table, the hardware and the wall time.
"""

import argparse
import json
import os
import platform
import time

import jax.numpy as jnp
import numpy as np

from msnerf_jax.eval import evaluate
from msnerf_jax.eval import paths
from msnerf_jax.kinds import stylized_scenes
from msnerf_jax.eval import metrics
from msnerf_jax.data import video
from msnerf_jax.kinds import views
from msnerf_jax.style import transfer as stylize_lib
from msnerf_jax.core import files
from msnerf_jax.data import images as images_lib
from msnerf_jax.data.stylized import read_manifest
from msnerf_jax.models import vgg
from msnerf_jax.kinds.runs import load_run, load_run_and_scene
from msnerf_jax.kinds.multistyle import style_vectors
from msnerf_jax.style.vectors import resolve_style, sweep


def style_picture(spec, sources):
  """The image behind a style (a training style's source file, or a file)."""
  return images_lib.read_image(sources.get(spec, spec), max_side=1024)


def distance(encoder, frames, image) -> float:
  d = metrics.style_distance(encoder, jnp.asarray(np.stack(frames)), jnp.asarray(image)[None])
  return float(np.mean(d["adain"]))


def main():
  parser = argparse.ArgumentParser(description=__doc__,
                                   formatter_class=argparse.RawDescriptionHelpFormatter)
  parser.add_argument("--run", required=True, help="multi-style run folder")
  parser.add_argument("--out", required=True, help="output folder")
  parser.add_argument("--views", type=int, default=3, help="views of the camera path")
  parser.add_argument("--steps", type=int, default=5, help="values of t or s in [0, 1]")
  parser.add_argument("--chunk", type=int, default=None, help="rays per rendering call")
  parser.add_argument("mode", choices=("interp", "strength", "unseen"))
  parser.add_argument("styles", nargs="+", help="interp: A B; strength: S; unseen: IMG ...")
  args = parser.parse_args()
  t0 = time.time()
  run, scene = load_run_and_scene(args.run, "multistyle")
  vectors = style_vectors(run)
  manifest = read_manifest(run.record["stylized"])
  sources = {s["name"]: s["source"] for s in manifest["styles"] if s["source"]}
  encoder, cache = vgg.load_vgg_params(), {}
  poses = scene.render_poses[np.linspace(0, len(scene.render_poses), args.views + 1)[:-1]
                             .round().astype(int)]
  render = lambda styles: [views.render_styles(scene, run.params, run.config, c2w,
                                               np.stack(styles), args.chunk)["rgb"]
                           for c2w in poses]  # [views][K, H, W, 3]: one sweep per view
  ts = np.linspace(0.0, 1.0, max(2, args.steps))
  at_view_size = lambda picture: stylize_lib.cover_crop(picture, scene.height, scene.width)
  rows, grid = [], []
  if args.mode in ("interp", "strength"):
    if args.mode == "interp":
      if len(args.styles) != 2:
        parser.error("interp takes two styles, A and B")
      a, b = args.styles
      ends = [resolve_style(s, vectors, cache) for s in (a, b)]
      images = {x: at_view_size(style_picture(x, sources)) for x in (a, b)}
    else:
      if len(args.styles) != 1 or "original" not in vectors:
        parser.error("strength takes one style, and a run trained with --include-original")
      ends = [vectors["original"], resolve_style(args.styles[0], vectors, cache)]
      images = {args.styles[0]: at_view_size(style_picture(args.styles[0], sources))}
      nerf_run = load_run(run.record["nerf_run"])
      photo = [views.render_view(scene, nerf_run.params, nerf_run.config, c2w,
                                 args.chunk)["rgb"] for c2w in poses]
    sweeps = render(sweep(ends[0], ends[1], len(ts)))
    grid = [list(s) for s in sweeps]
    key = "t" if args.mode == "interp" else "s"
    for k, t in enumerate(ts):
      frames = [s[k] for s in sweeps]
      row = {key: float(t)}
      for name, image in images.items():
        row[f"distance to {name}"] = distance(encoder, frames, image)
      if args.mode == "strength":
        row["PSNR vs photo-real"] = float(np.mean([metrics.psnr(f, p)
                                                   for f, p in zip(frames, photo)]))
      rows.append(row)
  else:
    decoder = stylized_scenes.load_decoder(manifest["decoder"])
    nerf_run = load_run(run.record["nerf_run"])
    base = [views.render_view(scene, nerf_run.params, nerf_run.config, c2w, args.chunk)
            for c2w in poses]
    for spec in args.styles:
      picture = style_picture(spec, sources)
      image = at_view_size(picture)  # what the distances use; the baseline covers its own size.
      ours = [s[0] for s in render([resolve_style(spec, vectors, cache)])]
      per_frame = paths.per_frame_adain(decoder, encoder, base, picture, 1.0,
                                        scene.white_background, manifest["stylize_scale"])
      d_ours, d_adain = distance(encoder, ours, image), distance(encoder, per_frame, image)
      rows.append({"style": os.path.basename(spec), "trained on": spec in vectors,
                   "multi-style": d_ours, "per-frame AdaIN": d_adain,
                   "ratio": d_ours / max(d_adain, 1e-12)})
      grid.append([image] + ours + per_frame)
  os.makedirs(args.out, exist_ok=True)
  figure = video.write_grid(os.path.join(args.out, "grid.png"), grid)
  md = evaluate.markdown_table(rows, list(rows[0]))
  seconds = time.time() - t0
  where = f"{platform.machine()}, {os.cpu_count()} cores, {platform.processor() or 'CPU'}"
  md.append(f"\n{args.mode} on {args.run}, {args.views} views of {scene.width}x{scene.height}: "
            f"{seconds:.0f} s ({where})")
  files.atomic_write_bytes(os.path.join(args.out, "results.md"), "\n".join(md).encode())
  files.atomic_write_bytes(os.path.join(args.out, "results.json"),
                                json.dumps({"mode": args.mode, "styles": args.styles,
                                            "rows": rows, "seconds": seconds}, indent=2).encode())
  print("\n".join(md))
  print(f"written: {figure}, {os.path.join(args.out, 'results.md')}")


if __name__ == "__main__":
  main()
