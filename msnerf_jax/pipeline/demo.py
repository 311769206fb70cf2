"""A procedural demo scene and style images, made with numpy alone (no download, no network).

`write_scene` ray-traces a few textured primitives (a checkered ground disc, spheres with
checker and gradient textures, a striped box) with Lambertian shading and hard shadows from
known cameras on a hemisphere of radius 4, and writes them in the Blender (NeRF synthetic)
format: transforms_{train,val}.json with camera_angle_x and RGBA PNGs whose background is
transparent, so `load_blender` (near 2, far 6, white background) reads it like lego.
`write_styles` draws three style images of clearly different character. Both are
deterministic functions of their seed.
"""

import io
import json
import os
from typing import Dict, List, Tuple

import numpy as np
from PIL import Image

from msnerf_jax.data.blender import pose_spherical
from msnerf_jax.core.files import atomic_write_bytes

CAMERA_ANGLE_X = 0.6911112070083618  # lego's horizontal field of view (about 39.6 degrees).
RADIUS = 4.0
LIGHT = np.array([0.45, -0.35, 0.82]) / np.linalg.norm([0.45, -0.35, 0.82])
GROUND_Z, GROUND_R = -0.45, 1.25
STYLE_NAMES = ("stripes", "mosaic", "swirl")


# ----------------------------------------------------------------------------- the scene


def scene_objects(seed: int = 0) -> Dict[str, dict]:
  """The primitives of the demo scene; the seed jitters their placement and colours a little."""
  rng = np.random.default_rng([seed, 1])
  j = lambda scale=0.06: rng.uniform(-scale, scale, 3) * [1, 1, 0]
  hue = lambda base: np.clip(np.asarray(base) + rng.uniform(-0.06, 0.06, 3), 0, 1)
  return {
      "big_sphere": {"center": np.array([0.42, 0.32, 0.03]) + j(), "radius": 0.48,
                     "colors": (hue([0.85, 0.15, 0.12]), hue([0.95, 0.92, 0.85]))},
      "small_sphere": {"center": np.array([-0.28, 0.68, -0.21]) + j(), "radius": 0.24,
                       "colors": (hue([0.1, 0.7, 0.3]), hue([0.1, 0.8, 0.95]))},
      "box": {"center": np.array([-0.45, -0.3, -0.13]) + j(), "half": np.array([0.32, 0.32, 0.32]),
              "colors": (hue([0.15, 0.25, 0.8]), hue([0.98, 0.8, 0.1]))},
      "ground": {"colors": (hue([0.75, 0.62, 0.45]), hue([0.35, 0.25, 0.18]))},
  }


def _sphere_t(o, d, center, radius):
  oc = o - center
  b = np.sum(oc * d, -1)
  c = np.sum(oc * oc, -1) - radius ** 2
  disc = b * b - c
  root = np.sqrt(np.maximum(disc, 0.0))
  t = np.where(-b - root > 1e-4, -b - root, -b + root)
  return np.where((disc > 0) & (t > 1e-4), t, np.inf)


def _box_t(o, d, center, half):
  with np.errstate(divide="ignore", invalid="ignore"):
    inv = 1.0 / np.where(np.abs(d) < 1e-12, 1e-12, d)
    t1, t2 = (center - half - o) * inv, (center + half - o) * inv
  t_near = np.max(np.minimum(t1, t2), -1)
  t_far = np.min(np.maximum(t1, t2), -1)
  t = np.where(t_near > 1e-4, t_near, t_far)
  return np.where((t_far >= t_near) & (t > 1e-4), t, np.inf)


def _ground_t(o, d):
  with np.errstate(divide="ignore", invalid="ignore"):
    t = (GROUND_Z - o[..., 2]) / d[..., 2]
  p = o + np.nan_to_num(t, posinf=0.0, neginf=0.0)[..., None] * d
  inside = (np.sum(p[..., :2] ** 2, -1) < GROUND_R ** 2) & (t > 1e-4) & np.isfinite(t)
  return np.where(inside, t, np.inf)


def _hits(o, d, objects) -> np.ndarray:
  """[..., 4] distances to each primitive (inf = missed), in a fixed order."""
  return np.stack([_sphere_t(o, d, objects["big_sphere"]["center"], objects["big_sphere"]["radius"]),
                   _sphere_t(o, d, objects["small_sphere"]["center"],
                             objects["small_sphere"]["radius"]),
                   _box_t(o, d, objects["box"]["center"], objects["box"]["half"]),
                   _ground_t(o, d)], -1)


def _shade(p, which, objects):
  """Albedo [N, 3] and normal [N, 3] at hit points p [N, 3] of primitive `which` [N]."""
  albedo = np.zeros_like(p)
  normal = np.zeros_like(p)
  pick = lambda flag, a, b: np.where(flag[:, None], a, b)
  # Big sphere: a latitude/longitude checker.
  s = objects["big_sphere"]
  m = which == 0
  n = (p[m] - s["center"]) / s["radius"]
  lon, lat = np.arctan2(n[:, 1], n[:, 0]), np.arcsin(np.clip(n[:, 2], -1, 1))
  check = (np.floor(lon / (np.pi / 6)) + np.floor(lat / (np.pi / 6))) % 2 == 0
  albedo[m], normal[m] = pick(check, s["colors"][0], s["colors"][1]), n
  # Small sphere: a vertical colour gradient.
  s = objects["small_sphere"]
  m = which == 1
  n = (p[m] - s["center"]) / s["radius"]
  t = (n[:, 2:3] + 1) / 2
  albedo[m], normal[m] = (1 - t) * s["colors"][0] + t * s["colors"][1], n
  # Box: stripes around it (by height) and a diagonal on top.
  b = objects["box"]
  m = which == 2
  q = (p[m] - b["center"]) / b["half"]
  axis = np.argmax(np.abs(q), -1)
  n = np.zeros_like(q)
  n[np.arange(len(q)), axis] = np.sign(q[np.arange(len(q)), axis])
  stripe = np.where(axis == 2, np.floor((q[:, 0] + q[:, 1]) * 2.5), np.floor(q[:, 2] * 3.5)) % 2
  albedo[m], normal[m] = pick(stripe == 0, b["colors"][0], b["colors"][1]), n
  # Ground: a checkerboard with a darker rim.
  g = objects["ground"]
  m = which == 3
  check = (np.floor(p[m, 0] * 3.2) + np.floor(p[m, 1] * 3.2)) % 2 == 0
  rim = np.sqrt(np.sum(p[m, :2] ** 2, -1)) > GROUND_R - 0.12
  albedo[m] = np.where(rim[:, None], 0.25, pick(check, g["colors"][0], g["colors"][1]))
  normal[m] = [0.0, 0.0, 1.0]
  return albedo, normal


def trace(origins: np.ndarray, directions: np.ndarray, objects) -> Tuple[np.ndarray, np.ndarray]:
  """Colour [N, 3] (Lambertian + ambient, hard shadows) and coverage [N] of rays [N, 3]."""
  d = directions / np.linalg.norm(directions, axis=-1, keepdims=True)
  t_all = _hits(origins, d, objects)
  which = np.argmin(t_all, -1)
  t = np.min(t_all, -1)
  hit = np.isfinite(t)
  rgb = np.zeros_like(origins)
  p = origins[hit] + t[hit, None] * d[hit]
  albedo, normal = _shade(p, which[hit], objects)
  lit = np.isinf(np.min(_hits(p + 1e-3 * normal, np.broadcast_to(LIGHT, p.shape), objects), -1))
  diffuse = np.maximum(np.sum(normal * LIGHT, -1), 0.0) * lit
  rgb[hit] = np.clip(albedo * (0.3 + 0.7 * diffuse[:, None]), 0.0, 1.0)
  return rgb, hit.astype(np.float64)


def render_view(c2w: np.ndarray, size: int, objects, supersample: int = 3) -> np.ndarray:
  """RGBA float image [size, size, 4] of camera c2w [3|4, 4], anti-aliased by supersampling.

  Pixels use the loader's convention (pixel centres at integer coordinates, principal
  point at size / 2), so NeRF rays through a pixel see what the pixel shows.
  """
  focal = 0.5 * size / np.tan(0.5 * CAMERA_ANGLE_X)
  s = supersample
  offsets = (np.arange(s) + 0.5) / s - 0.5
  x = (np.arange(size)[:, None] + offsets[None]).reshape(-1)
  i, j = np.meshgrid(x, x, indexing="xy")
  dirs = np.stack([(i - 0.5 * size) / focal, -(j - 0.5 * size) / focal, -np.ones_like(i)], -1)
  dirs = dirs.reshape(-1, 3) @ np.asarray(c2w)[:3, :3].T
  origins = np.broadcast_to(np.asarray(c2w)[:3, 3], dirs.shape)
  rgb, alpha = trace(origins, dirs, objects)
  rgba = np.concatenate([rgb * alpha[:, None], alpha[:, None]], -1).reshape(size, s, size, s, 4)
  rgba = rgba.mean((1, 3))
  cover = rgba[..., 3:]
  rgba[..., :3] = np.where(cover > 0, rgba[..., :3] / np.maximum(cover, 1e-8), 0.0)  # unpremultiply
  return rgba


def _png(image: np.ndarray, mode: str) -> bytes:
  buffer = io.BytesIO()
  Image.fromarray((np.clip(image, 0, 1) * 255 + 0.5).astype(np.uint8), mode).save(buffer, "PNG")
  return buffer.getvalue()


def camera_poses(n_train: int, n_val: int, seed: int = 0) -> Dict[str, np.ndarray]:
  """Camera-to-world [n, 4, 4] per split, on the hemisphere of radius 4 looking at the origin.

  Training cameras: stratified azimuths with random elevations between 15 and 65 degrees;
  validation cameras: evenly spaced at 30 degrees (between the training azimuths).
  """
  rng = np.random.default_rng([seed, 2])
  azimuth = (np.arange(n_train) + rng.uniform(0, 1, n_train)) * 360.0 / n_train - 180.0
  elevation = rng.uniform(15.0, 65.0, n_train)
  train = [pose_spherical(a, -e, RADIUS) for a, e in zip(azimuth, elevation)]
  val = [pose_spherical(-180.0 + (k + 0.5) * 360.0 / max(n_val, 1), -30.0, RADIUS)
         for k in range(n_val)]
  return {"train": np.asarray(train), "val": np.asarray(val)}


def write_scene(out_dir: str, size: int = 64, n_train: int = 40, n_val: int = 6,
                seed: int = 0, progress: bool = True) -> str:
  """Writes the demo scene in the Blender format to `out_dir` and returns it.

  A scene already there with the same settings (scene.json) is kept as it is.
  """
  from msnerf_jax.core.progress import progress_bar  # pylint: disable=g-import-not-at-top
  settings = {"size": size, "n_train": n_train, "n_val": n_val, "seed": seed, "version": 1}
  marker = os.path.join(out_dir, "scene.json")
  if os.path.exists(marker):
    with open(marker) as f:
      if json.load(f) == settings:
        return out_dir
  objects = scene_objects(seed)
  poses = camera_poses(n_train, n_val, seed)
  jobs = [(split, k, c2w) for split in ("train", "val") for k, c2w in enumerate(poses[split])]
  frames = {"train": [], "val": []}
  for split, k, c2w in progress_bar(jobs, desc="demo scene", disable=not progress, leave=False):
    atomic_write_bytes(os.path.join(out_dir, split, f"r_{k}.png"),
                       _png(render_view(c2w, size, objects), "RGBA"))
    frames[split].append({"file_path": f"./{split}/r_{k}", "transform_matrix": c2w.tolist()})
  for split, items in frames.items():
    atomic_write_bytes(os.path.join(out_dir, f"transforms_{split}.json"), json.dumps(
        {"camera_angle_x": CAMERA_ANGLE_X, "frames": items}, indent=2).encode())
  atomic_write_bytes(marker, json.dumps(settings).encode())
  return out_dir


# ----------------------------------------------------------------------------- the styles


def _palette(t: np.ndarray, colors) -> np.ndarray:
  """Piecewise-linear colour map of t in [0, 1] through `colors` (RGB in [0, 1])."""
  colors = np.asarray(colors, np.float64)
  x = np.clip(t, 0, 1) * (len(colors) - 1)
  k = np.minimum(np.floor(x).astype(int), len(colors) - 2)
  f = (x - k)[..., None]
  return (1 - f) * colors[k] + f * colors[k + 1]


# The three styles differ in texture and in their dominant colours (cool blues, warm
# oranges, greens): a multi-style NeRF keeps each style's palette even where the per-view
# textures of 2D stylization disagree between views and average out, so the styles stay
# clearly apart in the demo's renders.


def style_stripes(size: int, rng: np.random.Generator) -> np.ndarray:
  """Bold diagonal bands of blues and white with black outlines, with a slight wave."""
  y, x = np.mgrid[0:size, 0:size] / size
  colors = np.array([[0.05, 0.15, 0.55], [0.2, 0.5, 0.95], [0.6, 0.85, 1.0], [0.05, 0.05, 0.15],
                     [0.97, 0.97, 1.0]])
  u = (x + y) * 7 + 0.25 * np.sin(2 * np.pi * (x - y) * 2 + rng.uniform(0, 6))
  band = np.floor(u).astype(int)
  order = rng.permutation(len(colors))
  image = colors[order[band % len(colors)]]
  edge = np.abs(u - np.round(u)) < 0.06  # black outlines between the bands
  return np.where(edge[..., None], 0.02, image)


def style_mosaic(size: int, rng: np.random.Generator) -> np.ndarray:
  """A Voronoi mosaic of warm tiles (red, orange, amber, cream), each with a darker dot, on
  dark grout."""
  n = 70
  points = rng.uniform(0, size, (n, 2))
  colors = _palette(rng.uniform(0, 1, n), [[0.75, 0.1, 0.05], [0.95, 0.4, 0.1], [1.0, 0.7, 0.2],
                                           [1.0, 0.9, 0.6], [0.85, 0.25, 0.2]])
  y, x = np.mgrid[0:size, 0:size]
  dist = np.sqrt((x[..., None] - points[:, 0]) ** 2 + (y[..., None] - points[:, 1]) ** 2)
  order = np.argsort(dist, -1)
  first = np.take_along_axis(dist, order[..., :1], -1)[..., 0]
  second = np.take_along_axis(dist, order[..., 1:2], -1)[..., 0]
  image = colors[order[..., 0]]
  dot = first < size / 60
  image = np.where(dot[..., None], image * 0.45, image)
  return np.where((second - first < 2.2)[..., None], [0.12, 0.1, 0.14], image)


def style_swirl(size: int, rng: np.random.Generator) -> np.ndarray:
  """Domain-warped swirls in greens, from deep forest to lime and pale yellow."""
  y, x = (np.mgrid[0:size, 0:size] / size - 0.5) * 2
  r, a = np.sqrt(x ** 2 + y ** 2), np.arctan2(y, x)
  field = np.zeros_like(x)
  for _ in range(5):
    fx, fy, ph = rng.uniform(1, 4), rng.uniform(1, 4), rng.uniform(0, 2 * np.pi, 2)
    field += np.sin(fx * np.pi * x + np.sin(fy * np.pi * y + ph[0]) * 1.5 + ph[1])
  twist = np.sin(a * 3 + r * 9 + field * 0.9)
  t = 0.5 + 0.5 * np.sin(field * 1.3 + twist * 2.0)
  return _palette(t, [[0.02, 0.2, 0.08], [0.1, 0.45, 0.15], [0.3, 0.7, 0.25], [0.65, 0.9, 0.3],
                      [0.95, 1.0, 0.7]])


def write_styles(out_dir: str, size: int = 256, seed: int = 0) -> List[str]:
  """Writes stripes.png, mosaic.png and swirl.png to `out_dir`; returns their paths."""
  paths = []
  for k, (name, fn) in enumerate(zip(STYLE_NAMES, (style_stripes, style_mosaic, style_swirl))):
    path = os.path.join(out_dir, f"{name}.png")
    atomic_write_bytes(path, _png(fn(size, np.random.default_rng([seed, 10 + k])), "RGB"))
    paths.append(path)
  return paths
