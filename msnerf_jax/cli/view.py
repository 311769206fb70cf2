"""`msnerf view`: a run in the browser (msnerf_jax.viewer)."""

from msnerf_jax.cli.common import add_grids_argument
from msnerf_jax.core.errors import UserError
from msnerf_jax.train.stop import stop_requests

MAX_FULL_SIDE = 4096


def register(commands, formatter):
  p = commands.add_parser(
      "view", formatter_class=formatter,
      help="look around a run in the browser: orbit, styles, blends, strength, uploads",
      description="Serves a local web page (viser) that renders a NeRF, multi-style or feature "
                  "run from "
                  "the browser's camera: a low-resolution frame while the camera moves, the "
                  "full one when it stops. Style menus, a blend slider, a strength slider and "
                  "an upload field for any style image; buttons to snap to the nearest "
                  "training view, save the view as PNG and add camera keyframes (a "
                  "camera_path.json for `msnerf render --camera-path`). Ctrl-C or SIGTERM "
                  "stops it.",
      epilog="example: msnerf view --run runs/lego_pipeline/multistyle  (then open the printed "
             "address)")
  p.add_argument("--run", required=True, help="a NeRF, multi-style or feature run folder")
  p.add_argument("--styles", nargs="+", default=[], metavar="IMG",
                 help="style images added to the style menus (a multi-style or feature run)")
  p.add_argument("--decoder", default=None,
                 help="a feature run: the AdaIN run whose decoder paints it (default: the "
                      "one it was trained with)")
  add_grids_argument(p)
  p.add_argument("--port", type=int, default=8080, help="port to serve on (0: any free port)")
  p.add_argument("--host", default="127.0.0.1",
                 help="address to listen on: 127.0.0.1 (this machine only) unless you choose "
                      "to share it, e.g. 0.0.0.0")
  p.add_argument("--out", default=None,
                 help="folder of saved views and keyframes (default RUN/viewer)")
  p.add_argument("--exact", action="store_true",
                 help="draw with the exact renderer; by default a NeRF or multi-style run on "
                      "the occupancy grid (the fast preset) is drawn from its baked scene "
                      "(RUN/baked.npz, baked on first use)")
  p.add_argument("--full-side", type=int, default=None, metavar="N",
                 help="full frames (once the camera rests) of up to N x N pixels, shaped to "
                      "the window and never more than its own, e.g. 800 (16..4096; default: "
                      "the training images' size). Frames in progress are dropped when the "
                      "camera moves, so a large N costs waiting, not steering")
  p.set_defaults(func=cmd_view)


def cmd_view(args):
  if not 0 <= args.port <= 65535:
    raise UserError(f"--port {args.port}: must be in 0..65535")
  if args.full_side is not None and not 16 <= args.full_side <= MAX_FULL_SIDE:
    raise UserError(f"--full-side {args.full_side}: must be in 16..{MAX_FULL_SIDE}")
  try:
    from msnerf_jax.viewer import network, server  # pylint: disable=g-import-not-at-top
  except ImportError as e:
    raise UserError(f"the viewer needs viser ({e.name} is not installed): "
                    "pip install viser") from None
  print(f"msnerf view: loading {args.run}")
  viewer = server.open_viewer(args.run, args.out, args.host, args.port,
                              style_paths=args.styles, decoder_dir=args.decoder,
                              grids=args.grids, exact=args.exact, full_side=args.full_side)
  where = ("this machine only" if network.is_loopback(args.host)
           else "reachable from the network: anyone who can connect sees and uses it")
  print(f"msnerf view: serving {args.run} at {viewer.url} ({where}); saved files go to "
        f"{viewer.out_dir}. Ctrl-C stops.")
  # Ctrl-C and SIGTERM stop it, also where the shell that started it in the background
  # ignores SIGINT (the handlers are ours, not inherited).
  try:
    with stop_requests() as requested:
      server.serve_forever(viewer, should_stop=lambda: requested() is not None)
  except KeyboardInterrupt:  # a second signal while stopping
    pass
  print("msnerf view: stopped")
