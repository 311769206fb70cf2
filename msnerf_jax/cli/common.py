"""Helpers the CLI verbs share."""


def print_summary(title, items):
  """A titled block of aligned `key  value` lines (the end-of-command summary)."""
  print(f"\n{title}")
  width = max(len(k) for k, _ in items)
  for k, v in items:
    print(f"  {k:<{width}}  {v}")


def path_poses(scene, frames: int):
  """The scene's render path, resampled to `frames` cameras (0 = all): `Scene.path_poses`."""
  return scene.path_poses(frames)


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
