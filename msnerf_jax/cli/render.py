"""`msnerf render`: a styled run's videos and interpolation grid along a camera path, for
any run kind with styles (a NeRF run: as `msnerf nerf render`)."""

import time

from msnerf_jax.cli.common import (add_camera_path_arguments, add_fast_argument,
                                   add_grids_argument, load_run_and_scene, output_stem,
                                   print_summary, render_cameras)
from msnerf_jax.core.errors import UserError


def register(commands, formatter):
  p = commands.add_parser(
      "render", formatter_class=formatter,
      help="videos and an interpolation grid of a run along its render path",
      description="For a multi-style run, writes OUT.mp4/.gif in one style, OUT_morph.mp4/.gif "
                  "whose style moves from A to B along the path, and OUT_grid.png (interpolation "
                  "steps x views). A STYLE is a training style's name or any image file (its "
                  "style vector is computed, so styles never trained on work too). For a NeRF "
                  "run, same as `msnerf nerf render`.",
      epilog="examples: msnerf render --run runs/ms --out runs/ms/video --style starry_night\n"
             "  msnerf render --run runs/ms --out v --interp starry_night scream --t 0.3\n"
             "  msnerf render --run runs/ms --out v --style scream --strength 0.5")
  p.add_argument("--run", required=True, help="run folder (multi-style, feature field, or NeRF)")
  p.add_argument("--out", required=True, help="output file stem")
  p.add_argument("--style", default=None, metavar="STYLE",
                 help="style of the main video (default: the first training style)")
  p.add_argument("--interp", nargs=2, default=None, metavar=("A", "B"),
                 help="main video in the blend (1 - t) A + t B of two styles")
  p.add_argument("--t", type=float, default=0.5, help="blend weight of B for --interp")
  p.add_argument("--strength", type=float, default=None,
                 help="main video at this strength between the original scene (0) and the "
                      "style (1); needs a run trained with --include-original")
  p.add_argument("--morph", nargs=2, default=None, metavar=("A", "B"),
                 help="styles of the morph video and the grid (default: the first two)")
  p.add_argument("--grid-steps", type=int, default=5, help="interpolation steps in the grid")
  p.add_argument("--grid-views", type=int, default=3, help="views (rows) in the grid")
  p.add_argument("--decoder", default=None, metavar="ADAIN_RUN",
                 help="feature runs: the AdaIN run that paints the features (default: the one "
                      "the run was trained for)")
  add_grids_argument(p)
  add_camera_path_arguments(p)
  p.add_argument("--chunk", type=int, default=None, help="rays per rendering call")
  add_fast_argument(p)
  p.set_defaults(func=cmd_render)


def cmd_render(args):
  # pylint: disable=g-import-not-at-top
  from msnerf_jax.pipeline import videos as style_videos
  from msnerf_jax.style import vectors as styles_lib
  from msnerf_jax.cli import nerf as nerf_cli
  from msnerf_jax.kinds.registry import get_kind
  from msnerf_jax.kinds.baked import baked_views
  from msnerf_jax.kinds.renderers import style_rendering
  from msnerf_jax.kinds.runs import read_run_file
  kind = get_kind(read_run_file(args.run)["kind"])
  if kind.style_renderer is None:
    return nerf_cli.cmd_render(args)
  styles_lib.check_unit("--t", args.t)
  styles_lib.check_unit("--strength", args.strength)
  if kind.paints_any_style and args.style is None and not args.interp:
    raise UserError(f"{args.run}: a {kind.title} run paints any style image: give --style IMG "
                    "(or --interp A B)")
  run, scene = load_run_and_scene(args.run, kind.name)
  # A painting kind's "original" is the scene's own statistics: --strength blends towards it.
  vectors, size, renderer = style_rendering(run, scene, args.chunk, args.grids, args.decoder)
  if args.fast:
    draw = baked_views(run, scene)
    renderer = lambda camera, styles: draw(camera, styles)["rgb"]
  cache = {}
  main, label = styles_lib.choose_main_style(vectors, cache, args.run, args.style, args.interp,
                                             args.t, args.strength, size)
  morph, ends = styles_lib.morph_ends(vectors, cache, args.morph, size)
  poses, fps, size = render_cameras(scene, args)
  t0 = time.time()
  written = style_videos.write_render_videos(
      renderer, poses, main, ends,
      output_stem(args.out), fps, args.grid_steps, args.grid_views)
  seconds = time.time() - t0
  print_summary(f"{kind.title} render done", [
      ("style", label), ("morph", " -> ".join(morph) if morph else "(one style only)"),
      ("frames", f"{len(poses)} of {size}"),
      ("time", f"{seconds:.1f} s"), ("written", ", ".join(written))])
