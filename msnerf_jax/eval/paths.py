"""The frames each method of `msnerf evaluate` renders along one camera path: the NeRF's
photo-real path (the geometry and the frames per-frame AdaIN stylizes), the multi-style runs'
sweeps, single-style NeRFs, feature fields and painted runs.

A method's frames are a Path: (label, {style name: frames [P]}, {style name: geometry [P]}),
a geometry being the {"depth", "accumulation"} of each camera its consistency warps with.
"""

import os
from typing import Any, Dict, List, Optional, Sequence, Tuple

import numpy as np

from msnerf_jax.core.errors import UserError
from msnerf_jax.core.progress import progress_bar
from msnerf_jax.data.scene import Scene
from msnerf_jax.kinds import stylized_scenes
from msnerf_jax.kinds.features import feature_painting
from msnerf_jax.kinds.painted import render_painted
from msnerf_jax.kinds.runs import load_run
from msnerf_jax.kinds.views import render_feature_styles, render_styles, render_view
from msnerf_jax.style import transfer as stylize_lib
from msnerf_jax.style.vectors import style_vector_of
from msnerf_jax.data import images as images_lib

Path = Tuple[str, Dict[str, List[np.ndarray]], Dict[str, List[Dict[str, np.ndarray]]]]


def path_poses(scene: Scene, frames: int) -> np.ndarray:
  """`frames` c2w [frames, 3, 4] spread evenly along the scene's render path (0: all of it)."""
  if not frames:
    return scene.render_poses
  return scene.render_poses[np.linspace(0, len(scene.render_poses) - 1, frames)
                            .round().astype(int)]


def nerf_path(scene: Scene, params, config, poses, chunk: Optional[int] = None,
              progress: bool = False) -> List[Dict[str, np.ndarray]]:
  """The NeRF's render of each camera (render_view's outputs), with its "pose"."""
  return [{**render_view(scene, params, config, c2w, chunk), "pose": c2w}
          for c2w in progress_bar(poses, desc="NeRF path", disable=not progress, leave=False)]


def per_frame_adain(decoder, encoder, base: Sequence[Dict[str, np.ndarray]], style: np.ndarray,
                    alpha: float, white_background: bool, scale: int = 1) -> List[np.ndarray]:
  """The per-frame AdaIN baseline: each NeRF render in `base` stylized on its own, at the
  stylized dataset's `scale` (its manifest's stylize_scale); on white-background (Blender)
  scenes the background is put back to white, as in the stylized training views."""
  frames = [stylize_lib.stylize_image(decoder, encoder, b["rgb"], [style], alpha=alpha,
                                      scale=scale) for b in base]
  if white_background:
    frames = [images_lib.over_background(f, b["accumulation"][..., None])
              for f, b in zip(frames, base)]
  return frames


def feature_field_frames(field, scene, base, base_nerf: str, encoder,
                         pictures: Sequence[np.ndarray], alphas: Sequence[float],
                         chunk: Optional[int] = None, progress: bool = False):
  """(frames [K][P], geometry [P]) of a loaded feature run in K styles along the P cameras
  `base` was rendered on, one feature render per camera: each style's statistics from its
  picture cover-cropped to the decoded size (as per-frame AdaIN crops it), at its strength
  alpha (a blend towards the scene's own statistics), the features painted by the run's
  decoder; on white-background scenes the background is put back to white by the NeRF's
  opacity, as per_frame_adain does. The geometry is `base`'s when the field was trained on
  that NeRF run (`base_nerf`), else its own NeRF's renders."""
  decoder = stylized_scenes.load_decoder(field.record["decoder"])
  stats, original, size = feature_painting(field, scene)
  vectors = np.stack([alpha * style_vector_of(encoder, p, size) + (1.0 - alpha) * original
                      for p, alpha in zip(pictures, alphas)])
  geometry = base
  if os.path.abspath(field.record["nerf_run"]) != os.path.abspath(base_nerf):
    geometry = [render_view(scene, field.params["nerf"], field.config.nerf, b["pose"], chunk)
                for b in base]
  frames = [[] for _ in vectors]
  for b, g in zip(progress_bar(base, desc="feature-field path", disable=not progress,
                               leave=False), geometry):
    sweep = render_feature_styles(scene, field.params, field.config, b["pose"], decoder, stats,
                                  vectors, chunk)
    if scene.white_background:
      sweep = images_lib.over_background(sweep, g["accumulation"][..., None])
    for k, frame in enumerate(sweep):
      frames[k].append(frame)
  return frames, geometry


def painted_frames(run, scene, base, base_nerf: str, chunk: Optional[int] = None,
                   progress: bool = False):
  """({style name: frames [P]}, geometry [P]) of a loaded painted run along the P cameras
  `base` was rendered on, all its styles in one render per camera; the geometry is `base`'s
  when it was painted on that NeRF run (`base_nerf`), else its own NeRF's renders."""
  names = run.record["styles"]
  frames = {n: [] for n in names}
  same = os.path.abspath(run.record["nerf_run"]) == os.path.abspath(base_nerf)
  geometry = []
  for b in progress_bar(base, desc="painted path", disable=not progress, leave=False):
    for name, frame in zip(names, render_painted(scene, run.params, run.config, b["pose"],
                                                 chunk)["rgb"]):
      frames[name].append(frame)
    geometry.append(b if same else render_view(scene, run.params["nerf"], run.config.nerf,
                                               b["pose"], chunk))
  return frames, geometry


def multistyle_paths(runs, vectors, names, methods, scene, poses, chunk, progress
                     ) -> List[Path]:
  """A Path per multi-style run: its render of every path camera in all `names` styles at
  once (each style with its own geometry: a density-aware run's differs)."""
  paths = []
  for r, v, method in zip(runs, vectors, methods):
    stack = np.stack([v[n] for n in names])
    sweep = [render_styles(scene, r.params, r.config, c2w, stack, chunk)
             for c2w in progress_bar(poses, desc=f"{method} path", disable=not progress,
                                     leave=False)]
    paths.append((method, {n: [s["rgb"][m] for s in sweep] for m, n in enumerate(names)},
                  {n: [{"depth": s["depth"][m], "accumulation": s["accumulation"][m]}
                       for s in sweep] for m, n in enumerate(names)}))
  return paths


def single_style_runs(run_dirs: Sequence[str], names: Sequence[str]) -> Dict[str, Any]:
  """style name -> the loaded NeRF run trained on that style alone, each checked."""
  singles = {}
  for d in run_dirs:
    single = load_run(d)
    style = single.record.get("style") or {}
    if single.kind != "nerf" or "name" not in style:
      raise UserError(f"{d}: not a single-style NeRF run (train one with `msnerf nerf train "
                      "--stylized DIR --style NAME`)")
    if style["name"] not in names:
      raise UserError(f"{d}: trained on style {style['name']!r}, which is not evaluated here "
                      f"({', '.join(names)})")
    singles[style["name"]] = single
  return singles


def single_style_path(single, name, scene, poses, chunk, progress) -> Path:
  """The Path of a single-style NeRF (trained on style `name`) along the cameras."""
  renders = [render_view(scene, single.params, single.config, c2w, chunk)
             for c2w in progress_bar(poses, desc=f"single-style {name}", disable=not progress,
                                     leave=False)]
  return "nerf-single-style", {name: [r["rgb"] for r in renders]}, {name: renders}


