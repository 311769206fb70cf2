"""Rendering rays with a radiance field: the hierarchical coarse/fine pipeline, and whole
images in fixed-size chunks so memory stays bounded whatever the resolution."""

import functools
from typing import Callable, Dict, Optional

import chex
import jax
import jax.numpy as jnp
import numpy as np

from msnerf_jax import sampling
from msnerf_jax.rendering import volume_render

# field_fn(params, points [R, S, 3], viewdirs [R, S, 3]) -> (rgb [..., R, S, 3], raw sigma [R, S])
FieldFn = Callable[..., tuple]


def draw_randomness(key: jax.Array, n_rays: int, config, train: bool = True
                    ) -> Dict[str, jnp.ndarray]:
  """All random numbers one training batch of rays needs, drawn up front.

  Drawing them for the global batch before it is split across devices makes a step's
  result independent of the number of devices.

  Returns:
    {"u_coarse": [R, n_coarse], "u_fine": [R, n_fine]} (stratified jitter and inverse-cdf
    uniforms) when perturbing, plus {"noise_coarse", "noise_fine"} (sigma noise, already
    scaled by raw_noise_std) when that is > 0. Empty when not training.
  """
  if not train:
    return {}
  k_uc, k_uf, k_nc, k_nf = jax.random.split(key, 4)
  out = {}
  if config.perturb:
    out["u_coarse"] = jax.random.uniform(k_uc, (n_rays, config.n_coarse))
    out["u_fine"] = jax.random.uniform(k_uf, (n_rays, config.n_fine))
  if config.raw_noise_std > 0:
    out["noise_coarse"] = config.raw_noise_std * jax.random.normal(k_nc, (n_rays, config.n_coarse))
    out["noise_fine"] = config.raw_noise_std * jax.random.normal(
        k_nf, (n_rays, config.n_coarse + config.n_fine))
  return out


def composite(rgb, raw_sigma, z_vals, rays, noise, white_background):
  """Activates raw density (plus optional noise) and volume-renders. Shapes as volume_render."""
  if noise is not None:
    raw_sigma = raw_sigma + noise
  return volume_render(rgb, jax.nn.relu(raw_sigma), z_vals, rays["directions"],
                       white_background)


def points_along(rays, z_vals):
  """Sample positions [R, S, 3] and view directions [R, 1, 3] (shared by a ray's samples)."""
  points = rays["origins"][..., None, :] + rays["directions"][..., None, :] * z_vals[..., None]
  return points, rays["viewdirs"][..., None, :]


def apply_in_chunks(field_fn: FieldFn, params, points, viewdirs, chunk: int):
  """field_fn over [R, S, 3] samples, about `chunk` samples (whole rays) at a time.

  A lax.map over groups of rays: mathematically the same as one call, but on CPU
  cache-sized matmuls train about twice as fast as one huge one. chunk <= 0: one call.
  """
  n_rays, n_samples = points.shape[:2]
  n = n_rays * n_samples
  if chunk <= 0 or n <= chunk:
    return field_fn(params, points, viewdirs)
  # Whole rays per chunk (per-ray view directions stay aligned): the largest divisor of
  # the ray count that keeps a chunk within `chunk` samples.
  per = max(d for d in range(1, max(1, chunk // n_samples) + 1) if n_rays % d == 0)
  split = lambda x: x.reshape(n_rays // per, per, *x.shape[1:])
  rgb, sigma = jax.lax.map(lambda pv: field_fn(params, pv[0], pv[1]),
                           (split(points), split(viewdirs)))
  return rgb.reshape(n_rays, *rgb.shape[2:]), sigma.reshape(n_rays, *sigma.shape[2:])


def render_rays(field_fn: FieldFn, params, rays: Dict[str, jnp.ndarray], config,
                randomness: Optional[Dict[str, jnp.ndarray]] = None,
                white_background: bool = False) -> Dict[str, Dict[str, jnp.ndarray]]:
  """Hierarchical volume sampling for a batch of rays (NeRF section 5.2).

  Coarse: n_coarse stratified samples through params["coarse"]. Fine: n_fine more drawn
  from the coarse weights by inverse-transform sampling; params["fine"] sees the sorted
  union of both sets.

  Args:
    field_fn: the radiance field, see FieldFn.
    params: {"coarse": ..., "fine": ...}.
    rays: ray_bundle dict, leading shape [R].
    randomness: from draw_randomness; empty/None renders deterministically (evaluation).
  Returns:
    {"coarse": outputs, "fine": outputs} with volume_render's outputs.
  """
  randomness = randomness or {}
  chex.assert_rank(rays["origins"], 2)
  z_coarse = sampling.stratified_samples(rays["near"], rays["far"], config.n_coarse,
                                         u=randomness.get("u_coarse"), lindisp=config.lindisp)
  points, viewdirs = points_along(rays, z_coarse)
  rgb, raw_sigma = apply_in_chunks(field_fn, params["coarse"], points, viewdirs,
                                   config.mlp_chunk)
  coarse = composite(rgb, raw_sigma, z_coarse, rays, randomness.get("noise_coarse"),
                     white_background)

  mids = 0.5 * (z_coarse[..., 1:] + z_coarse[..., :-1])
  z_fine = sampling.sample_pdf(mids, jax.lax.stop_gradient(coarse["weights"][..., 1:-1]),
                               config.n_fine, u=randomness.get("u_fine"))
  z_all = jnp.sort(jnp.concatenate([z_coarse, jax.lax.stop_gradient(z_fine)], -1), -1)
  points, viewdirs = points_along(rays, z_all)
  rgb, raw_sigma = apply_in_chunks(field_fn, params["fine"], points, viewdirs, config.mlp_chunk)
  fine = composite(rgb, raw_sigma, z_all, rays, randomness.get("noise_fine"), white_background)
  return {"coarse": coarse, "fine": fine}


def _styled_field_in_chunks(field, params, points, viewdirs, codes, chunk: int):
  """A style field over points [R, S, 3] (shared) or [M, R, S, 3] (per style), in chunks of
  whole rays. Returns rgb [M, R, S, 3] and raw sigma [R, S] or [M, R, S]."""
  per_style = points.ndim == 4
  n_styles = jax.tree_util.tree_leaves(codes)[0].shape[0]

  def rays_first(p, x, d):  # apply_in_chunks splits the leading (ray) axis.
    if per_style:
      x = jnp.moveaxis(x, 0, 1)
    rgb, sigma = field(p, x, d, codes)
    return jnp.moveaxis(rgb, 0, 1), (jnp.moveaxis(sigma, 0, 1) if sigma.ndim == 3 else sigma)

  if per_style:
    points = jnp.moveaxis(points, 0, 1)
  # The trunk runs once per sample, the heads once per (sample, style): scale the chunk down.
  rgb, sigma = apply_in_chunks(rays_first, params, points, viewdirs,
                               max(1, chunk // (n_styles if per_style else 1)))
  return jnp.moveaxis(rgb, 0, 1), (jnp.moveaxis(sigma, 0, 1) if sigma.ndim == 3 else sigma)


def render_rays_styles(field, params, rays: Dict[str, jnp.ndarray], styles: jnp.ndarray,
                       config, randomness: Optional[Dict[str, jnp.ndarray]] = None,
                       white_background: bool = False) -> Dict[str, Dict[str, jnp.ndarray]]:
  """Hierarchical volume sampling of the same rays in M styles at once.

  The style heads run once per style (`field.codes`). With a frozen density (standard
  variant) the weights do not depend on the style, so all styles share the coarse and fine
  samples and one trunk evaluation per sample. A density-aware field returns a density per
  style; then each style draws its own fine samples and the fine trunk runs per style.

  Args:
    field: a style field: `field.codes(params, styles)` and
      `field(params, points, viewdirs, codes) -> (rgb [M, ..., 3], raw sigma)`.
    params: {"coarse": ..., "fine": ...}.
    rays: ray_bundle dict, leading shape [R].
    styles: [M, style_dim] style vectors.
    config: the NerfConfig with the sampling settings.
  Returns:
    {"coarse": outputs, "fine": outputs}, volume_render's outputs with a leading [M].
  """
  randomness = randomness or {}
  chex.assert_rank([rays["origins"], styles], 2)
  n_styles = styles.shape[0]

  def composite_styles(rgb, raw_sigma, z_vals, noise):
    shape = rgb.shape[:-1]  # [M, R, S]
    if noise is not None:
      raw_sigma = raw_sigma + noise
    return volume_render(rgb, jax.nn.relu(jnp.broadcast_to(raw_sigma, shape)),
                         jnp.broadcast_to(z_vals, shape),
                         jnp.broadcast_to(rays["directions"], (*shape[:2], 3)), white_background)

  z_coarse = sampling.stratified_samples(rays["near"], rays["far"], config.n_coarse,
                                         u=randomness.get("u_coarse"), lindisp=config.lindisp)
  points, viewdirs = points_along(rays, z_coarse)
  codes = field.codes(params["coarse"], styles)
  rgb, raw_sigma = _styled_field_in_chunks(field, params["coarse"], points, viewdirs, codes,
                                           config.mlp_chunk)
  coarse = composite_styles(rgb, raw_sigma, z_coarse, randomness.get("noise_coarse"))

  shared = raw_sigma.ndim == 2  # the density does not depend on the style.
  weights = coarse["weights"][0] if shared else coarse["weights"]  # [R, S] or [M, R, S]
  mids = 0.5 * (z_coarse[..., 1:] + z_coarse[..., :-1])
  u_fine = randomness.get("u_fine")
  if not shared:
    mids = jnp.broadcast_to(mids, (n_styles, *mids.shape))
    u_fine = None if u_fine is None else jnp.broadcast_to(u_fine, (n_styles, *u_fine.shape))
  z_fine = sampling.sample_pdf(mids, jax.lax.stop_gradient(weights[..., 1:-1]), config.n_fine,
                               u=u_fine)
  z_all = jnp.sort(jnp.concatenate(
      [jnp.broadcast_to(z_coarse, z_fine.shape[:-1] + z_coarse.shape[-1:]),
       jax.lax.stop_gradient(z_fine)], -1), -1)
  if shared:
    points, viewdirs = points_along(rays, z_all)
  else:
    points = rays["origins"][:, None, :] + rays["directions"][:, None, :] * z_all[..., None]
  codes = field.codes(params["fine"], styles)
  rgb, raw_sigma = _styled_field_in_chunks(field, params["fine"], points, viewdirs, codes,
                                           config.mlp_chunk)
  fine = composite_styles(rgb, raw_sigma, z_all, randomness.get("noise_fine"))
  return {"coarse": coarse, "fine": fine}


IMAGE_OUTPUTS = ("rgb", "depth", "disparity", "accumulation")


@functools.partial(jax.jit, static_argnums=(0, 2, 3))
def _render_chunk(field_fn, params, config, white_background, rays, styles=None):
  if styles is None:
    out = render_rays(field_fn, params, rays, config, None, white_background)["fine"]
  else:
    out = render_rays_styles(field_fn, params, rays, styles, config, None,
                             white_background)["fine"]
  return {k: out[k] for k in IMAGE_OUTPUTS}


def render_image(field_fn: FieldFn, params, rays: Dict[str, jnp.ndarray], config,
                 white_background: bool = False, chunk: Optional[int] = None,
                 styles: Optional[jnp.ndarray] = None) -> Dict[str, np.ndarray]:
  """Renders rays of any leading shape (an image [H, W]) chunk by chunk, deterministically.

  Each jitted call sees exactly `chunk` rays (the last chunk is padded), so peak memory
  depends on the chunk size, not on the image size, and there is one compilation.
  With `styles` [M, style_dim] and a style field, renders all M styles in each call (a style
  sweep: the trunk runs once per sample for all of them, see render_rays_styles).

  Returns:
    numpy dict of rgb [..., 3], depth, disparity, accumulation [...] (fine network), each
    with a leading [M] when `styles` is given.
  """
  chunk = chunk or config.render_chunk
  shape = rays["origins"].shape[:-1]
  flat = {k: np.asarray(v).reshape(-1, *v.shape[len(shape):]) for k, v in rays.items()}
  n = flat["origins"].shape[0]
  axis = 0 if styles is None else 1  # where the ray axis of the outputs is.
  outputs = {k: [] for k in IMAGE_OUTPUTS}
  for start in range(0, n, chunk):
    piece = {k: v[start:start + chunk] for k, v in flat.items()}
    size = piece["origins"].shape[0]
    if size < chunk:  # pad with copies of the first ray: same shapes, one compilation.
      piece = {k: np.concatenate([v, np.repeat(v[:1], chunk - size, 0)]) for k, v in piece.items()}
    out = _render_chunk(field_fn, params, config, white_background, piece, styles)
    for k in IMAGE_OUTPUTS:
      outputs[k].append(np.take(np.asarray(out[k]), np.arange(size), axis=axis))
  result = {}
  for k, v in outputs.items():
    joined = np.concatenate(v, axis=axis)
    lead = joined.shape[:axis]
    result[k] = joined.reshape(*lead, *shape, *joined.shape[axis + 1:])
  return result
