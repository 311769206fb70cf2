"""`msnerf stylize-scene` and `msnerf multistyle train|eval`: the paper's 3D style stage."""

import json
import os
import time

from msnerf_jax.core import config as config_lib
from msnerf_jax.cli.common import load_run_and_scene, print_summary, print_training_summary
from msnerf_jax.cli.config_args import add_trainer_options, trainer_config
from msnerf_jax.core.errors import UserError

_DEFAULTS = config_lib.MultistyleConfig()
# The options `msnerf multistyle train --help` lists first (--lr sets lr_init and lr_final).
_MAIN = ("density_aware", "steps", "batch_rays", "rgb_extra_layers", "density_extra_layers",
         "style_weight", "style_patch", "style_patches", "checkpoint_every", "seed")


def register(commands, formatter):
  _register_stylize_scene(commands, formatter)
  _register_multistyle(commands, formatter)


def _register_stylize_scene(commands, formatter):
  p = commands.add_parser(
      "stylize-scene", formatter_class=formatter,
      help="stylize every view of a scene with each style (the multi-style training set)",
      description="Stylizes every view (all splits) of a Blender or LLFF scene with each style "
                  "image by AdaIN, and writes per style the images and the 1024-d style vector, "
                  "plus a manifest. An interrupted run continues where it stopped.",
      epilog="example: msnerf stylize-scene --data lego --downscale 8 --decoder runs/adain "
             "--styles a.jpg b.jpg --include-original --out runs/lego_styles")
  p.add_argument("--data", default=None,
                 help="scene folder (Blender, LLFF or a capture, auto-detected); required "
                      "unless --from-features")
  p.add_argument("--decoder", default=None,
                 help="AdaIN run folder (`msnerf adain train`); required unless "
                      "--from-features (then default: the feature run's)")
  p.add_argument("--from-features", default=None, metavar="FEATURE_RUN",
                 help="render every view from a feature run (`msnerf features train`), "
                      "stylized in 3D, instead of stylizing each photo by 2D AdaIN; the scene, "
                      "downscale and stylize scale are the run's")
  p.add_argument("--styles", nargs="+", required=True, metavar="IMG", help="style images")
  p.add_argument("--alphas", nargs="+", type=float, default=None, metavar="A",
                 help="style strength per style image in [0, 1] (default 1 for all)")
  p.add_argument("--include-original", action="store_true",
                 help="add the unstylized views as a style named 'original' (strength control)")
  p.add_argument("--downscale", type=int, default=0,
                 help="image downscale factor, as for `msnerf nerf train` (0 = the format's "
                      "default)")
  p.add_argument("--format", default="auto", help="scene format, as for `msnerf nerf train`")
  p.add_argument("--layout", default="auto", help="capture layout, as for `msnerf nerf train`")
  p.add_argument("--stylize-scale", type=int, default=1, metavar="N",
                 help="stylize each view enlarged N times, then shrink the result: strokes N x "
                      "finer relative to the scene (e.g. 4 at --downscale 8 stylizes lego at "
                      "the reference code's 400x400 and trains at 100x100)")
  p.add_argument("--scene-stats", action="store_true",
                 help="normalise every view by the VGG statistics of all training views instead "
                      "of its own: one colour map for the whole scene, so the views agree more "
                      "(docs/method.md's per-view AdaIN without it)")
  p.add_argument("--out", required=True, help="dataset folder")
  p.set_defaults(func=cmd_stylize_scene)


def _register_multistyle(commands, formatter):
  ms = commands.add_parser("multistyle", formatter_class=formatter,
                           help="train and evaluate a multi-style NeRF",
                           description="Style heads on the frozen trunk of a trained NeRF.")
  verbs = ms.add_subparsers(dest="verb", metavar="VERB", required=True)
  p = verbs.add_parser(
      "train", formatter_class=formatter,
      help="train a multi-style NeRF (re-run the same command to resume)",
      description="Copies the trunk of a NeRF run (frozen: no gradient, no optimizer state) "
                  "and trains new style-conditioned heads on a stylized dataset; every sampled "
                  "pixel is supervised in every style with one trunk evaluation.")
  p.add_argument("--nerf", required=True, help="NeRF run folder (`msnerf nerf train`)")
  p.add_argument("--stylized", required=True, help="dataset folder (`msnerf stylize-scene`)")
  p.add_argument("--out", required=True, help="run folder")
  add_trainer_options(p, config_lib.MultistyleConfig, _MAIN, 3,
                      f"initial learning rate, decaying exponentially to lr/10 at step "
                      f"{_DEFAULTS.optim.lr_decay_steps}", "multistyle",
                      "every other multi-style setting")
  p.set_defaults(func=cmd_train)

  p = verbs.add_parser("eval", formatter_class=formatter,
                       help="per-style PSNR/SSIM on held-out stylized views",
                       description="Renders the held-out views in every training style and "
                                   "compares them with the stylized images.")
  p.add_argument("--run", required=True, help="multi-style run folder")
  p.add_argument("--split", default="val", choices=("train", "val", "test"), help="which views")
  p.add_argument("--chunk", type=int, default=None, help="rays per rendering call")
  p.set_defaults(func=cmd_eval)


def cmd_stylize_scene(args):
  from msnerf_jax.kinds import stylized_scenes  # pylint: disable=g-import-not-at-top
  t0 = time.time()
  if args.from_features is not None:
    given = [f"--{name.replace('_', '-')}" for name, default in (
        ("data", None), ("downscale", 0), ("format", "auto"), ("layout", "auto"),
        ("stylize_scale", 1), ("scene_stats", False)) if getattr(args, name) != default]
    if given:
      raise UserError(f"{given[0]}: --from-features takes the scene, its size, the stylize "
                      "scale and the statistics from the feature run; drop it")
    summary, scene = stylized_scenes.stylize_scene_from_features(
        args.from_features, args.styles, args.out, alphas=args.alphas,
        include_original=args.include_original, decoder_dir=args.decoder)
  else:
    for name in ("data", "decoder"):
      if getattr(args, name) is None:
        raise UserError(f"--{name}: required (or --from-features FEATURE_RUN)")
    summary, scene = stylized_scenes.stylize_scene_folder(
        args.data, args.decoder, args.styles, args.out, alphas=args.alphas,
        include_original=args.include_original, downscale=args.downscale,
        stylize_scale=args.stylize_scale, scene_stats=args.scene_stats,
        scene_format=args.format, layout=args.layout)
  print_summary("stylized dataset done", [
      ("folder", summary["out"]), ("styles", ", ".join(summary["styles"])),
      ("views", f"{len(scene.images)} of {scene.width}x{scene.height} per style"),
      ("images", f"{summary['written']} written, {summary['skipped']} already there"),
      ("time", f"{time.time() - t0:.0f} s"),
      ("next", f"msnerf multistyle train --nerf NERF_RUN --stylized {args.out} --out RUN_DIR")])


def cmd_train(args):
  # pylint: disable=g-import-not-at-top
  from msnerf_jax.data.stylized import load_stylized
  from msnerf_jax.train import multistyle
  # --lr also sets lr_final (lr / 10) unless --lr-final is given.
  config, shows = trainer_config(args, config_lib.MultistyleConfig, "multistyle", 0.1)
  stylized = load_stylized(args.stylized, progress=shows)
  if shows:
    print(f"stylized dataset {args.stylized}: {len(stylized.names)} styles "
          f"({', '.join(stylized.names)}), {len(stylized.splits['train'])} training views")
  summary = multistyle.train(config, args.nerf, stylized, args.out, n_devices=args.devices,
                             parallel=args.parallel)
  if shows:
    print_training_summary("multi-style training done", summary, " (all styles)",
                           f"msnerf multistyle eval --run {args.out}; msnerf render --run "
                           f"{args.out} --out {os.path.join(args.out, 'video')}; msnerf view "
                           f"--run {args.out}")


def cmd_eval(args):
  # pylint: disable=g-import-not-at-top
  from msnerf_jax.data import video
  from msnerf_jax.core.files import atomic_write_bytes
  from msnerf_jax.data.stylized import load_stylized
  from msnerf_jax.eval.evaluate import evaluate_multistyle
  from msnerf_jax.kinds.views import render_styles
  run, scene = load_run_and_scene(args.run, "multistyle")
  stylized = load_stylized(run.record["stylized"])
  if list(stylized.names) != list(run.record["styles"]):
    raise UserError(f"{run.record['stylized']}: styles {stylized.names} differ from the run's "
                    f"{run.record['styles']}")
  t0 = time.time()
  rows, means = evaluate_multistyle(scene, stylized, run.params, run.config, args.split,
                                    args.chunk)
  out_dir = os.path.join(args.run, f"eval_{args.split}")
  result = {"step": run.step, "split": args.split, "means": means, "views": rows}
  atomic_write_bytes(os.path.join(out_dir, "metrics.json"), json.dumps(result, indent=2).encode())
  # One figure: a held-out view, target above render, one column per style.
  i = scene.split(args.split)[0]
  out = render_styles(scene, run.params, run.config, int(i), stylized.vectors,
                      args.chunk)
  figure = video.write_grid(os.path.join(out_dir, "targets_vs_renders.png"),
                            [list(stylized.images[:, i] / 255.0), list(out["rgb"])])
  print(f"{'style':<28} {'PSNR':>7} {'SSIM':>7}")
  for name, m in means.items():
    print(f"{name:<28} {m['psnr']:7.2f} {m['ssim']:7.4f}")
  print_summary(f"multi-style eval on {args.split} (step {run.step})", [
      ("mean PSNR", f"{means['mean']['psnr']:.2f} dB"),
      ("mean SSIM", f"{means['mean']['ssim']:.4f}"),
      ("time", f"{time.time() - t0:.1f} s"), ("metrics", os.path.join(out_dir, "metrics.json")),
      ("figure", figure)])
