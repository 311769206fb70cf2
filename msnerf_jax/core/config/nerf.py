"""The scene and NeRF configs, and the NeRF presets (paper, cpu, fast)."""

import dataclasses
import functools
from typing import Any

from msnerf_jax.core.config.base import (bad_setting, check_at_least, check_hash_settings,
                                         override, setting)
from msnerf_jax.core.config.optim import OptimConfig, optimisation
from msnerf_jax.core.errors import UserError


@dataclasses.dataclass(frozen=True)
class DataConfig:
  """Which scene to load and how (saved with a run so eval/render reload the same views)."""
  path: str = setting("", "scene folder (Blender, LLFF or a capture, auto-detected)")
  format: str = setting("auto", "scene format: auto, blender, llff, transforms (nerfstudio / "
                                "instant-ngp transforms.json) or colmap (sparse/0 model)")
  downscale: int = setting(0, "image downscale factor (0 = the format's: Blender 1, LLFF 8, "
                              "captures the smallest power of two that brings the longer side "
                              "to 400 px or less; LLFF and captures read images_N when present)")
  llff_holdout: int = setting(8, "LLFF, and captures without a split: every n-th image is held "
                                 "out for val/test")
  layout: str = setting("auto", "captures: auto (decided from the cameras), forward-facing "
                                "(LLFF recentring + NDC) or object (centred on what the cameras "
                                "look at, bounds from the data)")

  def validate(self) -> "DataConfig":
    """The config itself, or UserError naming the first setting that cannot work (the format
    and layout names are checked by the scene loaders, which know them)."""
    check_at_least(self, ("llff_holdout",))
    return self


@dataclasses.dataclass(frozen=True)
class NerfConfig:
  """Vanilla NeRF: architecture, sampling and optimisation (defaults = reference code, Blender)."""
  # Architecture (the `trunk` a multi-style model later freezes): "mlp" (the reference MLP)
  # or "hash" (multiresolution hash encoding, models/hash_trunk.py: net_width is the width of
  # its small MLPs; net_depth, skip_layer and pos_freqs are the MLP's alone).
  trunk: str = setting("mlp", "the trunk: mlp (the reference MLP) or hash (multiresolution hash "
                              "encoding)")
  net_depth: int = setting(8, "trunk layers (the skip connection goes to the middle)")
  net_width: int = setting(256, "trunk width")
  skip_layer: int = setting(4, "trunk layer whose output gets the encoded input again")
  pos_freqs: int = setting(10, "positional-encoding frequencies of the points")
  dir_freqs: int = setting(4, "positional-encoding frequencies of the view directions")
  hash_levels: int = setting(16, "hash trunk: resolution levels")
  hash_features: int = setting(2, "hash trunk: features per level")
  hash_table_size: int = setting(2 ** 17, "hash trunk: table entries per level (a power of two)")
  hash_min_res: int = setting(16, "hash trunk: coarsest grid resolution")
  hash_max_res: int = setting(512, "hash trunk: finest grid resolution")
  # Sampling (msnerf_jax/nerf/samplers): "hierarchical" (coarse and fine networks, n_coarse +
  # n_fine samples per ray) or "grid" (one network, samples only in the occupied cells of an
  # occupancy grid; see msnerf_jax/nerf/occupancy.py).
  sampler: str = setting("hierarchical", "where to sample: hierarchical (coarse + fine "
                                         "networks) or grid (one network, only in the occupied "
                                         "cells of an occupancy grid)")
  n_coarse: int = setting(64, "stratified samples per ray")
  n_fine: int = setting(128, "extra hierarchical samples per ray")
  scene_box: float = setting(0.0, "half side of the scene's box around the origin, for the hash "
                                  "trunk and the grid (0 = Blender and NDC 1.5, captures: the "
                                  "farthest camera)")
  grid_resolution: int = setting(64, "grid sampler: cells per side of the occupancy grid")
  march_steps: int = setting(256, "grid sampler: candidate samples per ray across the box")
  march_segments: int = setting(2, "grid sampler: rendering marches in this many segments, a "
                                   "ray stopping after one once its transmittance is below 1e-4")
  samples_per_ray: int = setting(32, "grid sampler: sample budget per ray (shared by a batch's "
                                     "rays)")
  grid_every: int = setting(16, "grid sampler: steps between refreshes of the grid")
  grid_warmup: int = setting(256, "grid sampler: steps during which a refresh visits every cell")
  grid_decay: float = setting(0.95, "grid sampler: decay of a cell's density estimate at each "
                                    "refresh")
  grid_threshold: float = setting(0.01, "grid sampler: optical depth per step above which a "
                                        "cell is occupied")
  lindisp: bool = setting(False, "sample linearly in inverse depth instead of depth")
  perturb: bool = setting(True, "jitter the stratified samples while training")
  raw_noise_std: float = setting(0.0, "std of the noise added to the raw density while "
                                      "training")
  # Optimisation.
  batch_rays: int = setting(1024, "rays per step")
  optim: OptimConfig = optimisation(steps=200_000, lr_init=5e-4, lr_final=5e-5,
                                    lr_decay_steps=250_000, checkpoint_every=5000)
  precrop_steps: int = setting(500, "Blender: steps that sample only the central crop of each "
                                    "view (avoids an empty scene)")
  precrop_frac: float = setting(0.5, "side of that central crop, as a fraction of the view")
  # Empty space. random_background (scenes with alpha, i.e. Blender RGBA): every training ray
  # gets a random background colour per step; its target is the photo composited over it by
  # the photo's alpha and its render is composited over the same colour, so only true
  # transparency reproduces every background (white fog no longer explains a white one).
  # Rendering and evaluation still composite over white. distortion_weight: weight of the
  # mip-NeRF 360 distortion loss on both levels' weights, or on the occupancy grid's packed
  # samples (discourages floaters; any scene).
  random_background: bool = setting(False, "train against a random background colour per ray "
                                           "and step, so empty space stays empty (needs images "
                                           "with alpha; the presets turn it on for Blender "
                                           "scenes but for paper, as the reference code)")
  distortion_weight: float = setting(0.0, "weight of the mip-NeRF 360 distortion loss against "
                                          "semi-transparent floaters (0 = off)")
  # Bookkeeping.
  render_chunk: int = setting(4096, "rays per jitted rendering call (bounds memory whatever the "
                                    "image size)")
  mlp_chunk: int = setting(8192, "samples per MLP call inside a step (cache-sized matmuls; 0 = "
                                 "all at once)")

  def validate(self) -> "NerfConfig":
    """The config itself, or UserError `--OPTION VALUE: problem` naming the first setting
    that cannot work: the one place a NerfConfig's values are refused."""
    self.optim.validate()
    check_at_least(self, ("net_depth", "net_width", "n_coarse", "n_fine", "batch_rays",
                          "render_chunk"))
    check_at_least(self, ("pos_freqs", "dir_freqs", "precrop_steps", "mlp_chunk"), 0)
    if not 0.0 < self.precrop_frac <= 1.0:
      bad_setting(self, "precrop_frac", "must be in (0, 1]")
    if not self.raw_noise_std >= 0:
      bad_setting(self, "raw_noise_std", "must be >= 0")
    if not self.distortion_weight >= 0:
      bad_setting(self, "distortion_weight", "must be >= 0")
    bad = functools.partial(bad_setting, self)
    if self.trunk not in TRUNKS:
      bad("trunk", f"unknown trunk (choose from {', '.join(TRUNKS)})")
    if self.sampler not in SAMPLERS:
      bad("sampler", f"unknown sampler (choose from {', '.join(SAMPLERS)})")
    if self.trunk == "hash":
      check_hash_settings(self)
    if self.scene_box < 0:
      bad("scene_box", "must be >= 0 (0 = from the scene)")
    if self.sampler == SAMPLERS[1]:  # the occupancy grid's settings
      check_at_least(self, ("grid_resolution", "march_steps", "march_segments",
                            "samples_per_ray", "grid_every"))
      check_at_least(self, ("grid_warmup",), 0)
      if not 0.0 < self.grid_decay <= 1.0:
        bad("grid_decay", "must be in (0, 1]")
      if self.grid_threshold < 0:
        bad("grid_threshold", "must be >= 0")
      if self.raw_noise_std > 0:
        bad("raw_noise_std", "the occupancy-grid sampler adds no density noise (use 0)")
    return self


def _paper(llff: bool) -> NerfConfig:
  """The reference code's defaults."""
  return override(
      NerfConfig(),
      n_fine=64 if llff else 128,
      raw_noise_std=1.0 if llff else 0.0,
      precrop_steps=0 if llff else 500,
      steps=200_000,
      checkpoint_every=5000)


def _fast(llff: bool) -> NerfConfig:
  """The hash-grid trunk with the occupancy-grid sampler."""
  # Hash grid (16 levels x 2 features, 2^16 entries, 16 -> 256) and occupancy grid (64^3,
  # 128 steps across the box, a budget of 24 samples a ray): about 0.14 s per 1024-ray
  # step on 2 cores (lego 100x100), instant-NGP's learning rate and Adam.
  return override(
      NerfConfig(),
      trunk="hash",
      sampler="grid",
      net_width=64,
      hash_table_size=2 ** 16,
      hash_max_res=256,
      march_steps=128,
      # Forward-facing scenes fill the view: their rays need more of their 128 steps.
      samples_per_ray=64 if llff else 24,
      # Photos without alpha: the distortion loss against semi-transparent floaters, and
      # rendering in 16 segments (early ray termination). Measured on fern (README, "Empty
      # space"): 24.16 dB against 24.02 without it, 45% of the grid occupied against 85%,
      # a test view rendered in 8.2 s (16 segments) against 19.7 s (2 segments, no loss).
      distortion_weight=0.01 if llff else 0.0,
      march_segments=16 if llff else 2,
      batch_rays=1024,
      lr_init=1e-2,
      lr_final=3e-4,
      lr_decay_steps=6000,  # measured: 27.0 dB at step 3500 on lego, 26.6 with 4000
      precrop_steps=0,
      random_background=not llff,
      steps=4000,
      checkpoint_every=500,
      # One call: under a lax.map, the tables' gradient is a full-size scatter per chunk.
      mlp_chunk=0)


def _cpu(llff: bool) -> NerfConfig:
  """A small MLP for a 2-core laptop."""
  # 4x64 MLP, 16 + 32 samples: about 0.3 s per 1024-ray step on 2 cores (lego 100x100).
  return override(
      NerfConfig(),
      net_depth=4,
      net_width=64,
      skip_layer=2,
      n_coarse=16,
      n_fine=32,
      batch_rays=1024,
      lr_init=2e-3,
      lr_final=1e-4,
      lr_decay_steps=10_000,
      precrop_steps=0 if llff else 200,
      raw_noise_std=1.0 if llff else 0.0,
      random_background=not llff,
      steps=6000,
      checkpoint_every=500,
      mlp_chunk=2048)


_PRESETS = {"paper": _paper, "cpu": _cpu, "fast": _fast}
PRESETS = tuple(_PRESETS)
# The preset of every command that trains a NeRF (`msnerf nerf train`, the pipeline, the
# demo): on lego and fern it trains to 5 dB more than `cpu` in the same time.
DEFAULT_PRESET = "fast"


def nerf_preset(name: str, scene_format: str, **overrides: Any) -> NerfConfig:
  """The named preset for a scene format, with explicit overrides applied last.

  `paper`: the reference code's defaults (128 fine samples on Blender, 64 and sigma noise
  1.0 on LLFF and on captures; white backgrounds). `cpu`: a smaller network and fewer samples tuned for a
  2-core laptop, trained against random backgrounds on Blender scenes (no white fog).
  `fast`: the hash-grid trunk with the occupancy-grid sampler (instant-NGP's recipe, sized
  for a CPU), random backgrounds on Blender scenes, the distortion loss on the others.
  Overriding net_depth without skip_layer puts the skip connection after the middle layer,
  where both presets have it.
  """
  if name not in PRESETS:
    raise UserError(f"--preset {name}: unknown preset (choose from {', '.join(PRESETS)})")
  # Photos without alpha (LLFF and users' captures) train as the reference trains LLFF.
  return override(_PRESETS[name](scene_format != "blender"), **overrides)


TRUNKS = ("mlp", "hash")
SAMPLERS = ("hierarchical", "grid")
