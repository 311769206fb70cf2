"""The pipeline's last stage: the multi-style run's video of every style side by side and of
a style morph, the feature field's, and the grid of styles x views of both models."""

import os

import numpy as np

from msnerf_jax.core import files
from msnerf_jax.core.progress import progress_bar
from msnerf_jax.data import images as images_lib
from msnerf_jax.data import video
from msnerf_jax.data.stylized import style_name
from msnerf_jax.kinds.renderers import style_rendering
from msnerf_jax.kinds.runs import load_run_and_scene
from msnerf_jax.pipeline.settings import Settings
from msnerf_jax.style import vectors as styles_lib


def _feature_renderer(out, styles, names, s: Settings):
  """Renders one camera in the styles `names` by the feature run (the statistics of the style
  images cover-cropped as per-frame AdaIN crops them; "original": the scene's own, i.e. the
  decoder's picture of the scene's features)."""
  run, scene = load_run_and_scene(os.path.join(out, "features"), "features")
  table, size, render = style_rendering(run, scene, s.chunk or None)
  cache = {}
  vectors = {**table,
             **{style_name(p): styles_lib.resolve_style(p, {}, cache, size) for p in styles}}
  return lambda c2w: render(c2w, [vectors[n] for n in names])


def _style_tile(styles, name, scene):
  """The grid's first column: the style picture of `name` cover-cropped to the view's size,
  or, for the original, the first training photo."""
  paths = {style_name(p): p for p in styles}
  if name not in paths:
    return scene.images[scene.split("train")[0]]
  return images_lib.cover_crop(images_lib.read_image(paths[name], max_side=1024), scene.height,
                               scene.width)


def run_renders(out, styles, s: Settings, progress):
  """Writes OUT/renders/ (render_files) and grid_rows.txt; returns the files written."""
  run, scene = load_run_and_scene(os.path.join(out, "multistyle"), "multistyle")
  vectors, _, render = style_rendering(run, scene, s.chunk or None)
  names = list(vectors)
  poses = scene.path_poses(s.frames)
  folder = os.path.join(out, "renders")
  # All styles at once per camera (one trunk pass): the side-by-side video and the grid.
  sweeps = [render(c2w, list(vectors.values()))
            for c2w in progress_bar(poses, desc="render styles", disable=not progress)]
  written = video.write_videos(os.path.join(folder, "styles"),
                               [video.grid([sw]) for sw in sweeps], s.fps)
  morph_names = [n for n in names if n != styles_lib.ORIGINAL] or names
  path = styles_lib.morph_loop([vectors[n] for n in morph_names], len(poses))
  frames = [render(c2w, [v])[0] for c2w, v in progress_bar(
      list(zip(poses, path)), desc="render morph", disable=not progress)]
  written += video.write_videos(os.path.join(folder, "morph"), frames, s.fps)
  views = np.linspace(0, len(poses), max(1, s.grid_views) + 1)[:-1].round().astype(int)
  groups = [[[_style_tile(styles, n, scene)], [sweeps[v][m] for v in views]]
            for m, n in enumerate(names)]
  labels = ["style", "multi-style NeRF (paper)"]
  if s.features_steps:
    # One feature render per camera, every style painted from it.
    render_features = _feature_renderer(out, styles, names, s)
    feature_sweeps = [render_features(c2w) for c2w in progress_bar(
        poses, desc="render feature field", disable=not progress)]
    written += video.write_videos(os.path.join(folder, "features"),
                                  [video.grid([sw]) for sw in feature_sweeps],
                                  s.fps)
    for m, row in enumerate(groups):
      row.append([feature_sweeps[v][m] for v in views])
    labels.append("feature field (AdaIN in 3D)")
  path = os.path.join(folder, "grid.png")
  images_lib.write_image(path, video.labelled_grid(groups, names, labels))
  written.append(path)
  files.atomic_write_bytes(os.path.join(folder, "grid_rows.txt"),
                           "".join(n + "\n" for n in names).encode())
  return written
