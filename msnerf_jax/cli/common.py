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


def check_path_options(frames: int, fps) -> None:
  """UserError unless --frames is >= 0 and --fps (when given) positive."""
  from msnerf_jax.errors import UserError  # pylint: disable=g-import-not-at-top
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
  from msnerf_jax import runs  # pylint: disable=g-import-not-at-top
  return runs.load_run_and_scene(run_dir, kind)


def print_training_summary(title: str, summary, what: str, next_hint: str) -> None:
  """The end-of-training block of a trainer's summary dict (see train.loop.fit)."""
  print_summary(title, [
      ("run", summary["run_dir"]),
      ("steps", f"{summary['steps']} (resumed from {summary['resumed_from']})"),
      ("time", f"{summary['seconds']:.0f} s on {summary['devices']} device(s)"),
      ("last batch", f"loss {summary.get('loss', float('nan')):.4f}, "
                     f"PSNR {summary.get('psnr', float('nan')):.2f} dB{what}"),
      ("next", next_hint)])
