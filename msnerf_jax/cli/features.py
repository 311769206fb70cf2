"""`msnerf features train`: a VGG feature field on a NeRF run's frozen geometry (AdaIN in 3D;
its runs render with `msnerf render --style IMG`)."""

import os

from msnerf_jax.core import config as config_lib
from msnerf_jax.cli.common import print_training_summary
from msnerf_jax.cli.config_args import add_trainer_options, trainer_config

# The options `msnerf features train --help` lists first (--lr sets lr_init).
_MAIN = ("stylize_scale", "steps", "batch_cells")


def register(commands, formatter):
  ff = commands.add_parser(
      "features", formatter_class=formatter,
      help="train a VGG feature field: any style image at once, strokes fixed to the scene",
      description="The scene's VGG features (the AdaIN encoder's relu4_1) as a field on the "
                  "frozen geometry of a NeRF run. A style is then one affine map of that "
                  "field for every view (AdaIN in 3D, content statistics pooled over the "
                  "scene) and the AdaIN decoder paints it: render with `msnerf render --run "
                  "RUN --style IMG`.")
  verbs = ff.add_subparsers(dest="verb", metavar="VERB", required=True)
  p = verbs.add_parser(
      "train", formatter_class=formatter,
      help="train a feature field (re-run the same command to resume)",
      description="Encodes the training views once (cached in the run), then fits a hash-grid "
                  "feature field, volume-rendered with the NeRF's frozen weights (the NeRF is "
                  "copied into the run and gets no gradient and no optimizer state), to the "
                  "relu4_1 cells of the views: each cell's feature is the mean of several "
                  "jittered rays inside its 8x8 pixel block, L1 to the encoder's.",
      epilog="example: msnerf features train --nerf runs/lego_nerf --decoder runs/adain "
             "--stylize-scale 4 --out runs/lego_features")
  p.add_argument("--nerf", required=True, help="NeRF run folder (`msnerf nerf train`)")
  p.add_argument("--decoder", required=True,
                 help="AdaIN run folder (`msnerf adain train`) that will paint the features")
  p.add_argument("--out", required=True, help="run folder")
  add_trainer_options(p, config_lib.FeatureConfig, _MAIN + ("checkpoint_every", "seed"),
                      len(_MAIN), "initial learning rate, decaying exponentially to --lr-final "
                                  "at --lr-decay-steps", "features",
                      "every other feature-field setting")
  p.set_defaults(func=cmd_train)


def cmd_train(args):
  from msnerf_jax.train import features  # pylint: disable=g-import-not-at-top
  config, shows = trainer_config(args, config_lib.FeatureConfig, "features")
  summary = features.train(config, args.nerf, args.decoder, args.out, n_devices=args.devices,
                           parallel=args.parallel, progress=shows)
  if shows:
    nan = float("nan")
    print_training_summary(
        "feature training done", summary, "",
        f"msnerf render --run {args.out} --style STYLE.jpg --out "
        f"{os.path.join(args.out, 'video')}",
        f"MSE {summary.get('mse', nan):.4f}, L1 {summary.get('l1', nan):.4f} (relu4_1)"
        + (f"; decoded patches MSE {summary['decode']:.4f}" if "decode" in summary else ""))
