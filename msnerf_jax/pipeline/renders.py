"""The pipeline's last stage: each trained model's video of every style side by side, a style
morph of the painted run (or of the paper's model without one), and one grid of styles x views
whose column groups are the methods in the order users see them: painted, feature field, the
paper's multi-style NeRF, per-frame AdaIN (each NeRF view stylized on its own)."""

import os
from typing import List, NamedTuple

import numpy as np

from msnerf_jax.core import files
from msnerf_jax.core.progress import progress_bar
from msnerf_jax.data import images as images_lib
from msnerf_jax.data import video
from msnerf_jax.data.stylized import read_manifest, style_name
from msnerf_jax.eval import paths
from msnerf_jax.kinds.registry import get_kind
from msnerf_jax.kinds.renderers import style_rendering
from msnerf_jax.kinds.runs import load_run_and_scene
from msnerf_jax.kinds.stylized_scenes import load_decoder
from msnerf_jax.models import vgg
from msnerf_jax.pipeline.settings import Settings
from msnerf_jax.style import vectors as styles_lib


class Method(NamedTuple):
  kind: str  # the run kind, and the stage's run folder under OUT.
  video: str  # OUT/renders/<video>.mp4/.gif: every style side by side.
  label: str  # the grid's column group.


PAINTED = Method("painted", "painted", "painted (strokes in 3D)")
FEATURES = Method("features", "features", "feature field (AdaIN in 3D)")
MULTISTYLE = Method("multistyle", "styles", "multi-style NeRF (paper)")
PER_FRAME = "per-frame AdaIN"


def methods(s: Settings) -> List[Method]:
  """The trained models the renders show, first the one users should see first."""
  return (([PAINTED] if s.paint_steps else []) + ([FEATURES] if s.features_steps else [])
          + [MULTISTYLE])


def morph_name(s: Settings) -> str:
  """The style-morph video's name: the first method's."""
  first = methods(s)[0]
  return "morph" if first is MULTISTYLE else f"{first.video}_morph"


def render_files(s: Settings) -> List[str]:
  """The files the renders stage writes."""
  names = [m.video for m in methods(s)] + [morph_name(s)]
  return [n + ext for n in names for ext in (".mp4", ".gif")] + ["grid.png"]


def _renderer(run, scene, method: Method, styles, names, s: Settings):
  """(render of one camera in K styles given as K vectors -> [K, H, W, 3], {name: vector} of
  `names`) of one method's loaded run. The feature field paints the style images
  (cover-cropped as per-frame AdaIN crops them); the others render their own trained styles
  of those names ("original": the scene's own look)."""
  table, size, render = style_rendering(run, scene, s.chunk or None)
  cache = {}
  if method is FEATURES:
    table = {**table, **{style_name(p): styles_lib.resolve_style(p, {}, cache, size)
                         for p in styles}}
  return render, {n: table[n] for n in names}


def _per_frame_adain(out, decoder_dir, names, poses) -> List[List[np.ndarray]]:
  """[style][view] frames of the NeRF at `poses`, each stylized on its own by the decoder as
  the stylized dataset was (its alpha and scale; "original": the NeRF's frame itself)."""
  nerf, scene = load_run_and_scene(os.path.join(out, "nerf"), "nerf")
  manifest = read_manifest(os.path.join(out, "stylized"))
  sources = {x["name"]: x for x in manifest["styles"] if x.get("source")}
  base = paths.nerf_path(scene, nerf.params, nerf.config, poses)
  decoder, encoder = load_decoder(decoder_dir), vgg.load_vgg_params()
  rows = []
  for name in names:
    if name not in sources:
      rows.append([b["rgb"] for b in base])
      continue
    picture = images_lib.read_image(sources[name]["source"], max_side=1024)
    rows.append(paths.per_frame_adain(decoder, encoder, base, picture, sources[name]["alpha"],
                                      scene.white_background, manifest["stylize_scale"]))
  return rows


def _style_tile(styles, name, scene):
  """The grid's first column: the style picture of `name` cover-cropped to the view's size,
  or, for the original, the first training photo."""
  by_name = {style_name(p): p for p in styles}
  if name not in by_name:
    return scene.images[scene.split("train")[0]]
  return images_lib.cover_crop(images_lib.read_image(by_name[name], max_side=1024),
                               scene.height, scene.width)


def _write_morph(folder, name, render, vectors, poses, s: Settings, progress) -> List[str]:
  """OUT/renders/<name>.mp4/.gif: one orbit whose style morphs through the styles."""
  ends = [v for n, v in vectors.items() if n != styles_lib.ORIGINAL] or list(vectors.values())
  path = styles_lib.morph_loop(ends, len(poses))
  frames = [render(c2w, [v])[0] for c2w, v in progress_bar(
      list(zip(poses, path)), desc="render morph", disable=not progress)]
  return video.write_videos(os.path.join(folder, name), frames, s.fps)


def run_renders(out, styles, decoder_dir, s: Settings, progress) -> List[str]:
  """Writes OUT/renders/ (render_files) and grid_rows.txt; returns the files written."""
  load = lambda method: load_run_and_scene(os.path.join(out, method.kind), method.kind)
  paper = load(MULTISTYLE)
  run, scene = paper
  # The styles of the paper's model, "original" included; every method renders them.
  names = list(get_kind(MULTISTYLE.kind).style_table(run, scene)[0])
  poses = scene.path_poses(s.frames)
  folder = os.path.join(out, "renders")
  views = np.linspace(0, len(poses), max(1, s.grid_views) + 1)[:-1].round().astype(int)
  columns, written = [], []
  for method in methods(s):
    render, vectors = _renderer(*(paper if method is MULTISTYLE else load(method)), method,
                                styles, names, s)
    if not columns:  # the first method's style morph along the orbit
      written += _write_morph(folder, morph_name(s), render, vectors, poses, s, progress)
    # All styles at once per camera (one pass of the geometry): the side-by-side video.
    sweeps = [render(c2w, list(vectors.values())) for c2w in progress_bar(
        poses, desc=f"render {method.kind}", disable=not progress)]
    written += video.write_videos(os.path.join(folder, method.video),
                                  [video.grid([sw]) for sw in sweeps], s.fps)
    columns.append([[sweeps[v][m] for v in views] for m in range(len(names))])
  columns.append(_per_frame_adain(out, decoder_dir, names, poses[views]))
  groups = [[[_style_tile(styles, n, scene)]] + [c[m] for c in columns]
            for m, n in enumerate(names)]
  labels = ["style"] + [m.label for m in methods(s)] + [PER_FRAME]
  path = os.path.join(folder, "grid.png")
  images_lib.write_image(path, video.labelled_grid(groups, names, labels))
  written.append(path)
  files.atomic_write_bytes(os.path.join(folder, "grid_rows.txt"),
                           "".join(n + "\n" for n in names).encode())
  return written
