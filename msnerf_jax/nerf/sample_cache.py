"""A frozen NeRF's views as cached sample lists: each pixel's samples (where they are and how
much they weigh in its composite), computed once, so rendering a colour field over the same
geometry is a gather and a segment sum with no trunk evaluation (painted colour fields).

A view's cache is a dict of numpy arrays: "points" [P, 3] float32, "weights" [P] float32,
"pixel" [P] int32 (the pixel index in the view, row-major) and "accumulation" [H * W] (the sum
of the kept weights of each pixel). Several views pack into arrays with a leading [N] and
their lists padded with weight 0 (pack_views), which is what jitted code indexes.
"""

import functools
from typing import Callable, Dict, List, Optional

import chex
import jax
import jax.numpy as jnp
import numpy as np

from msnerf_jax.nerf.render import flat_rays, padded, sampling_config
from msnerf_jax.nerf.samplers import sampler_of

CACHE_KEYS = ("points", "weights", "pixel")


@functools.partial(jax.jit, static_argnums=(0, 3, 4, 5))
def _samples_chunk(field, nerf_params, rays, config, top_k, budget):
  return sampler_of(config).weighted_samples(field, nerf_params, rays, config, top_k, budget)


def view_samples(field, nerf_params, rays: Dict[str, jnp.ndarray], config, top_k: int = 16,
                 threshold: float = 1e-3, chunk: Optional[int] = None) -> Dict[str, np.ndarray]:
  """The cache of one view: the samples of the frozen NeRF (`field`, `nerf_params`) along
  `rays` [H, W] (any leading shape) whose weight is above `threshold` (0 keeps all), as
  render.render_feature_image places them (the sampler's weighted_samples: the top_k
  heaviest a ray, or every sample the grid sampler marches), at most the `top_k` heaviest
  of each ray (cap_samples: on the grid sampler a ray's kept samples then carry the weight
  of those left out), `chunk` rays per jitted call.

  Returns: {"points" [P, 3], "weights" [P], "pixel" [P] int32, "accumulation" [n]} for the
  n rays, pixel-major.
  """
  config = sampling_config(config)
  sampler = sampler_of(config)
  config = sampler.render_config(config)
  chunk = chunk or config.render_chunk
  host_state = sampler.host_state(nerf_params)
  nerf_params = jax.device_put(nerf_params)
  _, flat, blank = flat_rays(rays)
  n = flat["origins"].shape[0]
  parts: List[Dict[str, np.ndarray]] = []
  for start in range(0, n, chunk):
    size = min(chunk, n - start)
    piece = padded(flat, blank, np.arange(start, start + size), chunk)
    budget = sampler.piece_budget(host_state, config, piece)
    out = jax.tree_util.tree_map(np.asarray, _samples_chunk(field, nerf_params, piece, config,
                                                            top_k, budget))
    keep = (out["ray"] < size) & (out["weights"] > threshold)
    part = cap_samples({"points": out["points"][keep], "weights": out["weights"][keep],
                        "pixel": out["ray"][keep].astype(np.int32)}, top_k, size)
    part["pixel"] += start
    parts.append(part)
  cache = {k: np.concatenate([p[k] for p in parts]) for k in CACHE_KEYS}
  cache["accumulation"] = np.bincount(cache["pixel"], cache["weights"], n).astype(np.float32)
  return cache


def cap_samples(lists: Dict[str, np.ndarray], top_k: int, n: int) -> Dict[str, np.ndarray]:
  """Sample lists ({"points" [P, 3], "weights" [P], "pixel" [P]} of n pixels) with at most
  the `top_k` heaviest samples of each pixel, in their order, each pixel's kept weights
  scaled to the sum of all of its weights (so a render from them keeps every pixel's
  opacity, and its colour is the weighted mean of its heaviest samples'). Lists that hold
  no more than top_k a pixel are returned as they are.
  """
  pixel, weights = lists["pixel"], lists["weights"]
  if pixel.size == 0 or np.bincount(pixel, minlength=n).max() <= top_k:
    return lists
  order = np.lexsort((-weights, pixel))  # pixel-major, heaviest first
  ordered = pixel[order]
  first = np.searchsorted(ordered, ordered, "left")  # where each one's pixel starts
  rank = np.empty_like(order)
  rank[order] = np.arange(order.size) - first
  keep = rank < top_k
  whole = np.bincount(pixel, weights, n)
  kept = np.bincount(pixel[keep], weights[keep], n)
  scale = (whole / np.maximum(kept, 1e-30)).astype(np.float32)
  return {"points": lists["points"][keep], "weights": weights[keep] * scale[pixel[keep]],
          "pixel": pixel[keep]}


def pack_views(views: List[Dict[str, np.ndarray]], multiple: int = 1024) -> Dict[str, np.ndarray]:
  """Views' caches (view_samples') as arrays with a leading [N]: their lists padded to the
  longest, rounded up to `multiple`, with weight 0 at pixel 0 (no effect on any render).

  Returns: {"points" [N, P, 3], "weights" [N, P], "pixel" [N, P], "accumulation" [N, n]}.
  """
  longest = max(v["weights"].shape[0] for v in views)
  size = max(multiple, -(-longest // multiple) * multiple)
  pad = lambda x: np.concatenate([x, np.zeros((size - x.shape[0], *x.shape[1:]), x.dtype)])
  packed = {k: np.stack([pad(v[k]) for v in views]) for k in CACHE_KEYS}
  packed["accumulation"] = np.stack([v["accumulation"] for v in views])
  return packed


def cached_render(colour_fn: Callable[[jnp.ndarray], jnp.ndarray],
                  cache: Dict[str, jnp.ndarray], background: Optional[jnp.ndarray] = None
                  ) -> jnp.ndarray:
  """A colour field rendered from one view's cached samples: the weighted sum of the colours
  at each pixel's samples, over `background` where the scene is transparent. Pure and
  jittable (it vmaps over views); its gradient reaches the colour field only.

  Args:
    colour_fn: points [P, 3] -> colours [..., P, C] (e.g. [M, P, 3]: M styles at once).
    cache: one view's {"points" [P, 3], "weights" [P], "pixel" [P], "accumulation" [n]}.
    background: [C] colour composited over by 1 - accumulation, or None (black).
  Returns: [..., n, C] the n pixels.
  """
  chex.assert_rank([cache["points"], cache["weights"]], [2, 1])
  n = cache["accumulation"].shape[-1]
  colours = colour_fn(cache["points"])
  colours = jnp.moveaxis(colours, -2, 0)  # [P, ..., C]
  weighted = cache["weights"].reshape((-1,) + (1,) * (colours.ndim - 1)) * colours
  rgb = jax.ops.segment_sum(weighted, cache["pixel"], n)
  rgb = jnp.moveaxis(rgb, 0, -2)
  if background is not None:
    rgb = rgb + (1.0 - cache["accumulation"])[:, None] * background
  return rgb


def deferred_grad(loss_fn: Callable[[jnp.ndarray], jnp.ndarray], colour_fn: Callable,
                  params, cache: Dict[str, jnp.ndarray],
                  background: Optional[jnp.ndarray] = None, chunk: int = 16384):
  """(loss, d loss / d params) of loss_fn(cached_render of the colour field) by ARF's
  deferred back-propagation: the view is rendered whole without gradients, the loss is
  differentiated with respect to its pixels, and the pixel gradients are pulled back to the
  params through the render of `chunk` samples at a time (a lax.scan), so the memory of the
  backward pass is one chunk's, not the view's. Rendering is linear in the colours, so this
  is the direct gradient. Pure and jittable.

  Args:
    loss_fn: image [..., n, C] -> [] (e.g. a VGG loss on the view reshaped).
    colour_fn: (params, points [P, 3]) -> colours [..., P, C].
    cache: one view's sample lists (cached_render's).
  """
  render = lambda p, lists, bg: cached_render(functools.partial(colour_fn, p), lists, bg)
  image = jax.lax.stop_gradient(render(params, cache, background))
  loss, pixel_grads = jax.value_and_grad(loss_fn)(image)
  size = cache["weights"].shape[0]
  pieces = -(-size // chunk)
  pad = lambda x: jnp.concatenate([x, jnp.zeros((pieces * chunk - size, *x.shape[1:]),
                                                x.dtype)]).reshape(pieces, chunk, *x.shape[1:])
  lists = {k: pad(cache[k]) for k in CACHE_KEYS}

  def add_piece(total, piece):
    piece = {**piece, "accumulation": cache["accumulation"]}
    _, pull = jax.vjp(lambda p: render(p, piece, None), params)
    return jax.tree_util.tree_map(jnp.add, total, pull(pixel_grads)[0]), None

  zeros = jax.tree_util.tree_map(jnp.zeros_like, params)
  grads, _ = jax.lax.scan(add_piece, zeros, lists)
  return loss, grads
