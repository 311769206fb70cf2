"""`msnerf paint train`: colour fields per style painted on a NeRF run's frozen geometry with
a style loss on rendered views (strokes that stay on the scene; render with `msnerf render`)."""

import os

from msnerf_jax.cli.common import print_summary, print_training_summary
from msnerf_jax.cli.config_args import add_trainer_options, trainer_config
from msnerf_jax.core import config as config_lib
from msnerf_jax.core.errors import UserError

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
  _register_train(verbs, formatter)
  _register_add(verbs, formatter)


def _register_train(verbs, formatter):
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
  add_trainer_options(p, config_lib.PaintConfig, _MAIN + ("checkpoint_every", "seed"),
                      len(_MAIN), "initial learning rate, decaying exponentially to --lr-final "
                                  "at --lr-decay-steps", "painted",
                      "every other painting setting")
  p.set_defaults(func=cmd_train)


def _register_add(verbs, formatter):
  a = verbs.add_parser(
      "add", formatter_class=formatter,
      help="add a new style to a painted run in minutes, without retraining it",
      description="Stylizes 1-3 key training views with per-frame AdaIN (--decoder), paints "
                  "them into 3D (each painted point takes its colour from the one key view "
                  "that sees it most: no averaging of views), fills what no key view sees "
                  "from its painted neighbours, then polishes the new style alone with the "
                  "run's style loss. The other styles are not touched.",
      epilog="example: msnerf paint add --run runs/lego_painted --style sketch.png "
             "--decoder runs/adain")
  a.add_argument("--run", required=True, help="painted run folder (`msnerf paint train`)")
  a.add_argument("--style", required=True, metavar="IMG", help="the new style's image")
  a.add_argument("--decoder", required=True,
                 help="AdaIN run (`msnerf adain train`) that stylizes the key views")
  a.add_argument("--key-views", nargs="+", type=int, default=None, metavar="I",
                 help="the key training views (indices into the training split; default: "
                      "--count of them spread around the scene)")
  a.add_argument("--count", type=int, default=2, help="key views chosen when --key-views is "
                                                     "not given (1-3; default: 2)")
  a.add_argument("--polish-steps", type=int, default=150,
                 help="steps of the style loss on the new style afterwards (default: 150)")
  a.add_argument("--stylize-scale", type=int, default=1,
                 help="stylize the key views enlarged N times (default: 1)")
  a.add_argument("--no-progress", action="store_true", help="no progress bars")
  a.set_defaults(func=cmd_add)


def cmd_train(args):
  from msnerf_jax.train import paint  # pylint: disable=g-import-not-at-top
  config, shows = trainer_config(args, config_lib.PaintConfig, "painted")
  summary = paint.train(config, args.nerf, args.styles, args.out, n_devices=args.devices,
                        parallel=args.parallel, progress=shows)
  if shows:
    term, nan = config.style_loss, float("nan")
    print_training_summary(
        "painting done", summary, "",
        f"msnerf render --run {args.out} --out {os.path.join(args.out, 'video')}",
        f"{term} {summary.get(term, nan):.4f}, content {summary.get('content', nan):.3f}, MSE "
        f"to the colour-transferred photos {summary.get('mse', nan):.4f}")


def cmd_add(args):
  from msnerf_jax.train import paint_add  # pylint: disable=g-import-not-at-top
  if not 1 <= args.count <= 3:
    raise UserError(f"--count {args.count}: choose 1 to 3 key views")
  if args.polish_steps < 0:
    raise UserError(f"--polish-steps {args.polish_steps}: must be >= 0")
  result = paint_add.add_style(args.run, args.style, args.decoder, args.key_views, args.count,
                               args.polish_steps, args.stylize_scale,
                               progress=not args.no_progress)
  print_summary("style added", [
      ("run", args.run), ("style", result["style"]),
      ("key views", " ".join(str(v) for v in result["views"])
       + f" (they see {100 * result['seen']:.0f}% of the painted points)"),
      ("time", f"{result['seconds']:.0f} s"),
      ("next", f"msnerf render --run {args.run} --style {result['style']} --out "
               f"{os.path.join(args.run, 'video_' + result['style'])}")])
