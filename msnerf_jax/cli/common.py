"""Helpers the CLI verbs share."""


def print_summary(title, items):
  """A titled block of aligned `key  value` lines (the end-of-command summary)."""
  print(f"\n{title}")
  width = max(len(k) for k, _ in items)
  for k, v in items:
    print(f"  {k:<{width}}  {v}")


def path_poses(scene, frames: int):
  """The scene's render path, resampled to `frames` cameras (0 = all of them)."""
  import numpy as np  # pylint: disable=g-import-not-at-top
  poses = scene.render_poses
  if frames > 0:
    poses = poses[np.linspace(0, len(poses) - 1, frames).round().astype(int)]
  return poses


def output_stem(path: str) -> str:
  """FILE, FILE.mp4 or FILE.gif -> FILE (the stem the .mp4/.gif/_*.png outputs share)."""
  import os  # pylint: disable=g-import-not-at-top
  return os.path.splitext(path)[0] if path.endswith((".mp4", ".gif", ".png")) else path
