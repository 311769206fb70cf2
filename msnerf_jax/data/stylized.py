"""The N x M stylized scene dataset on disk: every view of a scene stylized with every style.

Layout of a dataset folder:
  manifest.json           scene, size, splits, the styles (name, source, alpha), which are done,
                          the decoder, the stylize scale and the content statistics ("view"
                          or "scene")
  poses.npy               [N, 3, 4] camera-to-world of the views (checked against a NeRF run)
  content_stats.npy       [2, 512] relu4_1 mean and std of the training views (only with
                          "content_stats": "scene")
  <style>/style_vector.npy  the style's 1024-d vector
  <style>/0000.png ...    view i stylized (PNG, the scene's resolution)

Every file is written atomically and a style is marked done in the manifest only when all of
its views exist, so an interrupted `stylize-scene` continues where it stopped.
"""

import dataclasses
import os
import re
from typing import Any, Dict, List, Optional, Sequence

import numpy as np

from msnerf_jax.core import config as config_lib
from msnerf_jax.core import files
from msnerf_jax.data import images as images_lib
from msnerf_jax.data.scene import Scene, drop_legacy_data_keys
from msnerf_jax.core.errors import UserError
from msnerf_jax.core.progress import progress_bar

MANIFEST = "manifest.json"
POSES = "poses.npy"
VECTOR = "style_vector.npy"
CONTENT_STATS = "content_stats.npy"
CONTENT_STATS_KINDS = ("view", "scene")
ORIGINAL = "original"


def style_name(path: str, alpha: float = 1.0) -> str:
  """A folder-safe name of a style image (+ its strength when below 1): `starry_night_a0.5`."""
  stem = re.sub(r"[^A-Za-z0-9_.-]+", "_", os.path.splitext(os.path.basename(path))[0])
  return stem if alpha == 1.0 else f"{stem}_a{alpha:g}"


def view_file(out_dir: str, name: str, index: int) -> str:
  return os.path.join(out_dir, name, f"{index:04d}.png")


def stylize_scene(scene: Scene, data_config: config_lib.DataConfig, stylize_fn,
                  style_vector_fn, style_paths: Sequence[str], alphas: Sequence[float],
                  include_original: bool, out_dir: str, progress: bool = True,
                  decoder: Optional[str] = None, stylize_scale: int = 1,
                  content_stats_fn=None, features: Optional[str] = None) -> Dict[str, Any]:
  """Writes (or completes) the stylized dataset of a scene.

  Args:
    scene, data_config: the loaded scene and the DataConfig that loads it again.
    stylize_fn(index, content [H, W, 3], style [h, w, 3], alpha, scale, content_stats) ->
      [H, W, 3]: the stylizer of view `index` of the scene (stylize.stylize_image's `scale`
      and `content_stats`, or a feature field's render of that camera).
    style_vector_fn(image [h, w, 3]) -> [1024]: the style vector of an image.
    style_paths, alphas: style images and their strengths (one alpha each).
    include_original: add the unstylized views as one more style named "original", whose
      vector is the mean style vector of the training views.
    out_dir: the dataset folder.
    decoder: the AdaIN run folder behind stylize_fn (recorded for evaluations).
    stylize_scale: passed to stylize_fn and recorded, so evaluations stylize their per-frame
      baseline the same way.
    content_stats_fn(views, scale) -> (mean, std) [1, C]: with it, every view is normalised
      by the content statistics of the training views (stylize.scene_content_stats), saved
      as content_stats.npy so that a resumed run uses the same; without it, each view by its
      own (per-view AdaIN, as in docs/method.md).
    features: the feature run behind stylize_fn, if any (recorded; its content statistics
      are pooled over the scene).
  Returns:
    summary dict {"out", "styles", "written", "skipped"}.
  """
  images_lib.check_scale(stylize_scale)
  styles, pictures = _styles(style_paths, alphas, include_original)
  names = [s["name"] for s in styles]
  manifest = {
      "data": config_lib.to_dict(data_config), "height": scene.height, "width": scene.width,
      "n_views": len(scene.images), "splits": {k: [int(i) for i in v]
                                               for k, v in scene.splits.items()},
      "views": [os.path.basename(p) for p in scene.image_paths], "styles": styles, "done": [],
      "decoder": os.path.abspath(decoder) if decoder else None,
      "stylize_scale": int(stylize_scale),
      "content_stats": "view" if content_stats_fn is None else "scene"}
  if features is not None:  # (absent otherwise: the manifests of earlier versions stay valid)
    manifest.update(features=os.path.abspath(features), content_stats="scene")
  _start(out_dir, manifest, scene.c2w)
  content_stats = None
  if content_stats_fn is not None and any(s["source"] for s in styles):
    content_stats = _content_stats(out_dir, scene, content_stats_fn, stylize_scale)
  remaining = sum(1 for st in styles if st["name"] not in manifest["done"]) * len(scene.images)
  files.check_free_space(out_dir, remaining * png_bytes(scene.height, scene.width),
                         f"the stylized views ({remaining} PNG files)")
  written = skipped = 0
  for style in styles:
    if style["name"] in manifest["done"]:
      skipped += len(scene.images)
      continue
    w, k = _write_style(scene, style, pictures.get(style["name"]), out_dir, stylize_fn,
                        style_vector_fn, stylize_scale, content_stats, progress)
    written, skipped = written + w, skipped + k
    manifest["done"].append(style["name"])
    files.write_json(os.path.join(out_dir, MANIFEST), manifest)
  return {"out": out_dir, "styles": names, "written": written, "skipped": skipped}


def _styles(style_paths: Sequence[str], alphas: Sequence[float], include_original: bool):
  """The manifest's styles [{"name", "source", "alpha"}] and their pictures (name -> image),
  every style image read and checked before anything is written."""
  if len(alphas) != len(style_paths):
    raise UserError(f"--alphas: got {len(alphas)} values for {len(style_paths)} styles")
  for a in alphas:
    if not 0.0 <= a <= 1.0:
      raise UserError(f"--alphas {a}: must be in [0, 1]")
  styles = [{"name": style_name(p, a), "source": os.path.abspath(p), "alpha": float(a)}
            for p, a in zip(style_paths, alphas)]
  if include_original:
    styles.append({"name": ORIGINAL, "source": None, "alpha": 0.0})
  names = [s["name"] for s in styles]
  if len(set(names)) != len(names):
    raise UserError(f"two styles have the same name ({', '.join(names)}); rename a file")
  pictures = {s["name"]: images_lib.read_image(s["source"], max_side=1024) for s in styles
              if s["source"]}
  for s in styles:
    shape = pictures[s["name"]].shape if s["source"] else (16, 16)
    if min(shape[:2]) < 16:
      raise UserError(f"{s['source']}: style image is {shape[1]}x{shape[0]}, need at least 16x16")
  return styles, pictures


def _start(out_dir: str, manifest: Dict[str, Any], c2w: np.ndarray) -> None:
  """Writes the manifest and the poses of a new dataset, or checks that an existing one was
  made the same way (its finished styles then go into manifest["done"])."""
  path = os.path.join(out_dir, MANIFEST)
  if os.path.exists(out_dir) and not os.path.isdir(out_dir):
    raise UserError(f"{out_dir}: is a file, expected a folder")
  if os.path.exists(path):
    saved = read_manifest(out_dir)
    mismatch = config_lib.diff({k: v for k, v in saved.items() if k != "done"},
                               {k: v for k, v in manifest.items() if k != "done"})
    if mismatch:
      raise UserError(f"{out_dir}: holds a stylized dataset made differently ({mismatch}); "
                      "use another --out, or the same options to continue")
    names = [s["name"] for s in manifest["styles"]]
    manifest["done"] = [n for n in saved["done"] if n in names]
  try:
    os.makedirs(out_dir, exist_ok=True)
    files.write_npy(os.path.join(out_dir, POSES), c2w)
    files.write_json(path, manifest)
  except PermissionError:
    raise UserError(f"{out_dir}: not writable") from None


def _content_stats(out_dir: str, scene: Scene, content_stats_fn, stylize_scale: int):
  """The training views' content statistics: saved with the dataset, so a resumed run uses
  the same."""
  stats_path = os.path.join(out_dir, CONTENT_STATS)
  if os.path.exists(stats_path):
    return read_content_stats(out_dir)
  content_stats = content_stats_fn(scene.images[scene.split("train")], stylize_scale)
  files.write_npy(stats_path, np.concatenate(content_stats).astype(np.float32))
  return content_stats


def _write_style(scene: Scene, style: Dict[str, Any], picture, out_dir: str, stylize_fn,
                 style_vector_fn, stylize_scale: int, content_stats, progress: bool):
  """Writes one style's vector and every view not written yet; returns (written, skipped)."""
  name = style["name"]
  if name == ORIGINAL:
    train = scene.split("train")
    vector = np.mean([np.asarray(style_vector_fn(scene.images[i])) for i in train], axis=0)
  else:
    vector = np.asarray(style_vector_fn(picture))
  files.write_npy(os.path.join(out_dir, name, VECTOR), vector)
  written = skipped = 0
  for i in progress_bar(range(len(scene.images)), desc=f"stylize {name}", disable=not progress):
    target = view_file(out_dir, name, i)
    if os.path.exists(target):
      skipped += 1
      continue
    view = scene.images[i]
    if name != ORIGINAL:
      view = np.asarray(stylize_fn(i, view, picture, style["alpha"], stylize_scale,
                                   content_stats))
      if scene.alphas is not None:  # keep the white background of RGBA (Blender) views.
        view = images_lib.over_background(view, scene.alphas[i][..., None].astype(np.float32)
                                          / 255.0)
    images_lib.write_image(target, view)
    written += 1
  return written, skipped



def png_bytes(height: int, width: int) -> int:
  """About how many bytes one stylized RGB PNG of that size takes on disk: half the raw
  pixels (lego's white backgrounds compress to a third, photographs to two thirds) and a
  file-system block."""
  return height * width * 3 // 2 + 4096


def read_manifest(out_dir: str) -> Dict[str, Any]:
  path = os.path.join(out_dir, MANIFEST)
  if not os.path.isdir(out_dir):
    raise UserError(f"{out_dir}: no such stylized dataset folder")
  try:
    manifest = images_lib.read_json(path)
  except FileNotFoundError:
    raise UserError(f"{path}: missing; make the dataset with `msnerf stylize-scene`") from None
  required = ("data", "height", "width", "n_views", "splits", "styles", "done")
  if not isinstance(manifest, dict) or any(k not in manifest for k in required):
    raise UserError(f"{path}: missing keys (needs {', '.join(required)})")
  if isinstance(manifest["data"], dict):
    drop_legacy_data_keys(manifest["data"], path)
  # Datasets made before the option existed were stylized at scale 1.
  images_lib.check_scale(manifest.setdefault("stylize_scale", 1), f"{path}: stylize_scale")
  kind = manifest.setdefault("content_stats", "view")
  if kind not in CONTENT_STATS_KINDS:
    raise UserError(f"{path}: content_stats is {kind!r}, expected one of "
                    f"{', '.join(CONTENT_STATS_KINDS)}")
  _check_manifest(manifest, path)
  return manifest


def _check_manifest(manifest: Dict[str, Any], path: str) -> None:
  """UserError naming the manifest's file and key unless its values have the types and
  ranges stylize_scene writes."""
  whole = lambda v: isinstance(v, int) and not isinstance(v, bool)
  for key in ("height", "width", "n_views"):
    if not whole(manifest[key]) or manifest[key] < 1:
      raise UserError(f"{path}: {key} must be a whole number >= 1, got {manifest[key]!r}")
  if not isinstance(manifest["data"], dict):
    raise UserError(f"{path}: data must be an object (the scene's settings)")
  splits = manifest["splits"]
  if not isinstance(splits, dict) or not all(
      isinstance(ids, list) and all(whole(i) and 0 <= i < manifest["n_views"] for i in ids)
      for ids in splits.values()):
    raise UserError(f"{path}: splits must map names to lists of view numbers below n_views "
                    f"{manifest['n_views']}")
  styles = manifest["styles"]
  if not isinstance(styles, list) or not all(
      isinstance(s, dict) and isinstance(s.get("name"), str) and s["name"] for s in styles):
    raise UserError(f"{path}: styles must be a list of objects with a 'name'")
  names = [s["name"] for s in styles]
  if len(set(names)) != len(names) or any(os.sep in n or n in (".", "..") for n in names):
    raise UserError(f"{path}: style names must be distinct folder names, got {names}")
  done = manifest["done"]
  if not isinstance(done, list) or not all(isinstance(n, str) for n in done):
    raise UserError(f"{path}: done must be a list of style names")


def read_content_stats(out_dir: str):
  """(mean [1, C], std [1, C]) saved by a "scene" stylized dataset; UserError if unusable."""
  path = os.path.join(out_dir, CONTENT_STATS)
  stats = images_lib.read_npy(path, (2, None))
  if np.any(stats[1] <= 0):
    raise UserError(f"{path}: a standard deviation is not positive")
  return stats[:1], stats[1:]


def check_views(path: str, n: int, height: int, width: int, c2w: np.ndarray, scene: Scene,
                what: str) -> None:
  """UserError unless a stylized dataset's views (count, size, poses) are those of `scene`."""
  if (height, width) != (scene.height, scene.width):
    raise UserError(f"{path}: views are {width}x{height}, {what} is "
                    f"{scene.width}x{scene.height} (use the same --downscale)")
  if n != len(scene.images) or not np.allclose(c2w, scene.c2w, atol=1e-4):
    raise UserError(f"{path}: camera poses do not match {what} (stylized from another scene?)")


def style_views(folder: str, name: str, scene: Scene) -> Scene:
  """`scene` with its images replaced by the views of one style of a stylized dataset.

  Same cameras, splits and render path: what a NeRF trained on one style alone (the
  single-style baseline) is trained and evaluated on. UserError naming the problem when the
  style is missing or unfinished, or the dataset was made from other views.
  """
  manifest = read_manifest(folder)
  names = [s["name"] for s in manifest["styles"]]
  if name not in names:
    raise UserError(f"style {name!r}: not in {folder} (has {', '.join(names)})")
  if name not in manifest["done"]:
    raise UserError(f"{folder}: style {name} is not finished; re-run the same "
                    "`msnerf stylize-scene` command to complete it")
  n, h, w = manifest["n_views"], manifest["height"], manifest["width"]
  c2w = images_lib.read_npy(os.path.join(folder, POSES), (n, 3, 4))
  check_views(folder, n, h, w, c2w, scene, f"the scene {manifest['data'].get('path', '')}")
  images = read_views(folder, name, n, h, w, progress=False).astype(np.float32) / 255.0
  return dataclasses.replace(scene, images=images)


def read_views(folder: str, name: str, n: int, height: int, width: int,
               progress: bool = True) -> np.ndarray:
  """The n views of one style as uint8 [n, height, width, 3]; UserError naming a file that
  cannot be read or has another size than the manifest's."""
  images = []  # (allocated as the views are read: the manifest's size may be wrong)
  for i in progress_bar(range(n), desc=f"loading {name}", disable=not progress, leave=False):
    path = view_file(folder, name, i)
    image = images_lib.read_image(path)
    if image.shape[:2] != (height, width):
      raise UserError(f"{path}: image is {image.shape[1]}x{image.shape[0]}, the manifest "
                      f"says {width}x{height}")
    images.append(images_lib.to_uint8(image))
  return np.stack(images) if images else np.zeros((0, height, width, 3), np.uint8)


@dataclasses.dataclass(frozen=True, eq=False)
class StylizedData:
  """A loaded stylized dataset. images: [M, N, H, W, 3] uint8; vectors: [M, 1024];
  c2w: [N, 3, 4]; names: the M style names; splits: name -> view indices."""
  names: List[str]
  vectors: np.ndarray
  images: np.ndarray
  c2w: np.ndarray
  splits: Dict[str, np.ndarray]
  path: str

  def vector(self, name: str) -> np.ndarray:
    if name not in self.names:
      raise UserError(f"style {name!r}: not in {self.path} (has {', '.join(self.names)})")
    return self.vectors[self.names.index(name)]


def load_stylized(out_dir: str, progress: bool = True) -> StylizedData:
  """Reads a complete stylized dataset (every style done); UserError naming what is wrong."""
  manifest = read_manifest(out_dir)
  names = [s["name"] for s in manifest["styles"]]
  missing = [n for n in names if n not in manifest["done"]]
  if not names:
    raise UserError(f"{os.path.join(out_dir, MANIFEST)}: lists no styles")
  if missing:
    raise UserError(f"{out_dir}: styles {', '.join(missing)} are not finished; re-run the "
                    "same `msnerf stylize-scene` command to complete them")
  n, h, w = manifest["n_views"], manifest["height"], manifest["width"]
  c2w = images_lib.read_npy(os.path.join(out_dir, POSES), (n, 3, 4))
  vectors = np.stack([images_lib.read_npy(os.path.join(out_dir, m, VECTOR), (1024,)) for m in names])
  images = np.stack([read_views(out_dir, name, n, h, w, progress) for name in names])
  splits = {k: np.asarray(v, np.int64) for k, v in manifest["splits"].items()}
  return StylizedData(names=names, vectors=vectors, images=images, c2w=c2w, splits=splits,
                      path=out_dir)
