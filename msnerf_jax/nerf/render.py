"""The one renderer of every field: a batch of rays through the sampler the config names
(msnerf_jax.nerf.samplers), and whole images in fixed-size chunks so memory stays bounded
whatever the resolution, split over the devices of a mesh."""

import functools
from typing import Dict, Optional

import chex
import jax
import jax.numpy as jnp
import numpy as np

from jax.sharding import Mesh, PartitionSpec

from msnerf_jax.core import parallel
from msnerf_jax.nerf.field_samples import FieldFn
from msnerf_jax.nerf.samplers import sampler_of


def sampling_config(config):
  """The NerfConfig that holds the sampling settings: `config` itself, or the NeRF config a
  run's config holds (a MultistyleConfig's or FeatureConfig's `.nerf`)."""
  return getattr(config, "nerf", config)


def draw_randomness(key: jax.Array, n_rays: int, config, train: bool = True
                    ) -> Dict[str, jnp.ndarray]:
  """All random numbers one training batch of rays needs, drawn up front (the sampler's).

  Drawing them for the global batch before it is split across devices makes a step's
  result independent of the number of devices.

  Returns:
    hierarchical: {"u_coarse": [R, n_coarse], "u_fine": [R, n_fine]} (stratified jitter and
    inverse-cdf uniforms) when perturbing, plus {"noise_coarse", "noise_fine"} (sigma noise,
    already scaled by raw_noise_std) when that is > 0. grid: {"u_march": [R]} (where in its
    step each ray's samples sit) when perturbing. Empty when not training.
  """
  if not train:
    return {}
  return sampler_of(config).draw_randomness(key, n_rays, config)


def render_rays(field, params, rays: Dict[str, jnp.ndarray], config,
                randomness: Optional[Dict[str, jnp.ndarray]] = None,
                white_background: bool = False, background: Optional[jnp.ndarray] = None,
                conditioning=None) -> Dict[str, Dict[str, jnp.ndarray]]:
  """Hierarchical volume sampling (NeRF section 5.2) of a batch of rays through any field:
  the one renderer of every field.

  Coarse: n_coarse stratified samples through params["coarse"]. Fine: n_fine more drawn
  from the coarse weights by inverse-transform sampling; params["fine"] sees the sorted
  union of both sets. With config.sampler "grid" there is one level instead: params["fine"]
  at the samples in the occupied cells of params["occupancy"] (samplers.grid).

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
    config: the NerfConfig with the sampling settings, or a run's config holding one
      (sampling_config).
    randomness: from draw_randomness; empty/None renders deterministically (evaluation).
    background: [R, 3] colours both levels are composited over (replaces white_background),
      or None.
    conditioning: None, or [M, ...] per-batch conditioning.
  Returns:
    {"coarse": outputs, "fine": outputs} with volume_render's outputs and "z_vals", each
    with a leading [M] when conditioned ({"fine"} alone with the grid sampler).
  """
  randomness = randomness or {}
  config = sampling_config(config)
  chex.assert_rank(rays["origins"], 2)
  if conditioning is not None:
    chex.assert_rank(conditioning, 2)
  return sampler_of(config).render_rays(field, params, rays, config, randomness,
                                        white_background, background, conditioning)


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
  out = sampler_of(config).image_rays(field_fn, params, rays, config, white_background, styles,
                                      budget, first)
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


def flat_rays(rays: Dict[str, jnp.ndarray]):
  """(leading shape, the rays as numpy [N, ...], a padding ray [1, ...]) of rays of any
  leading shape. The padding ray has zero length (far = near): it takes no samples from
  anyone's budget."""
  shape = rays["origins"].shape[:-1]
  flat = {k: np.asarray(v).reshape(-1, *v.shape[len(shape):]) for k, v in rays.items()}
  blank = {k: v[:1] for k, v in flat.items()}
  blank["far"] = blank["near"]
  return shape, flat, blank


def padded(flat: Dict[str, np.ndarray], blank: Dict[str, np.ndarray], take: np.ndarray,
           size: int) -> Dict[str, np.ndarray]:
  """The rays `take` of flat_rays' rays, padded to `size` rays with its blank ray: one
  rendering call's fixed-size piece (one compilation serves every call)."""
  return {k: np.concatenate([v[take], np.repeat(blank[k], size - take.size, 0)])
          for k, v in flat.items()}


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
  need, rounded up to a power of two (samplers.grid): no slot is spent
  on empty space or behind an opaque surface, and no ray overflows (one that did would go
  again at the front of a later call): the sampler's render_piece.

  `mesh` (parallel.AXIS; default: every device of this process, parallel.local_mesh):
  each call's rays are split over its devices (shard_map), `chunk` on each; a mesh of
  every process's devices (parallel.data_mesh after msnerf_jax.core.distributed.initialize)
  splits them over the processes too, and then every process calls this with the same
  rays and gets the whole image.

  Returns:
    numpy dict of rgb [..., 3], depth, disparity, accumulation [...] (fine network), each
    with a leading [M] when `styles` is given.
  """
  config = sampling_config(config)
  chunk = chunk or config.render_chunk
  sampler = sampler_of(config)
  config = sampler.render_config(config)
  mesh = mesh or parallel.local_mesh()
  host_state = sampler.host_state(params)
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
    piece = padded(flat, blank, take, per_call)
    out = sampler.render_piece(functools.partial(_render_call, field_fn), params, host_state,
                               config, white_background, mesh, piece, styles)
    done = out["complete"][:size]
    keep_complete(outputs, out, take, done, n, axis)
    pending = np.concatenate([take[~done], pending])
  return {k: joined.reshape(*joined.shape[:axis], *shape, *joined.shape[axis + 1:])
          for k, joined in outputs.items()}


def keep_complete(outputs: Dict[str, np.ndarray], out: Dict[str, np.ndarray],
                   take: np.ndarray, done: np.ndarray, n: int, axis: int) -> None:
  """Writes the complete rays (`done`) of one call's outputs (its first take.size rays, the
  ray axis at `axis`) into `outputs` [..., n, ...] at their indices `take`."""
  for k in IMAGE_OUTPUTS:
    value = np.take(out[k], np.arange(take.size), axis=axis)
    if k not in outputs:
      outputs[k] = np.zeros((*value.shape[:axis], n, *value.shape[axis + 1:]), value.dtype)
    index = (slice(None),) * axis + (take[done],)
    outputs[k][index] = np.take(value, np.nonzero(done)[0], axis=axis)


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
  the grid sampler's).

  Returns:
    {"features": [R, D], "accumulation": [R] (the sum of the weights used), "complete":
    [R] bool (False: a ray whose samples overflowed the grid sampler's budget)}.
  """
  chex.assert_rank(rays["origins"], 2)
  return sampler_of(config).feature_rays(field, feature_fn, params, rays, config, top_k, budget)


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
  sampler = sampler_of(config)
  host_state = sampler.host_state(params["nerf"])
  config = sampler.render_config(config)
  params = jax.device_put(params)
  shape, flat, blank = flat_rays(rays)
  n = flat["origins"].shape[0]
  parts = []
  for start in range(0, n, chunk):
    size = min(chunk, n - start)
    piece = padded(flat, blank, np.arange(start, start + size), chunk)
    budget = sampler.piece_budget(host_state, config, piece)
    out = _render_feature_chunk(field, feature_fn, params, piece, config, top_k, budget)
    parts.append({k: np.asarray(out[k])[:size] for k in ("features", "accumulation")})
  return {k: np.concatenate([p[k] for p in parts]).reshape(*shape, *parts[0][k].shape[1:])
          for k in ("features", "accumulation")}
