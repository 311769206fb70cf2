"""`msnerf paint train`: colour fields per style painted on a NeRF run's frozen geometry with
a style loss on rendered views (strokes that stay on the scene; render with `msnerf render`)."""

import os

from msnerf_jax.cli.common import add_parallel_arguments, print_summary, start_processes
from msnerf_jax.cli.config_args import (add_config_arguments, add_config_option,
                                        config_overrides, start_config)
from msnerf_jax.core import config as config_lib
from msnerf_jax.core.errors import UserError

_DEFAULTS = config_lib.PaintConfig()
# The options `msnerf paint train --help` lists first (--lr sets lr_init).
_MAIN = ("steps", "init_steps", "resolution", "style_loss")


def register(commands, formatter):
  pt = commands.add_parser(
      "paint", formatter_class=formatter,
      help="paint styles in 3D: colour fields on a NeRF's frozen geometry, steady strokes",
      description="Each style becomes a colour field over the frozen geometry of a NeRF "
                  "run, optimised with a style loss on whole rendered views (ARF's "
                  "nearest-neighbour feature matching), so its strokes are painted on the "
                  "scene and stay there as the camera moves. Render with `msnerf render "
                  "--run RUN --style NAME`.")
  verbs = pt.add_subparsers(dest="verb", metavar="VERB", required=True)
  p = verbs.add_parser(
      "train", formatter_class=formatter,
      help="paint M styles in one run (re-run the same command to resume)",
      description="Caches the training views' samples of the NeRF once (in the run), fits "
                  "each style's colour grid to the photos colour-transferred to the style, "
                  "then optimises it with the style loss on rendered training views: no "
                  "per-view target, so no two views disagree. The NeRF is copied into the "
                  "run and gets no gradient and no optimizer state.",
      epilog="example: msnerf paint train --nerf runs/lego_nerf --styles mondrian.jpg "
             "brushstrokes.jpg --out runs/lego_painted")
  p.add_argument("--nerf", required=True, help="NeRF run folder (`msnerf nerf train`)")
  p.add_argument("--styles", nargs="*", required=True, metavar="IMG",
                 help="style images, one colour field each (named by their file names)")
  p.add_argument("--out", required=True, help="run folder")
  add_config_arguments(p, config_lib.PaintConfig, _DEFAULTS, names=_MAIN)
  p.add_argument("--lr", type=float, default=None,
                 help=f"initial learning rate, decaying exponentially to --lr-final at the "
                      f"last step (default: {_DEFAULTS.lr_init})")
  add_config_arguments(p, config_lib.PaintConfig, _DEFAULTS,
                       names=("checkpoint_every", "seed"))
  add_parallel_arguments(p)
  add_config_option(p, "painted")
  add_config_arguments(p, config_lib.PaintConfig, _DEFAULTS,
                       title="every other painting setting",
                       skip=_MAIN + ("lr_init", "checkpoint_every", "seed"))
  p.set_defaults(func=cmd_train)


def cmd_train(args):
  from msnerf_jax.train import paint  # pylint: disable=g-import-not-at-top
  shows = start_processes(args)
  if os.path.isfile(args.out):
    raise UserError(f"{args.out}: is a file, expected a run folder")
  built = config_lib.override(config_lib.PaintConfig(), lr_init=args.lr,
                              **config_overrides(args, config_lib.PaintConfig))
  config = start_config(args, "painted", built, {"lr_init": "lr"})
  summary = paint.train(config, args.nerf, args.styles, args.out, n_devices=args.devices,
                        parallel=args.parallel, progress=shows)
  if shows:
    term = config.style_loss
    print_summary("painting done", [
        ("run", summary["run_dir"]),
        ("steps", f"{summary['steps']} (resumed from {summary['resumed_from']})"),
        ("time", f"{summary['seconds']:.0f} s on {summary['devices']} device(s)"),
        ("last batch", f"{term} {summary.get(term, float('nan')):.4f}, content "
                       f"{summary.get('content', float('nan')):.3f}, MSE to the "
                       f"colour-transferred photos {summary.get('mse', float('nan')):.4f}"),
        ("next", f"msnerf render --run {args.out} --out {os.path.join(args.out, 'video')}")])
