"""`msnerf demo`: a procedural scene and styles (or real ones) through the whole pipeline."""

import dataclasses
import os

from msnerf_jax.core.errors import UserError

# Sized to finish within 15 minutes on a 2-core CPU (see README).
DEMO_SIZE = 64
DEMO_VIEWS = 40


def demo_settings():
  from msnerf_jax.pipeline.settings import Settings  # pylint: disable=g-import-not-at-top
  # About 12 minutes and 1.6 GiB on an idle 2-core CPU (docs/getting-started.md). The decoder
  # gets the largest share: with fewer steps its outputs are the style's texture alone, and
  # the stylized views (and so every render) lose the scene.
  # The multi-style heads' batch loss is flat from step 300 on at this size (PSNR 18.4 at
  # steps 200-300 and 1300-1500 alike, 7 December): 500 steps, and the time goes to painting.
  return dataclasses.replace(Settings(), adain_steps=800, adain_size=64, adain_batch=4,
                             adain_lr=1e-3, style_weight=0.5, nerf_steps=1000,
                             nerf_batch_rays=1024, ms_steps=500, ms_batch_rays=512,
                             features_steps=400, features_batch_cells=512, paint_steps=300,
                             fps=10)


def look_at(renders, settings) -> str:
  """The line naming the renders to look at, the first model's first."""
  from msnerf_jax.pipeline.renders import methods, morph_name  # pylint: disable=g-import-not-at-top
  what = {"painted": "painted in 3D", "features": "painted by the feature field",
          "styles": "the paper's multi-style NeRF"}
  files = [f"{os.path.join(renders, morph_name(settings) + '.mp4')} (style morph along the "
           f"orbit, {what[methods(settings)[0].video]})",
           f"{os.path.join(renders, 'grid.png')} (styles x views, every model and per-frame "
           "AdaIN)"]
  files += [f"{os.path.join(renders, m.video + '.mp4')} (all styles side by side, "
            f"{what[m.video]})" for m in methods(settings)]
  return "look at: " + ", ".join(files)


def register(commands, formatter):
  from msnerf_jax.cli.pipeline import add_settings_arguments  # pylint: disable=g-import-not-at-top
  p = commands.add_parser(
      "demo", formatter_class=formatter,
      help="try it: a built-in scene and three styles through every stage (no download)",
      description="Draws a small textured scene from known cameras (Blender format) and three "
                  "style images with numpy, then runs `msnerf pipeline` on them at a size that "
                  "finishes within about 15 minutes on a 2-core CPU. Writes OUT/renders/morph.mp4 "
                  "(an orbit whose style morphs through the styles), OUT/renders/grid.png "
                  "(styles x views) and OUT/summary.txt. With --data/--styles it runs on a real "
                  "scene and real style images instead. Re-run to resume or to skip what is done.",
      epilog="example: msnerf demo --out runs/demo")
  p.add_argument("--out", default=os.path.join("runs", "demo"), help="output folder")
  p.add_argument("--data", default=None,
                 help="a real scene folder instead of the built-in one (Blender, LLFF, a "
                      "transforms.json or COLMAP capture)")
  p.add_argument("--styles", nargs="+", default=None, metavar="IMG",
                 help="real style images instead of the built-in ones")
  p.add_argument("--decoder", default=None, metavar="ADAIN_RUN",
                 help="a trained AdaIN run folder to use instead of training one")
  p.add_argument("--size", type=int, default=DEMO_SIZE,
                 help="image side of the built-in scene in pixels")
  p.add_argument("--views", type=int, default=DEMO_VIEWS,
                 help="training views of the built-in scene")
  add_settings_arguments(p, demo_settings())
  p.set_defaults(func=cmd_demo)


def cmd_demo(args):
  # pylint: disable=g-import-not-at-top
  from msnerf_jax.pipeline import demo
  from msnerf_jax.pipeline.run import format_summary, run_pipeline
  from msnerf_jax.pipeline.settings import Settings
  from msnerf_jax.cli.pipeline import settings_from_args
  if args.size < 16:
    raise UserError(f"--size {args.size}: must be at least 16")
  if args.views < 2:
    raise UserError(f"--views {args.views}: must be at least 2")
  if os.path.exists(args.out) and not os.path.isdir(args.out):
    raise UserError(f"{args.out}: is a file, expected an output folder")
  data = args.data
  if data is None:
    data = demo.write_scene(os.path.join(args.out, "scene"), size=args.size, n_train=args.views,
                            n_val=max(2, args.views // 8), seed=args.seed,
                            progress=not args.no_progress)
    print(f"built-in scene: {args.views} training views of {args.size}x{args.size} in {data}")
  styles = args.styles
  if styles is None:
    styles = demo.write_styles(os.path.join(args.out, "styles"), seed=args.seed)
    print(f"built-in styles: {', '.join(styles)}")
  settings = settings_from_args(args, Settings)
  summary = run_pipeline(data, styles, args.out, args.decoder, settings,
                         progress=not args.no_progress)
  print("\n" + format_summary(summary), end="")
  print("\n" + look_at(os.path.join(args.out, "renders"), settings))
