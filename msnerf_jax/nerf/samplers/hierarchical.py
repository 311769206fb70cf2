"""The hierarchical sampler (NeRF section 5.2): n_coarse stratified samples through
params["coarse"], then n_fine more drawn from the coarse weights by inverse-transform sampling;
params["fine"] sees the sorted union of both sets."""

import dataclasses
from typing import Dict

import jax
import jax.numpy as jnp

from msnerf_jax.nerf import sampling
from msnerf_jax.nerf.field_samples import composite, field_in_chunks, points_along
from msnerf_jax.nerf.samplers.base import Sampler


def render_level(field, params, rays, z_vals, conditioning, config, noise,
                 white_background: bool, background=None):
  """One level of the hierarchy: the field at depths z_vals [R, S] or [*L, R, S], composited.

  Returns (composite's outputs, shared): `shared` is True when the density does not
  depend on the conditioning (then every conditioning has the same weights).
  """
  codes = None if conditioning is None else field.codes(params, conditioning)
  points, viewdirs = points_along(rays, z_vals)
  rgb, raw_sigma = field_in_chunks(field, params, points, viewdirs, codes, config.mlp_chunk)
  return (composite(rgb, raw_sigma, z_vals, rays, noise, white_background, background),
          raw_sigma.ndim == 2)


def fine_samples(z_coarse, weights, n_fine: int, u=None):
  """The fine level's sorted depths: z_coarse [R, Sc] plus n_fine inverse-transform samples
  of the coarse weights [R, Sc] or [*L, R, Sc] (NeRF section 5.2), no gradient through
  their placement. Returns [R, Sc + n_fine] or [*L, R, Sc + n_fine]."""
  mids = 0.5 * (z_coarse[..., 1:] + z_coarse[..., :-1])
  lead = weights.shape[:-1]
  if weights.ndim > z_coarse.ndim:  # one set of samples per conditioning.
    mids = jnp.broadcast_to(mids, (*lead, mids.shape[-1]))
    u = None if u is None else jnp.broadcast_to(u, (*lead, u.shape[-1]))
  z_fine = sampling.sample_pdf(mids, jax.lax.stop_gradient(weights[..., 1:-1]), n_fine, u=u)
  return jnp.sort(jnp.concatenate(
      [jnp.broadcast_to(z_coarse, (*lead, z_coarse.shape[-1])),
       jax.lax.stop_gradient(z_fine)], -1), -1)


def draw_randomness(key: jax.Array, n_rays: int, config) -> Dict[str, jnp.ndarray]:
  """{"u_coarse": [R, n_coarse], "u_fine": [R, n_fine]} (stratified jitter and inverse-cdf
  uniforms) when perturbing, plus {"noise_coarse", "noise_fine"} (sigma noise, already scaled
  by raw_noise_std) when that is > 0."""
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


def render_rays(field, params, rays, config, randomness, white_background, background=None,
                conditioning=None) -> Dict[str, Dict[str, jnp.ndarray]]:
  """{"coarse": outputs, "fine": outputs} of the two levels (render.render_rays' contract)."""
  z_coarse = sampling.stratified_samples(rays["near"], rays["far"], config.n_coarse,
                                         u=randomness.get("u_coarse"), lindisp=config.lindisp)
  coarse, shared = render_level(field, params["coarse"], rays, z_coarse, conditioning, config,
                                randomness.get("noise_coarse"), white_background, background)
  weights = coarse["weights"]
  if shared and conditioning is not None:  # the same weights for every conditioning.
    weights = weights[0]
  z_all = fine_samples(z_coarse, weights, config.n_fine, randomness.get("u_fine"))
  fine, _ = render_level(field, params["fine"], rays, z_all, conditioning, config,
                         randomness.get("noise_fine"), white_background, background)
  return {"coarse": coarse, "fine": fine}


def weighted_samples(field, nerf_params, rays, config, top_k: int):
  """The `top_k` heaviest fine samples of each ray of the frozen NeRF and their weights,
  ray-major: Sampler.weighted_samples' outputs (points [R * K, 3])."""
  n = rays["origins"].shape[0]
  fine = render_rays(field, jax.lax.stop_gradient(nerf_params), rays, config, {}, False)["fine"]
  k = min(top_k, fine["weights"].shape[-1])
  weights, index = jax.lax.top_k(jax.lax.stop_gradient(fine["weights"]), k)
  points, _ = points_along(rays, jnp.take_along_axis(fine["z_vals"], index, -1))
  return {"points": jax.lax.stop_gradient(points).reshape(-1, 3),
          "weights": weights.reshape(-1), "ray": jnp.repeat(jnp.arange(n), k),
          "complete": jnp.ones((n,), bool)}


def feature_rays(field, feature_fn, params, rays, config, top_k: int):
  """A feature field composited with the NeRF's frozen weights at the `top_k` heaviest fine
  samples of each ray: render.render_feature_rays' outputs."""
  n = rays["origins"].shape[0]
  out = weighted_samples(field, params["nerf"], rays, config, top_k)
  weights = out["weights"].reshape(n, -1)
  feats = feature_fn(params["features"], out["points"].reshape(n, weights.shape[1], 3))
  return {"features": jnp.sum(weights[..., None] * feats, -2),
          "accumulation": jnp.sum(weights, -1), "complete": out["complete"]}


@dataclasses.dataclass(frozen=True)
class HierarchicalSampler(Sampler):
  """Coarse and fine networks; a rendering call renders its rays whole."""
  name: str = "hierarchical"
  levels: tuple = ("coarse", "fine")
  occupancy: bool = False

  def draw_randomness(self, key, n_rays, config):
    return draw_randomness(key, n_rays, config)

  def render_rays(self, field, params, rays, config, randomness, white_background,
                  background=None, conditioning=None):
    return render_rays(field, params, rays, config, randomness, white_background, background,
                       conditioning)

  def image_rays(self, field, params, rays, config, white_background, conditioning=None,
                 budget=None, first=None):
    del budget, first
    return render_rays(field, params, rays, config, {}, white_background, None,
                       conditioning)["fine"]

  def render_piece(self, call, params, host_state, config, white_background, mesh, piece,
                   styles):
    del host_state
    return call(params, config, white_background, mesh, piece, styles)

  def feature_rays(self, field, feature_fn, params, rays, config, top_k, budget=None):
    del budget
    return feature_rays(field, feature_fn, params, rays, config, top_k)

  def weighted_samples(self, field, nerf_params, rays, config, top_k, budget=None):
    del budget
    return weighted_samples(field, nerf_params, rays, config, top_k)


HIERARCHICAL = HierarchicalSampler()
