"""Videos and grids of a multi-style run along its camera path (what `msnerf render` and the
pipeline's renders stage write). The style vectors come from `msnerf_jax.style.vectors`."""

from typing import Any, Callable, List, Optional, Sequence

import numpy as np

from msnerf_jax.style import vectors as styles_lib
from msnerf_jax.data import video
from msnerf_jax.core.progress import progress_bar

# (camera: c2w [3, 4] or cameras.Camera, K style vectors [1024]) -> K images [K, H, W, 3].
StyleRenderer = Callable[[np.ndarray, Sequence[np.ndarray]], np.ndarray]


def style_renderer(run: Any, scene: Any, chunk: Optional[int] = None) -> StyleRenderer:
  """Renders one camera of a loaded multi-style run in K styles at once (one trunk pass)."""
  from msnerf_jax.kinds.views import render_styles  # pylint: disable=g-import-not-at-top
  return lambda c2w, styles: render_styles(scene, run.params, run.config, c2w,
                                           np.stack(styles), chunk)["rgb"]


def feature_style_renderer(run: Any, scene: Any, decoder: Any, content_stats: Any,
                           chunk: Optional[int] = None, grids: Optional[int] = None
                           ) -> StyleRenderer:
  """Renders one camera of a loaded feature run in K styles: one feature render, K AdaIN
  maps and decodes by `decoder` (stylize.Decoder); content_stats (mean, std) [512]; on
  `grids` cell grids (views.render_feature_styles'; None: its default). On
  white-background (Blender) scenes the frames are put over white by the NeRF's opacity,
  as the stylized views a multi-style run learns are."""
  # pylint: disable=g-import-not-at-top
  from msnerf_jax.style.features import DEFAULT_GRIDS
  from msnerf_jax.kinds.views import render_feature_styles, render_view
  grids = grids or DEFAULT_GRIDS

  def render(camera, styles):
    frames = render_feature_styles(scene, run.params, run.config, camera, decoder,
                                   content_stats, np.stack(styles), chunk, grids)
    if not scene.white_background:
      return frames
    acc = render_view(scene, run.params["nerf"], run.config.nerf, camera,
                      chunk)["accumulation"][..., None]
    return frames * acc + (1.0 - acc)
  return render


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
