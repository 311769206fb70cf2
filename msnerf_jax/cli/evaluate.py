"""`msnerf evaluate`: consistency and style metrics of styled runs against the baselines."""

import os

from msnerf_jax.cli.common import print_summary
from msnerf_jax.core.errors import UserError


def register(commands, formatter):
  p = commands.add_parser(
      "evaluate", formatter_class=formatter,
      help="consistency and style metrics of multi-style runs vs the baselines",
      description="Renders the camera path in each style with each multi-style run and the "
                  "baselines (per-frame AdaIN on the NeRF's renders; NeRFs trained on one "
                  "style alone, if given) and reports short/long-range warped RMSE and LPIPS "
                  "(k = 1, 7) and the style distance to the style image. Writes "
                  "results.md/.csv/.json and frames.png to --out.",
      epilog="example: msnerf evaluate --run runs/ms runs/ms_density --single-style "
             "runs/single_mondrian --out runs/eval")
  p.add_argument("--run", required=True, nargs="+", metavar="RUN",
                 help="multi-style run folder(s) of one stylized dataset (e.g. the standard "
                      "and the density-aware variant), or one painted run (`msnerf paint "
                      "train`: painted against per-frame AdaIN with --decoder, and the "
                      "metric's floors)")
  p.add_argument("--single-style", nargs="+", default=(), metavar="NERF_RUN",
                 help="NeRF runs trained on one style of that dataset (`msnerf nerf train "
                      "--stylized DIR --style NAME`), each compared on its style")
  p.add_argument("--features", nargs="+", default=(), metavar="FEATURE_RUN",
                 help="feature-field runs of the same scene (`msnerf features train`), each "
                      "painting every evaluated style from its image (row feature-field)")
  p.add_argument("--painted", nargs="+", default=(), metavar="PAINTED_RUN",
                 help="painted runs of the same scene (`msnerf paint train`), each compared "
                      "on the evaluated styles it painted (row painted)")
  p.add_argument("--stylize-scale", type=int, default=1,
                 help="with a painted --run: per-frame AdaIN stylizes each frame enlarged "
                      "this many times (default: 1)")
  p.add_argument("--styles", nargs="+", default=None, metavar="NAME",
                 help="training styles to evaluate (default: all stylized ones)")
  p.add_argument("--decoder", default=None,
                 help="AdaIN run for the per-frame baseline (default: the dataset's)")
  p.add_argument("--frames", type=int, default=40, help="frames of the camera path")
  p.add_argument("--chunk", type=int, default=None, help="rays per rendering call")
  p.add_argument("--out", required=True, help="folder for the tables and figures")
  p.set_defaults(func=cmd_evaluate)


def cmd_evaluate(args):
  # pylint: disable=g-import-not-at-top
  from msnerf_jax.eval import evaluate
  if args.frames < 9:
    raise UserError(f"--frames {args.frames}: need at least 9 (long range compares t, t + 7)")
  if os.path.isfile(args.out):
    raise UserError(f"{args.out}: is a file, expected a folder")
  from msnerf_jax.kinds.runs import read_run_file
  if len(args.run) == 1 and read_run_file(args.run[0]).get("kind") == "painted":
    from msnerf_jax.eval import painted
    if args.decoder is None:
      raise UserError("--decoder: required with a painted --run (the per-frame baseline)")
    result = painted.evaluate_painted(args.run[0], args.decoder, args.out, args.frames,
                                      args.stylize_scale, args.chunk)
    print("\n".join(painted.ratio_table(result["ratios"])))
  else:
    result = evaluate.evaluate_run(args.run, args.out, args.styles, args.decoder, args.frames,
                                   args.chunk, single_style_runs=args.single_style,
                                   feature_runs=args.features, painted_runs=args.painted)
    evaluate.print_table(result["rows"])
  print_summary("evaluation done", [("time", f"{result['seconds']:.0f} s"),
                                    ("written", ", ".join(result["files"]))])
