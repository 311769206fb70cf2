"""Helpers the CLI verbs share."""


def print_summary(title, items):
  """A titled block of aligned `key  value` lines (the end-of-command summary)."""
  print(f"\n{title}")
  width = max(len(k) for k, _ in items)
  for k, v in items:
    print(f"  {k:<{width}}  {v}")


def add_camera_path_arguments(parser) -> None:
  """--camera-path, --frames and --fps of the render verbs."""
  parser.add_argument("--camera-path", default=None, metavar="FILE",
                      help="render the cameras of this nerfstudio camera_path.json (its size, "
                           "field of view and fps) instead of the scene's path (`msnerf nerf "
                           "camera-path` writes the scene's path as one, to edit)")
  parser.add_argument("--frames", type=int, default=0, help="number of frames (0 = whole path)")
  parser.add_argument("--fps", type=float, default=None,
                      help="frames per second (default: the camera path's, else 24)")


def add_fast_argument(parser) -> None:
  """--fast of the render verbs: draw from the run's baked scene (kinds.baked)."""
  parser.add_argument("--fast", action="store_true",
                      help="NeRF and multi-style runs on the occupancy grid (the fast preset): "
                           "draw from the run's baked scene (RUN/baked.npz, baked on first "
                           "use; about 2x faster, PSNR within 0.1 dB on lego)")


def add_grids_argument(parser) -> None:
  """--grids of the verbs that paint a feature run."""
  parser.add_argument("--grids", type=int, choices=(1, 2, 4), default=None,
                      help="feature runs: relu4_1 cell grids each frame is painted on and "
                           "averaged over, the grid moved by half a cell (the decoder pins "
                           "its strokes to the grid, which moves with the camera): more "
                           "grids, steadier strokes, as many times the cost (default: "
                           "views.render_feature_styles')")


def check_path_options(frames: int, fps) -> None:
  """UserError unless --frames is >= 0 and --fps (when given) positive."""
  from msnerf_jax.core.errors import UserError  # pylint: disable=g-import-not-at-top
  if frames < 0:
    raise UserError(f"--frames {frames}: must be >= 0")
  if fps is not None and not fps > 0:
    raise UserError(f"--fps {fps}: must be positive")


def render_cameras(scene, args):
  """(cameras, fps, size text) the render verbs draw: the --camera-path file's cameras or the
  scene's path, resampled to --frames."""
  # pylint: disable=g-import-not-at-top
  from msnerf_jax.data.camera_path import read_camera_path
  from msnerf_jax.data.scene import spaced_indices
  check_path_options(args.frames, args.fps)
  if args.camera_path is None:
    return scene.path_poses(args.frames), args.fps or 24, f"{scene.width}x{scene.height}"
  cameras, fps = read_camera_path(args.camera_path)
  cameras = [cameras[i] for i in spaced_indices(len(cameras), args.frames)]
  return cameras, args.fps or fps, f"{cameras[0].width}x{cameras[0].height}"


def output_stem(path: str) -> str:
  """FILE, FILE.mp4 or FILE.gif -> FILE (the stem the .mp4/.gif/_*.png outputs share)."""
  import os  # pylint: disable=g-import-not-at-top
  return os.path.splitext(path)[0] if path.endswith((".mp4", ".gif", ".png")) else path


def load_run_and_scene(run_dir: str, kind: str):
  """(run, scene) of a run folder of the given kind: `runs.load_run_and_scene`."""
  from msnerf_jax.kinds import runs  # pylint: disable=g-import-not-at-top
  return runs.load_run_and_scene(run_dir, kind)


def print_training_summary(title: str, summary, what: str, next_hint: str,
                           last_batch: str = "") -> None:
  """The end-of-training block of a trainer's summary dict (see train.loop.fit); the last
  batch's loss and PSNR followed by `what`, or `last_batch` where given."""
  nan = float("nan")
  print_summary(title, [
      ("run", summary["run_dir"]),
      ("steps", f"{summary['steps']} (resumed from {summary['resumed_from']})"),
      ("time", f"{summary['seconds']:.0f} s on {summary['devices']} device(s)"
               + (f" of {summary['processes']} processes" if summary.get("processes", 1) > 1
                  else "")),
      ("last batch", last_batch or f"loss {summary.get('loss', nan):.4f}, "
                                   f"PSNR {summary.get('psnr', nan):.2f} dB{what}"),
      ("next", next_hint)])


def add_parallel_arguments(parser) -> None:
  """--devices, --parallel and the multi-process options of the training verbs."""
  group = parser.add_argument_group(
      "devices and processes",
      "Data parallel: every device computes its share of the batch, gradients are averaged. "
      "Several processes (hosts) train one run with jax.distributed: start the same command "
      "in each, with --coordinator, --num-processes and --process-id (or --coordinator auto "
      "under SLURM and the other clusters jax.distributed detects); process 0 writes the run "
      "folder, which every process must see (a shared file system).")
  group.add_argument("--devices", type=int, default=None,
                     help="devices to train on (default: all; with several processes, all "
                          "devices of all of them)")
  group.add_argument("--parallel", default="shard_map", choices=("shard_map", "pmap"),
                     help="jax.shard_map over a mesh of every device, or jax.pmap over this "
                          "process's (one process only); the same result")
  group.add_argument("--coordinator", default=None, metavar="HOST:PORT",
                     help="process 0's address (it listens on PORT), or 'auto'")
  group.add_argument("--num-processes", type=int, default=None, metavar="N",
                     help="how many processes train together")
  group.add_argument("--process-id", type=int, default=None, metavar="I",
                     help="this process's id, 0..N-1 (0 writes the run folder)")
  group.add_argument("--coordinator-timeout", type=float, default=300.0, metavar="S",
                     help="seconds to wait for every process to join")


def start_processes(args) -> bool:
  """Joins the other processes when --coordinator is given (before anything else uses
  JAX); returns whether this process prints (process 0, or the only one)."""
  # pylint: disable=g-import-not-at-top
  from msnerf_jax.core import distributed
  from msnerf_jax.core.errors import UserError
  if args.coordinator is None:
    if args.num_processes is not None or args.process_id is not None:
      raise UserError("--num-processes and --process-id need --coordinator HOST:PORT")
    return True
  distributed.initialize(args.coordinator, args.num_processes, args.process_id,
                         args.coordinator_timeout)
  return distributed.is_primary()
