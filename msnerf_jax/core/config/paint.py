"""The painted-run config: colour fields per style on a NeRF run's frozen geometry,
optimised with a style loss on rendered views (`msnerf paint train`)."""

import dataclasses

from msnerf_jax.core.config.base import (bad_setting, check_at_least, check_non_negative,
                                         setting)
from msnerf_jax.core.config.nerf import NerfConfig
from msnerf_jax.core.config.optim import OptimConfig, optimisation

PAINT_LOSSES = ("nnfm", "adain")  # PaintConfig.style_loss.
MIN_CROP = 32  # PaintConfig.crop: VGG's relu3 needs 8x8.


@dataclasses.dataclass(frozen=True)
class PaintConfig:
  """Painted colour fields: one grid of colours per style over a NeRF run's frozen density
  (models/painted_field.py), fitted first to the photos colour-transferred to each style,
  then with a style loss on whole rendered training views (train/paint.py).

  `nerf` is the NeRF run's config; `scene_box` the half side of the box the grids cover and
  `resolution` their vertices a side (0 = fitted to what the painting's views see when
  training starts: train/paint_grid.py; the run's run.json holds the fitted values).
  """
  nerf: NerfConfig = dataclasses.field(default_factory=NerfConfig)
  scene_box: float = setting(0.0, "half side of the box the colour grids cover (0 = fitted "
                                  "to what the views see, at most the NeRF's)")
  resolution: int = setting(0, "colour grid vertices a side (0 = about a pixel apart on the "
                               "surfaces the views see, 128 to 256)")
  style_loss: str = setting("nnfm", "the style term: nnfm (ARF's nearest-neighbour feature "
                                    "matching on VGG16 relu3_1..3_3) or adain (the AdaIN "
                                    "statistics of relu1_1..4_1)")
  style_weight: float = setting(1.0, "weight of the style term")
  content_weight: float = setting(1e-3, "weight of the content term: MSE of relu3 features to "
                                        "the colour-transferred photo's")
  tv_weight: float = setting(0.1, "weight of the rendered image's total variation")
  colour_transfer: bool = setting(True, "move the photos' colours to each style's mean and "
                                        "covariance first (the init fit's and the content "
                                        "term's target)")
  style_size: int = setting(0, "style images are cover-cropped to this square first (0 = "
                               "the views' longer side, 32 to 256: the painting's strokes "
                               "at the scale per-frame AdaIN paints them on a view)")
  init_steps: int = setting(100, "first steps (of --steps): MSE to the colour-transferred "
                                 "photos")
  path_views: int = setting(24, "cameras along the scene's render path painted too (the "
                                "photo-real NeRF's renders stand in for their photos; 0 = "
                                "the training views alone)")
  views_per_style: int = setting(1, "training views rendered in each style per step")
  crop: int = setting(0, "the style loss sees a random crop of this many pixels a side of "
                         "each rendered view (0 = the whole view; for views too large for "
                         "VGG at every step, e.g. LLFF's 504x378)")
  cache_threshold: float = setting(1e-3, "samples whose weight is at most this are left out "
                                         "of the cached sample lists")
  top_k: int = setting(16, "the heaviest samples of each ray kept in the cached lists "
                           "(hierarchical NeRFs render with them too; with the grid sampler "
                           "they carry the weight of the ones left out)")
  optim: OptimConfig = optimisation(steps=1000, lr_init=0.05, lr_final=0.005,
                                    lr_decay_steps=1000, checkpoint_every=250,
                                    keep_checkpoints=2)

  def validate(self) -> "PaintConfig":
    """The config itself, or UserError `--OPTION VALUE: problem` naming the first setting
    that cannot work (the styles and the NeRF run are the trainer's checks)."""
    if self.scene_box < 0:
      bad_setting(self, "scene_box", "must be >= 0 (0 = fitted)")
    if self.resolution != 0 and self.resolution < 2:
      bad_setting(self, "resolution", "must be 0 (fitted) or at least 2")
    if self.style_loss not in PAINT_LOSSES:
      bad_setting(self, "style_loss", f"choose from {', '.join(PAINT_LOSSES)}")
    check_non_negative(self, ("style_weight", "content_weight", "tv_weight"))
    if self.style_size != 0 and self.style_size < 16:
      bad_setting(self, "style_size", "must be 0 (the views' longer side) or at least 16")
    check_at_least(self, ("init_steps", "path_views"), 0)
    check_at_least(self, ("views_per_style", "top_k"))
    if self.crop and self.crop < MIN_CROP:
      bad_setting(self, "crop", f"must be 0 (whole views) or at least {MIN_CROP} (VGG's relu3 "
                                "needs 8x8)")
    if not 0.0 <= self.cache_threshold < 1.0:
      bad_setting(self, "cache_threshold", "must be in [0, 1)")
    self.optim.validate("lr")
    return self
