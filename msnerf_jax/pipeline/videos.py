"""Videos and grids of a multi-style run along its camera path (what `msnerf render` and the
pipeline's renders stage write). The style vectors come from `msnerf_jax.style.vectors`."""

from typing import Any, List, Optional, Sequence

import numpy as np

from msnerf_jax.style import vectors as styles_lib
from msnerf_jax.data import video
from msnerf_jax.core.progress import progress_bar
from msnerf_jax.kinds.base import StyleRenderer


def spaced_views(poses: Sequence[Any], n: int) -> List[Any]:
  """n cameras of `poses` (c2w [P, 3, 4] or cameras.Camera), (P - 1) / n apart, from the
  first."""
  return [poses[i] for i in np.linspace(0, len(poses) - 1, max(1, n) + 1)[:-1].round().astype(int)]


def write_render_videos(render: StyleRenderer, poses: np.ndarray, main: np.ndarray,
                        ends: Optional[Sequence[np.ndarray]], stem: str, fps: int,
                        grid_steps: int, grid_views: int, progress: bool = True) -> List[str]:
  """The files of `msnerf render` for a multi-style run; returns their paths.

  STEM.mp4/.gif: every camera of `poses` [P, 3, 4] in the style `main` [1024]. With `ends`
  (two style vectors A, B) also STEM_morph.mp4/.gif, whose style moves from A to B along the
  path, and STEM_grid.png: `grid_views` rows (cameras) x `grid_steps` columns (A ... B).
  """
  frames = [render(c2w, [main])[0]
            for c2w in progress_bar(poses, desc="style video", disable=not progress)]
  written = video.write_videos(stem, frames, fps)
  if ends is None:
    return written
  path = styles_lib.sweep(ends[0], ends[1], len(poses))
  frames = [render(c2w, [v])[0] for c2w, v in progress_bar(
      list(zip(poses, path)), desc="morph video", disable=not progress)]
  written += video.write_videos(stem + "_morph", frames, fps)
  steps = styles_lib.sweep(ends[0], ends[1], max(2, grid_steps))
  rows = [list(render(c2w, steps))  # one sweep per view
          for c2w in progress_bar(spaced_views(poses, grid_views), desc="grid",
                                  disable=not progress)]
  written.append(video.write_grid(stem + "_grid.png", rows))
  return written
