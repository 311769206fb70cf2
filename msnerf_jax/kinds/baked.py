"""A run's baked scene (msnerf_jax.nerf.baked), saved in its folder as `baked.npz` and reused:
the render path for looking (`msnerf view`, `msnerf render --fast`).

The file holds the bake's arrays and a fingerprint of what it was baked from (the trunk's
and the occupancy grid's bytes, the bake's settings and format): a run trained further, or a
file copied from another run, has another fingerprint and is baked again, never used. A
file that is not a readable bake (truncated, foreign) is one UserError naming it.
"""

import hashlib
import io
import os
import time
from typing import Callable, Optional

import jax
import numpy as np

from msnerf_jax.core.errors import UserError
from msnerf_jax.core.files import atomic_write_bytes
from msnerf_jax.data.images import file_problem
from msnerf_jax.kinds.registry import get_kind
from msnerf_jax.nerf import baked as baked_lib
from msnerf_jax.nerf import occupancy

BAKED_FILE = "baked.npz"
FORMAT = 1
RESOLUTION = 4  # sub-cells a side of an occupied cell
COMPONENTS = 16  # principal components of the trunk feature
MAX_BYTES = 256 * 2 ** 20  # a bake larger than this (a scene that fills its box) is refused.
ARRAYS = ("index", "density", "coefficients", "basis", "mean")


def why_not_baked(run) -> Optional[str]:
  """None when the run renders from a baked scene, else why not (in words)."""
  kind = get_kind(run.kind)
  if kind.field is None or kind.nerf_config is None:
    return f"a {run.kind!r} run is drawn by its own renderer"
  config = kind.nerf_config(run.config)
  if config.sampler != "grid":
    return "baking needs the occupancy-grid sampler (the fast preset)"
  if getattr(run.config, "density_aware", False):
    return "a density-aware run's density depends on the style"
  return None


def fingerprint(run) -> str:
  """sha256 (hex) of what a bake of the run depends on."""
  config = get_kind(run.kind).nerf_config(run.config)
  digest = hashlib.sha256(f"msnerf-bake {FORMAT} {RESOLUTION} {COMPONENTS} "
                          f"{config.scene_box} {config.grid_threshold}".encode())
  tree = {"trunk": run.params["fine"]["trunk"], "occupancy": run.params["occupancy"]}
  for path, leaf in jax.tree_util.tree_leaves_with_path(tree):
    digest.update(jax.tree_util.keystr(path).encode())
    digest.update(np.ascontiguousarray(np.asarray(leaf, np.float32)).tobytes())
  return digest.hexdigest()


def to_bytes(scene: baked_lib.BakedScene, stamp: str) -> bytes:
  """The .npz of a bake: density and index as they are, the coefficients as float16."""
  buffer = io.BytesIO()
  arrays = {k: np.asarray(getattr(scene, k)) for k in ARRAYS}
  arrays["coefficients"] = arrays["coefficients"].astype(np.float16)
  np.savez(buffer, **arrays, fingerprint=np.frombuffer(stamp.encode(), np.uint8),
           bound=np.float32(scene.bound), format=np.int32(FORMAT))
  return buffer.getvalue()


def read_baked(path: str):
  """(BakedScene, fingerprint) of a baked file; UserError naming it when it is not one."""
  try:
    with np.load(path, allow_pickle=False) as archive:
      if not all(k in archive for k in (*ARRAYS, "fingerprint", "bound", "format")):
        raise ValueError("arrays missing")
      arrays = {k: np.asarray(archive[k]) for k in (*ARRAYS, "fingerprint", "bound", "format")}
  except MemoryError:
    raise
  except Exception as e:  # pylint: disable=broad-except  # zip, header, shape errors ...
    raise UserError(f"{path}: not a baked scene ({file_problem(e)}); delete it to bake "
                    "again") from None
  if int(arrays["format"]) != FORMAT:
    raise UserError(f"{path}: a baked scene of format {int(arrays['format'])}, this version "
                    f"reads {FORMAT}; delete it to bake again")
  index, density = arrays["index"], arrays["density"]
  side = density.shape[-1] if density.ndim == 4 else 0
  shapes_ok = (index.ndim == 3 and index.dtype == np.int32 and density.ndim == 4
               and density.shape[1:] == (side,) * 3 and arrays["coefficients"].ndim == 5
               and arrays["coefficients"].shape[:4] == density.shape
               and arrays["basis"].ndim == 2 and arrays["mean"].shape == arrays["basis"].shape[1:]
               and arrays["coefficients"].shape[-1] == arrays["basis"].shape[0]
               and int(index.max(initial=-1)) < density.shape[0] and side >= 2)
  if not shapes_ok:
    raise UserError(f"{path}: not a baked scene (arrays of the wrong shapes); delete it to "
                    "bake again")
  scene = baked_lib.BakedScene(
      index=index, density=density.astype(np.float32),
      coefficients=arrays["coefficients"].astype(np.float32),
      basis=arrays["basis"].astype(np.float32), mean=arrays["mean"].astype(np.float32),
      bound=float(arrays["bound"]))
  return scene, bytes(arrays["fingerprint"]).decode("ascii", "replace")


def baked_scene(run, report: Callable[[str], None] = print) -> baked_lib.BakedScene:
  """The run's baked scene: RUN/baked.npz when it was baked from this run as it is now, else
  baked now (timed, reported) and saved there atomically.

  Raises:
    UserError: the run cannot be baked (why_not_baked), the bake would exceed MAX_BYTES, or
    RUN/baked.npz is not a baked scene.
  """
  reason = why_not_baked(run)
  if reason is not None:
    raise UserError(f"{run.run_dir}: no fast render path: {reason}")
  path = os.path.join(run.run_dir, BAKED_FILE)
  stamp = fingerprint(run)
  if os.path.exists(path):
    scene, saved = read_baked(path)
    if saved == stamp:
      return scene
    report(f"{path}: baked from another state of the run; baking again")
  config = get_kind(run.kind).nerf_config(run.config)
  occupied = int(np.sum(np.asarray(occupancy.occupied(
      np.asarray(run.params["occupancy"]), config.grid_threshold))))
  width = np.asarray(run.params["fine"]["trunk"]["feature"]["kernel"]).shape[-1]
  size = occupied * (RESOLUTION + 1) ** 3 * (4 + 2 * min(COMPONENTS, width))
  if size > MAX_BYTES:
    raise UserError(f"{run.run_dir}: its occupancy grid has {occupied} occupied cells, a bake "
                    f"of {size / 2**20:.0f} MB (more than {MAX_BYTES // 2**20} MB): the "
                    "scene fills its box; render it exactly (without --fast)")
  field = get_kind(run.kind).field(run.config)
  params = jax.device_put(run.params["fine"])
  geometry = jax.jit(lambda points: field.geometry(params, points))
  start = time.perf_counter()
  scene = baked_lib.bake(geometry, run.params["occupancy"], config, RESOLUTION, COMPONENTS)
  data = to_bytes(scene, stamp)
  atomic_write_bytes(path, data)
  report(f"baked {run.run_dir} in {time.perf_counter() - start:.1f} s: {occupied} cells, "
         f"{len(data) / 1e6:.1f} MB in {path}")
  return read_baked(path)[0]


def baked_views(run, scene, report: Callable[[str], None] = print):
  """A function `(camera, styles=None) -> outputs` drawing one camera of the run's scene
  (Scene.camera_rays' cameras) from its baked scene (baked_scene): numpy {"rgb": [H, W, 3],
  "depth", "disparity", "accumulation"}, with a leading [K] for K style vectors [1024]."""
  kind = get_kind(run.kind)
  bake = jax.device_put(baked_scene(run, report))
  field, config = kind.field(run.config), kind.nerf_config(run.config)
  params = jax.device_put(run.params)

  def draw(camera, styles=None):
    styles = None if styles is None else jax.numpy.asarray(np.stack(styles), np.float32)
    return baked_lib.render_baked_image(bake, field, params, scene.camera_rays(camera), config,
                                        scene.white_background, styles=styles)
  return draw
