"""The scene and NeRF configs, and the NeRF presets (paper, cpu, fast)."""

import dataclasses
import functools
from typing import Any

from msnerf_jax.core.config.base import (bad_setting, check_at_least, check_hash_settings,
                                         check_positive, override)
from msnerf_jax.core.errors import UserError


@dataclasses.dataclass(frozen=True)
class DataConfig:
  """Which scene to load and how (saved with a run so eval/render reload the same views)."""
  path: str = ""
  format: str = "auto"  # "auto", "blender", "llff", "transforms" or "colmap".
  # 0 = format default (Blender 1, LLFF 8, captures: the smallest power of two that brings
  # the longer side to 400 px or less). LLFF and captures read images_{factor} when present.
  downscale: int = 0
  llff_holdout: int = 8  # LLFF, and captures without a split: every n-th image is held out.
  # Captures: "auto" (decided from the cameras), "forward-facing" (LLFF's recentring + NDC)
  # or "object" (centred on the point the cameras look at, bounds from the data).
  layout: str = "auto"

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
  trunk: str = "mlp"
  net_depth: int = 8
  net_width: int = 256
  skip_layer: int = 4  # the encoded input is concatenated to the output of this layer.
  pos_freqs: int = 10
  dir_freqs: int = 4
  hash_levels: int = 16
  hash_features: int = 2  # features per level.
  hash_table_size: int = 2 ** 17  # entries per level, a power of two.
  hash_min_res: int = 16  # coarsest grid resolution.
  hash_max_res: int = 512  # finest grid resolution.
  # Sampling: "hierarchical" (coarse and fine networks, n_coarse + n_fine samples per ray) or
  # "grid" (one network, samples only in the occupied cells of an occupancy grid; see
  # msnerf_jax/nerf/occupancy.py).
  sampler: str = "hierarchical"
  n_coarse: int = 64
  n_fine: int = 128
  scene_box: float = 0.0  # half side of the box centred at the origin (0 = from the scene).
  grid_resolution: int = 64  # cells per side of the occupancy grid.
  march_steps: int = 256  # candidate samples per ray across its stretch of the box.
  march_segments: int = 2  # rendering: rays stop after a segment once they are opaque.
  samples_per_ray: int = 32  # sample budget of a batch: this many per ray, shared.
  grid_every: int = 16  # training steps between refreshes of the grid.
  grid_warmup: int = 256  # steps during which every refresh visits every cell.
  grid_decay: float = 0.95  # known cells decay by this at each refresh.
  grid_threshold: float = 0.01  # a cell is occupied above this optical depth per step.
  lindisp: bool = False
  perturb: bool = True
  raw_noise_std: float = 0.0
  # Optimisation.
  batch_rays: int = 1024
  steps: int = 200_000
  lr_init: float = 5e-4
  lr_final: float = 5e-5
  lr_decay_steps: int = 250_000  # lr reaches lr_final after this many steps (exponential).
  precrop_steps: int = 500  # Blender: sample only the central crop at first (avoids an empty scene).
  precrop_frac: float = 0.5
  # Empty space. random_background (scenes with alpha, i.e. Blender RGBA): every training ray
  # gets a random background colour per step; its target is the photo composited over it by
  # the photo's alpha and its render is composited over the same colour, so only true
  # transparency reproduces every background (white fog no longer explains a white one).
  # Rendering and evaluation still composite over white. distortion_weight: weight of the
  # mip-NeRF 360 distortion loss on both levels' weights, or on the occupancy grid's packed
  # samples (discourages floaters; any scene).
  random_background: bool = False
  distortion_weight: float = 0.0
  # Bookkeeping.
  seed: int = 0
  checkpoint_every: int = 5000
  keep_checkpoints: int = 3
  render_chunk: int = 4096  # rays per jitted rendering call: bounds memory whatever the image size.
  mlp_chunk: int = 8192  # samples per MLP call inside a step (cache-sized matmuls; 0 = all).

  def validate(self) -> "NerfConfig":
    """The config itself, or UserError `--OPTION VALUE: problem` naming the first setting
    that cannot work: the one place a NerfConfig's values are refused."""
    check_at_least(self, ("steps", "net_depth", "net_width", "n_coarse", "n_fine", "batch_rays",
                          "checkpoint_every", "keep_checkpoints", "lr_decay_steps",
                          "render_chunk"))
    check_positive(self, ("lr_init", "lr_final"))
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
  return NerfConfig(
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
  return NerfConfig(
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
  return NerfConfig(
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
