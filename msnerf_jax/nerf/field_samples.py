"""Evaluating a field at samples along rays: sample positions, the field over [R, S] samples in
cache-sized chunks (with or without a per-batch conditioning such as M style codes), and the
activation and compositing of its outputs. Every sampler (msnerf_jax.nerf.samplers) uses
these."""

from typing import Callable

import jax
import jax.numpy as jnp

from msnerf_jax.nerf.volume_rendering import volume_render

# field_fn(params, points [R, S, 3], viewdirs [R, S, 3]) -> (rgb [..., R, S, 3], raw sigma [R, S])
FieldFn = Callable[..., tuple]


def composite(rgb, raw_sigma, z_vals, rays, noise, white_background, background=None):
  """Activates raw density (plus optional noise) and volume-renders.

  Args:
    rgb: [*L, R, S, 3] colours, with any leading conditioning axes L (none, or [M] styles).
    raw_sigma: [R, S] (shared by every conditioning) or [*L, R, S] raw densities.
    z_vals: [R, S] or [*L, R, S] sample depths.
    noise: None or [R, S] sigma noise (added before the activation).
    background: None or [R, 3] colours composited over (replaces white_background).
  Returns:
    volume_render's outputs with leading L, plus the sample depths "z_vals" [R, S] or
    [*L, R, S] they were computed at (for losses on the weights).
  """
  shape = rgb.shape[:-1]  # [*L, R, S]
  if noise is not None:
    raw_sigma = raw_sigma + noise
  out = volume_render(rgb, jax.nn.relu(jnp.broadcast_to(raw_sigma, shape)),
                      jnp.broadcast_to(z_vals, shape),
                      jnp.broadcast_to(rays["directions"], (*shape[:-1], 3)),
                      white_background, background)
  return {**out, "z_vals": z_vals}


def points_along(rays, z_vals):
  """Sample positions [*L, R, S, 3] of depths z_vals [*L, R, S] (L: optional leading axes,
  one set of samples per conditioning) and view directions [R, 1, 3] (shared by a ray's
  samples)."""
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


def field_in_chunks(field, params, points, viewdirs, codes, chunk: int):
  """The field over points [R, S, 3] (shared) or [M, R, S, 3] (one set per conditioning), in
  chunks of whole rays (apply_in_chunks).

  codes None: an unconditioned field, `field(params, points, viewdirs)`. Otherwise the
  per-batch conditioning (`field.codes(params, conditioning)`, e.g. M style codes), passed
  as `field(params, points, viewdirs, codes)` -> rgb [M, R, S, 3], raw sigma [R, S] or
  [M, R, S]. Returns (rgb, raw sigma) with those shapes.
  """
  if codes is None:
    return apply_in_chunks(field, params, points, viewdirs, chunk)
  per_point_set = points.ndim == 4
  n_conditions = jax.tree_util.tree_leaves(codes)[0].shape[0]

  def rays_first(p, x, d):  # apply_in_chunks splits the leading (ray) axis.
    if per_point_set:
      x = jnp.moveaxis(x, 0, 1)
    rgb, sigma = field(p, x, d, codes)
    return jnp.moveaxis(rgb, 0, 1), (jnp.moveaxis(sigma, 0, 1) if sigma.ndim == 3 else sigma)

  if per_point_set:
    points = jnp.moveaxis(points, 0, 1)
  # The trunk runs once per sample, the heads once per (sample, condition): scale the chunk
  # (chunk <= 0, one call, stays one call: a chunk of 1 would map over the rays one by one).
  if chunk > 0:
    chunk = max(1, chunk // (n_conditions if per_point_set else 1))
  rgb, sigma = apply_in_chunks(rays_first, params, points, viewdirs, chunk)
  return jnp.moveaxis(rgb, 0, 1), (jnp.moveaxis(sigma, 0, 1) if sigma.ndim == 3 else sigma)
