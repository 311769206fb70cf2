"""`msnerf pipeline`: every stage in one command, with caching (see msnerf_jax.pipeline.run)."""

import dataclasses

from msnerf_jax.core import config as config_lib
from msnerf_jax.pipeline.settings import Settings

_HELP = {
    "downscale": "scene image downscale factor (0 = the format's default: Blender 1, LLFF 8, "
                 "captures to 400 px or less)",
    "format": "scene format: auto, blender, llff, transforms or colmap",
    "layout": "captures: auto, forward-facing or object",
    "adain_steps": "AdaIN decoder training steps",
    "adain_size": "side of the decoder's square training crops (multiple of 8)",
    "adain_batch": "crops per decoder step",
    "adain_lr": "decoder learning rate",
    "style_weight": "weight of the decoder's style loss",
    "preset": "NeRF preset (fast = hash grid + occupancy grid, cpu = small MLP, paper = "
              "reference)",
    "nerf_steps": "NeRF training steps (0 = the preset's)",
    "nerf_batch_rays": "NeRF rays per step (0 = the preset's)",
    "ms_steps": "multi-style NeRF training steps",
    "ms_batch_rays": "multi-style pixels per step (each supervised in every style)",
    "features_steps": "feature-field training steps (0 = no feature field)",
    "features_batch_cells": "feature-field relu4_1 cells per step",
    "paint_steps": "painted colour fields: training steps (0 = none)",
    "paint_crop": "painted colour fields: the style loss sees random crops of this side "
                  "(0 = whole views; 128 for views as large as LLFF's 504x378)",
    "paint_path_views": "painted colour fields: render-path cameras painted beside the "
                        "training views (0 = none, e.g. fern: its hazy NeRF's sample lists "
                        "are large)",
    "frames": "frames of the videos (0 = the scene's whole render path)",
    "fps": "frames per second of the videos",
    "grid_views": "views (columns) of the grid",
    "chunk": "rays per rendering call (0 = the config's)",
    "seed": "random seed of every stage",
}


def add_settings_arguments(parser, defaults):
  """One option per field of pipeline.settings.Settings, with `defaults` as the defaults."""
  group = parser.add_argument_group("stage sizes")
  for field in dataclasses.fields(defaults):
    value = getattr(defaults, field.name)
    kwargs = {"choices": config_lib.PRESETS} if field.name == "preset" else {}
    group.add_argument("--" + field.name.replace("_", "-"), type=type(value), default=value,
                       help=_HELP[field.name], **kwargs)
  group.add_argument("--no-progress", action="store_true", help="no progress bars")


def settings_from_args(args, cls):
  return cls(**{f.name: getattr(args, f.name) for f in dataclasses.fields(cls)})


def register(commands, formatter):
  p = commands.add_parser(
      "pipeline", formatter_class=formatter,
      help="every stage in one command: decoder, NeRF, stylized views, multi-style NeRF, "
           "feature field, painted colour fields, renders",
      description="Runs AdaIN decoder training (on the scene's training views and the styles; "
                  "skipped with --decoder), NeRF training, the stylized dataset (with the "
                  "original views), multi-style training (the paper's model), feature-field "
                  "training (AdaIN in 3D), painted colour fields (strokes in 3D) and the "
                  "renders (painted first), each in a subfolder "
                  "of --out. A finished stage is skipped on a re-run; an interrupted one "
                  "resumes. Ends with a summary (also OUT/summary.txt).",
      epilog="example: msnerf pipeline --data ../shared/data/nerf_synthetic/lego --downscale 8 "
             "--styles a.jpg b.jpg c.jpg --out runs/lego_pipeline")
  p.add_argument("--data", required=True, help="scene folder (Blender or LLFF, auto-detected)")
  p.add_argument("--styles", nargs="+", required=True, metavar="IMG", help="style images")
  p.add_argument("--out", required=True, help="output folder (one subfolder per stage)")
  p.add_argument("--decoder", default=None, metavar="ADAIN_RUN",
                 help="a trained AdaIN run folder to use instead of training one")
  add_settings_arguments(p, Settings())
  p.set_defaults(func=cmd_pipeline)


def cmd_pipeline(args):
  from msnerf_jax.pipeline.run import format_summary, run_pipeline  # pylint: disable=g-import-not-at-top
  summary = run_pipeline(args.data, args.styles, args.out, args.decoder,
                         settings_from_args(args, Settings), progress=not args.no_progress)
  print("\n" + format_summary(summary), end="")
