"""Rendering rays with a radiance field: the hierarchical coarse/fine pipeline, and whole
images in fixed-size chunks so memory stays bounded whatever the resolution."""

import dataclasses
import functools
from typing import Callable, Dict, Optional

import chex
import jax
import jax.numpy as jnp
import numpy as np

from jax.sharding import Mesh, PartitionSpec

from msnerf_jax.nerf import occupancy
from msnerf_jax.core import parallel
from msnerf_jax.nerf import sampling
from msnerf_jax.nerf.volume_rendering import disparity_of, volume_render, volume_render_packed

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
    scaled by raw_noise_std) when that is > 0. With the occupancy-grid sampler
    (config.sampler "grid"): {"u_march": [R]} (where in its step each ray's samples sit)
    when perturbing. Empty when not training.
  """
  if not train:
    return {}
  if config.sampler == "grid":
    return {"u_march": jax.random.uniform(key, (n_rays,))} if config.perturb else {}
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
  # The trunk runs once per sample, the heads once per (sample, condition): scale the chunk.
  rgb, sigma = apply_in_chunks(rays_first, params, points, viewdirs,
                               max(1, chunk // (n_conditions if per_point_set else 1)))
  return jnp.moveaxis(rgb, 0, 1), (jnp.moveaxis(sigma, 0, 1) if sigma.ndim == 3 else sigma)


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


def render_rays(field, params, rays: Dict[str, jnp.ndarray], config,
                randomness: Optional[Dict[str, jnp.ndarray]] = None,
                white_background: bool = False, background: Optional[jnp.ndarray] = None,
                conditioning=None) -> Dict[str, Dict[str, jnp.ndarray]]:
  """Hierarchical volume sampling (NeRF section 5.2) of a batch of rays through any field:
  the one renderer of every field.

  Coarse: n_coarse stratified samples through params["coarse"]. Fine: n_fine more drawn
  from the coarse weights by inverse-transform sampling; params["fine"] sees the sorted
  union of both sets. With config.sampler "grid" there is one level instead: params["fine"]
  at the samples in the occupied cells of params["occupancy"] (render_rays_grid).

  With a `conditioning` (e.g. [M, style_dim] style vectors) the same rays render under
  each of its M entries at once: `field.codes(params, conditioning)` runs once per level,
  the field returns rgb [M, ...]. A field whose density does not depend on the
  conditioning (the standard multi-style model) shares the samples and one trunk
  evaluation per sample across all M; one whose density does (density-aware) draws fine
  samples per conditioning, and the fine trunk runs per conditioning.

  Args:
    field: `field(params, points [R, S, 3], viewdirs [R, 1, 3]) -> (rgb [R, S, 3], raw
      sigma [R, S])` (FieldFn); with a conditioning, a conditioned field (see
      field_in_chunks).
    params: {"coarse": ..., "fine": ...}.
    rays: ray_bundle dict, leading shape [R].
    config: the NerfConfig with the sampling settings.
    randomness: from draw_randomness; empty/None renders deterministically (evaluation).
    background: [R, 3] colours both levels are composited over (replaces white_background),
      or None.
    conditioning: None, or [M, ...] per-batch conditioning.
  Returns:
    {"coarse": outputs, "fine": outputs} with volume_render's outputs and "z_vals", each
    with a leading [M] when conditioned ({"fine"} alone with the grid sampler).
  """
  randomness = randomness or {}
  chex.assert_rank(rays["origins"], 2)
  if conditioning is not None:
    chex.assert_rank(conditioning, 2)
  if config.sampler == "grid":
    return {"fine": render_rays_grid(field, params, rays, config, randomness, white_background,
                                     background, conditioning)}
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


def render_rays_grid(field, params, rays: Dict[str, jnp.ndarray], config,
                     randomness: Dict[str, jnp.ndarray], white_background: bool,
                     background: Optional[jnp.ndarray] = None, conditioning=None,
                     budget: Optional[int] = None, first: Optional[jnp.ndarray] = None
                     ) -> Dict[str, jnp.ndarray]:
  """One level of samples in the occupied cells (occupancy.march), composited.

  The sample budget is `budget` slots (static; default config.samples_per_ray x R) for the
  whole batch: rays through empty space take none, rays through the object what they need.

  Args: as render_rays; params {"fine": field params, "occupancy": [G, G, G] grid values};
    rays may carry "alive" [R] bool, and `first` limits the steps to one segment
    (occupancy.march).
  Returns:
    volume_render_packed's outputs (rgb, depth, disparity, accumulation with a leading [M]
    when conditioned; weights [B]) and "complete" [R] bool: False for a ray whose samples
    did not all fit in the budget (render it again in a smaller batch; leave it out of a
    loss); the slots' rays "sample_ray" [B] (R for an empty slot), positions
    "sample_points" [B, 3] and steps "sample_interval" [B, 2] (occupancy.march's interval).
  """
  n = rays["origins"].shape[0]
  grid = occupancy.occupied(params["occupancy"], config.grid_threshold)
  samples = occupancy.march(rays, grid, config, budget or n * config.samples_per_ray,
                            randomness.get("u_march"), first)
  ray = jnp.minimum(samples["ray"], n - 1)
  points = rays["origins"][ray] + rays["directions"][ray] * samples["t"][:, None]
  codes = None if conditioning is None else field.codes(params["fine"], conditioning)
  rgb, sigma = field_in_chunks(field, params["fine"], points[:, None], rays["viewdirs"][ray][:, None],
                               codes, config.mlp_chunk)
  if sigma.ndim != 2:
    raise ValueError("the occupancy-grid sampler needs a density shared by every conditioning")
  rgb = rgb[..., 0, :]  # [B, 3] or [M, B, 3]
  if conditioning is not None:
    rgb = jnp.moveaxis(rgb, 0, 1)
  out = volume_render_packed(rgb, jax.nn.relu(sigma[:, 0]), samples, n, white_background,
                             background)
  if conditioning is not None:  # the styles first, as render_level's outputs.
    m = conditioning.shape[0]
    out = {"rgb": jnp.moveaxis(out["rgb"], 1, 0), "weights": out["weights"],
           **{k: jnp.broadcast_to(out[k], (m, n)) for k in ("depth", "disparity", "accumulation")}}
  return {**out, "complete": samples["complete"], "sample_ray": samples["ray"],
          "sample_points": points, "sample_interval": samples["interval"]}


def render_rays_styles(field, params, rays: Dict[str, jnp.ndarray], styles: jnp.ndarray,
                       config, randomness: Optional[Dict[str, jnp.ndarray]] = None,
                       white_background: bool = False) -> Dict[str, Dict[str, jnp.ndarray]]:
  """render_rays of the same rays in M styles at once: styles [M, style_dim] are the
  conditioning of a style field (`field.codes(params, styles)` and
  `field(params, points, viewdirs, codes) -> (rgb [M, ..., 3], raw sigma)`). Returns
  {"coarse", "fine"} outputs with a leading [M]."""
  return render_rays(field, params, rays, config, randomness, white_background,
                     conditioning=styles)


IMAGE_OUTPUTS = ("rgb", "depth", "disparity", "accumulation")


def _image_outputs(field_fn, params, config, white_background, budget, rays, styles=None,
                   first=None):
  if config.sampler == "grid":
    out = render_rays_grid(field_fn, params, rays, config, {}, white_background,
                           conditioning=styles, budget=budget, first=first)
  else:
    out = render_rays(field_fn, params, rays, config, None, white_background,
                      conditioning=styles)["fine"]
  complete = out.get("complete", jnp.ones(rays["origins"].shape[:1], bool))
  return {**{k: out[k] for k in IMAGE_OUTPUTS}, "complete": complete}


_render_chunk = jax.jit(_image_outputs, static_argnums=(0, 2, 3, 4))


@functools.partial(jax.jit, static_argnums=(0, 2, 3, 4, 5))
def _render_chunk_sharded(field_fn, params, config, white_background, budget, mesh: Mesh, rays,
                          styles=None, first=None):
  """_image_outputs with the rays split over the devices of `mesh` (shard_map)."""
  split, whole = PartitionSpec(parallel.AXIS), PartitionSpec()
  ray_axis = split if styles is None else PartitionSpec(None, parallel.AXIS)
  specs = {**{k: ray_axis for k in IMAGE_OUTPUTS}, "complete": split}
  return jax.shard_map(
      lambda p, r, s, g: _image_outputs(field_fn, p, config, white_background, budget, r, s, g),
      mesh=mesh, in_specs=(whole, split, whole, whole), out_specs=specs)(params, rays, styles,
                                                                          first)


def _render_call(field_fn, params, config, white_background, mesh, piece, styles, budget=None,
                 first=None):
  """One jitted call on `piece`'s rays, split over `mesh`; numpy outputs."""
  if mesh.size == 1:
    out = _render_chunk(field_fn, params, config, white_background, budget, piece, styles,
                        first)
  else:
    out = parallel.gather(_render_chunk_sharded(field_fn, params, config, white_background,
                                                budget, mesh, parallel.split_rows(piece, mesh),
                                                styles, first))
  return {k: np.asarray(v) for k, v in out.items()}


@functools.partial(jax.jit, static_argnums=(1,))
def _sample_counts(grid, config, rays, first):
  return occupancy.count(rays, occupancy.occupied(grid, config.grid_threshold), config, first)


def sample_budget(needed: int, config) -> int:
  """The static budget of a rendering call that needs `needed` samples: the next power of
  two (so a few compilations serve every call), at least one ray's march_steps."""
  return max(config.march_steps, 1 << max(0, int(needed) - 1).bit_length())


TERMINATED = 1e-4  # rendering stops a ray once its transmittance falls below this.
RENDER_MLP_CHUNK = 16384  # samples per field call when rendering a config with mlp_chunk 0.


def _render_call_grid(field_fn, params, grid, config, white_background, mesh, piece, styles):
  """One call's rays with the grid sampler, marched in config.march_segments segments of
  their steps: after each, rays whose transmittance fell below TERMINATED take no more
  samples (early ray termination), and each segment gets the budget its samples need
  (counted first on the host). The segments' composites are joined front to back."""
  n = piece["origins"].shape[0]
  trans = np.ones(n, np.float32)
  total, complete = None, np.ones(n, bool)
  for first in range(0, config.march_steps, occupancy.segment_length(config)):
    piece = {**piece, "alive": trans > TERMINATED}
    first = np.int32(first)
    needed = np.asarray(_sample_counts(grid, config, piece, first))
    needed = needed.reshape(mesh.size, -1).sum(1).max()
    if needed == 0 and total is not None:
      continue
    out = _render_call(field_fn, params, config, False, mesh, piece, styles,
                       sample_budget(needed, config), first)
    if total is None:
      total = {k: np.zeros_like(out[k]) for k in ("rgb", "depth", "accumulation")}
    total["rgb"] += trans[:, None] * out["rgb"]
    total["depth"] += trans * out["depth"]
    total["accumulation"] += trans * out["accumulation"]
    acc = out["accumulation"] if styles is None else out["accumulation"][0]
    trans = trans * (1.0 - acc)
    complete &= out["complete"]
  acc = total["accumulation"]
  disparity = np.asarray(disparity_of(total["depth"], acc))
  rgb = total["rgb"] + (1.0 - acc)[..., None] if white_background else total["rgb"]
  return {"rgb": rgb, "depth": total["depth"], "disparity": disparity, "accumulation": acc,
          "complete": complete}


def flat_rays(rays: Dict[str, jnp.ndarray]):
  """(leading shape, the rays as numpy [N, ...], a padding ray [1, ...]) of rays of any
  leading shape. The padding ray has zero length (far = near): it takes no samples from
  anyone's budget."""
  shape = rays["origins"].shape[:-1]
  flat = {k: np.asarray(v).reshape(-1, *v.shape[len(shape):]) for k, v in rays.items()}
  blank = {k: v[:1] for k, v in flat.items()}
  blank["far"] = blank["near"]
  return shape, flat, blank


def render_image(field_fn: FieldFn, params, rays: Dict[str, jnp.ndarray], config,
                 white_background: bool = False, chunk: Optional[int] = None,
                 styles: Optional[jnp.ndarray] = None, mesh: Optional[Mesh] = None
                 ) -> Dict[str, np.ndarray]:
  """Renders rays of any leading shape (an image [H, W]) chunk by chunk, deterministically.

  Each jitted call sees exactly `chunk` rays per device (the last call is padded with rays
  of zero length), so peak memory depends on the chunk size, not on the image size, and
  there is one compilation. With `styles` [M, style_dim] and a style field, renders all M
  styles in each call (a style sweep: the trunk runs once per sample for all of them, see
  render_rays_styles). With the occupancy-grid sampler, each call marches its rays in
  segments with early ray termination, and each segment's sample budget is what its rays
  need, rounded up to a power of two (_render_call_grid, sample_budget): no slot is spent
  on empty space or behind an opaque surface, and no ray overflows (one that did would go
  again at the front of a later call).

  `mesh` (parallel.AXIS; default: every device of this process, parallel.local_mesh):
  each call's rays are split over its devices (shard_map), `chunk` on each; a mesh of
  every process's devices (parallel.data_mesh after msnerf_jax.core.distributed.initialize)
  splits them over the processes too, and then every process calls this with the same
  rays and gets the whole image.

  Returns:
    numpy dict of rgb [..., 3], depth, disparity, accumulation [...] (fine network), each
    with a leading [M] when `styles` is given.
  """
  chunk = chunk or config.render_chunk
  if config.sampler == "grid" and config.mlp_chunk == 0:  # forward only: chunks are cheap.
    config = dataclasses.replace(config, mlp_chunk=RENDER_MLP_CHUNK)
  mesh = mesh or parallel.local_mesh()
  grid = np.asarray(params["occupancy"]) if config.sampler == "grid" else None
  if mesh.size > 1:
    params = parallel.replicated(params, mesh)
    styles = None if styles is None else parallel.replicated(styles, mesh)
  else:  # on the device once, not once per call
    params, styles = jax.device_put((params, styles), mesh.devices.flat[0])
  per_call = chunk * mesh.size
  shape, flat, blank = flat_rays(rays)
  n = flat["origins"].shape[0]
  axis = 0 if styles is None else 1  # where the ray axis of the outputs is.
  outputs: Dict[str, np.ndarray] = {}
  pending = np.arange(n)
  while pending.size:
    take, pending = pending[:per_call], pending[per_call:]
    size = take.size
    piece = {k: np.concatenate([v[take], np.repeat(blank[k], per_call - size, 0)])
             for k, v in flat.items()}
    if grid is None:
      out = _render_call(field_fn, params, config, white_background, mesh, piece, styles)
    else:
      out = _render_call_grid(field_fn, params, grid, config, white_background, mesh, piece,
                              styles)
    done = out["complete"][:size]
    for k in IMAGE_OUTPUTS:
      value = np.take(out[k], np.arange(size), axis=axis)
      if k not in outputs:
        outputs[k] = np.zeros((*value.shape[:axis], n, *value.shape[axis + 1:]), value.dtype)
      index = (slice(None),) * axis + (take[done],)
      outputs[k][index] = np.take(value, np.nonzero(done)[0], axis=axis)
    pending = np.concatenate([take[~done], pending])
  result = {}
  for k, joined in outputs.items():
    lead = joined.shape[:axis]
    result[k] = joined.reshape(*lead, *shape, *joined.shape[axis + 1:])
  return result


# ----------------------------------------------------------------------------- feature fields


def render_feature_rays(field, feature_fn, params, rays: Dict[str, jnp.ndarray], config,
                        top_k: int = 16, budget: Optional[int] = None
                        ) -> Dict[str, jnp.ndarray]:
  """A feature field along rays, composited with a NeRF's frozen weights.

  The NeRF (`field`, params["nerf"]) renders the rays as render_rays does without
  randomness, under stop_gradient (no gradient reaches it, and XLA computes none); its
  weights composite `feature_fn(params["features"], points [..., 3]) -> [..., D]` at the
  samples that carry them: with the hierarchical sampler the `top_k` heaviest fine samples
  of each ray, with the grid sampler every sample it marched (`budget` slots, as
  render_rays_grid's).

  Returns:
    {"features": [R, D], "accumulation": [R] (the sum of the weights used), "complete":
    [R] bool (False: a ray whose samples overflowed the grid sampler's budget)}.
  """
  chex.assert_rank(rays["origins"], 2)
  n = rays["origins"].shape[0]
  nerf = jax.lax.stop_gradient(params["nerf"])
  if config.sampler == "grid":
    out = render_rays_grid(field, nerf, rays, config, {}, False, budget=budget)
    weights = jax.lax.stop_gradient(out["weights"])
    feats = feature_fn(params["features"], jax.lax.stop_gradient(out["sample_points"]))
    per_ray = lambda x: jax.ops.segment_sum(x, out["sample_ray"], n + 1,
                                            indices_are_sorted=True)[:n]
    return {"features": per_ray(weights[:, None] * feats), "accumulation": per_ray(weights),
            "complete": out["complete"]}
  fine = render_rays(field, nerf, rays, config)["fine"]
  k = min(top_k, fine["weights"].shape[-1])
  weights, index = jax.lax.top_k(jax.lax.stop_gradient(fine["weights"]), k)
  points, _ = points_along(rays, jnp.take_along_axis(fine["z_vals"], index, -1))
  feats = feature_fn(params["features"], jax.lax.stop_gradient(points))  # [R, K, D]
  return {"features": jnp.sum(weights[..., None] * feats, -2),
          "accumulation": jnp.sum(weights, -1), "complete": jnp.ones((n,), bool)}


_render_feature_chunk = jax.jit(render_feature_rays, static_argnums=(0, 1, 4, 5, 6))


def render_feature_image(field, feature_fn, params, rays: Dict[str, jnp.ndarray], config,
                         top_k: int = 16, chunk: Optional[int] = None
                         ) -> Dict[str, np.ndarray]:
  """render_feature_rays over rays of any leading shape [...], `chunk` rays per jitted call
  (the last padded with rays of zero length; with the grid sampler each call's budget is
  the samples its rays need, counted first, so none overflows).

  Returns: numpy {"features": [..., D], "accumulation": [...]}.
  """
  chunk = chunk or config.render_chunk
  grid = np.asarray(params["nerf"]["occupancy"]) if config.sampler == "grid" else None
  if grid is not None and config.mlp_chunk == 0:  # forward only: chunks are cheap.
    config = dataclasses.replace(config, mlp_chunk=RENDER_MLP_CHUNK)
  params = jax.device_put(params)
  shape, flat, blank = flat_rays(rays)
  n = flat["origins"].shape[0]
  parts = []
  for start in range(0, n, chunk):
    size = min(chunk, n - start)
    piece = {k: np.concatenate([v[start:start + size], np.repeat(blank[k], chunk - size, 0)])
             for k, v in flat.items()}
    budget = None
    if grid is not None:
      budget = sample_budget(np.asarray(_sample_counts(grid, config, piece, None)).sum(), config)
    out = _render_feature_chunk(field, feature_fn, params, piece, config, top_k, budget)
    parts.append({k: np.asarray(out[k])[:size] for k in ("features", "accumulation")})
  return {k: np.concatenate([p[k] for p in parts]).reshape(*shape, *parts[0][k].shape[1:])
          for k in ("features", "accumulation")}
