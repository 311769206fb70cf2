"""Where a painting's colour grid lies and how fine it is, fitted to what the views see: the
box (centred at the origin, like the NeRF's) holds all but a sliver of the weight of the
painting's views' samples (the training views' and the render path's), and the grid's
vertex spacing is about the size of a pixel on the surfaces the views see, between
MIN_RESOLUTION and MAX_RESOLUTION vertices a side.

A grid coarser than a pixel cannot hold strokes: on the cup capture (100x75 views, the
surfaces 1.4-2.6 units from the cameras, 74 px focal length) the NeRF's 11.4-unit box at 128
vertices a side spaced them 3-5 pixels apart, and its paintings came out smooth and blocky;
on lego 100x100 the same grid is under a pixel.
"""

import dataclasses
import math
from typing import Dict

import numpy as np

MIN_RESOLUTION, MAX_RESOLUTION = 128, 256  # vertices a side of a fitted grid.
BOX_SHARE = 0.999  # of the views' sample weight inside the box.
BOX_MARGIN = 1.05  # the box's half side over that quantile.


def weighted_quantile(values: np.ndarray, weights: np.ndarray, q: float) -> float:
  """The q-quantile of `values` [S] counted by `weights` [S] (>= 0, not all 0)."""
  order = np.argsort(values)
  share = np.cumsum(weights[order], dtype=np.float64)
  return float(values[order][min(np.searchsorted(share, q * share[-1]), len(order) - 1)])


def fitted_box(cache: Dict[str, np.ndarray], limit: float) -> float:
  """Half side of the box centred at the origin that holds BOX_SHARE of the cached views'
  sample weight (the painting's views: the training views and the render path's cameras),
  grown by BOX_MARGIN, at most `limit` (the NeRF's box). Points outside read the nearest
  face."""
  keep = cache["weights"] > 0
  reach = np.abs(cache["points"][keep]).max(-1)
  box = weighted_quantile(reach, cache["weights"][keep], BOX_SHARE) if reach.size else 0.0
  return float(min(limit, BOX_MARGIN * box)) if box > 0 else float(limit)


def pixel_footprint(cache: Dict[str, np.ndarray], width: int, every: int = 4) -> float:
  """How far apart the scene's surfaces put neighbouring pixels: the median distance
  between the weighted mean sample points of horizontally adjacent pixels that are both
  opaque (accumulation above 0.5), over every `every`-th cached view (packed lists, sorted
  by pixel; n = H * W pixels a view of `width`). In scene units (NDC on LLFF scenes), so it
  holds for any camera model."""
  gaps, n = [], cache["accumulation"].shape[1]
  for view in range(0, len(cache["weights"]), every):
    weights, pixel = cache["weights"][view], cache["pixel"][view]
    total = cache["accumulation"][view]  # each pixel's summed weight
    mean = np.stack([np.bincount(pixel, weights * cache["points"][view][:, i], n)
                     for i in range(3)], -1) / np.maximum(total, 1e-12)[:, None]
    opaque = total > 0.5
    pair = opaque[:-1] & opaque[1:] & (np.arange(n - 1) % width != width - 1)
    gaps.append(np.linalg.norm(mean[1:] - mean[:-1], axis=-1)[pair])
  gaps = np.concatenate(gaps) if gaps else np.zeros(0)
  return float(np.median(gaps)) if gaps.size else 0.0


def fitted_resolution(box: float, footprint: float) -> int:
  """Vertices a side that space a grid over [-box, box]^3 about one `footprint` apart,
  clipped to [MIN_RESOLUTION, MAX_RESOLUTION] (MIN_RESOLUTION for no footprint)."""
  if footprint <= 0:
    return MIN_RESOLUTION
  return int(np.clip(math.ceil(2.0 * box / footprint) + 1, MIN_RESOLUTION, MAX_RESOLUTION))


def fit(config, cache: Dict[str, np.ndarray], width: int, limit: float):
  """The PaintConfig with its grid resolved: scene_box 0 -> fitted_box (at most `limit`, the
  NeRF's box), resolution 0 -> fitted_resolution for the cached views' pixel_footprint
  (`width` pixels a row); settings given stay."""
  box = config.scene_box or fitted_box(cache, limit)
  resolution = config.resolution or fitted_resolution(box, pixel_footprint(cache, width))
  return dataclasses.replace(config, scene_box=float(box), resolution=int(resolution))
