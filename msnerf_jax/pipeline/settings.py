"""The pipeline's settings (the `msnerf pipeline` options), the configs each stage trains
with, the files the renders stage writes, and the cheap checks of every input before any
stage starts."""

import dataclasses
import os
from typing import Optional, Sequence

from msnerf_jax.core import config as config_lib
from msnerf_jax.core.errors import UserError


@dataclasses.dataclass(frozen=True)
class Settings:
  """Sizes and lengths of every stage (the `msnerf pipeline` options)."""
  downscale: int = 0  # scene image downscale (0 = the format's default).
  format: str = "auto"  # scene format (DataConfig.format).
  layout: str = "auto"  # capture layout (DataConfig.layout).
  adain_steps: int = 2000
  adain_size: int = 96  # side of the decoder's training crops (images are resized to it).
  adain_batch: int = 2
  adain_lr: float = 2e-4
  style_weight: float = 10.0
  # NeRF preset: `fast` (hash grid + occupancy grid) trains lego and fern to 5 dB more than
  # `cpu` in the same time and renders lego 6.6x faster, fern as fast (README, Benchmarks).
  preset: str = config_lib.DEFAULT_PRESET
  nerf_steps: int = 0  # 0 = the preset's.
  nerf_batch_rays: int = 0  # 0 = the preset's.
  ms_steps: int = 3000
  ms_batch_rays: int = 1024
  features_steps: int = 2000  # 0 = no feature field.
  features_batch_cells: int = 512
  paint_steps: int = 1000  # 0 = no painted run (`msnerf paint train`'s default length).
  paint_crop: int = 0  # the style loss's crops (0 = whole views; PaintConfig.crop).
  paint_path_views: int = 24  # render-path cameras painted too (PaintConfig).
  frames: int = 0  # frames of the videos (0 = the scene's whole render path).
  fps: int = 12
  grid_views: int = 4
  chunk: int = 0  # rays per rendering call (0 = the config's).
  seed: int = 0


def adain_config(s: Settings) -> config_lib.AdainConfig:
  return config_lib.AdainConfig(
      size=s.adain_size, resize=s.adain_size, batch=s.adain_batch, steps=s.adain_steps,
      lr=s.adain_lr, style_weight=s.style_weight, seed=s.seed,
      sample_every=max(1, min(500, s.adain_steps)),
      checkpoint_every=max(1, min(500, s.adain_steps)))


def nerf_config(s: Settings, scene_format: str) -> config_lib.NerfConfig:
  return config_lib.nerf_preset(s.preset, scene_format, steps=s.nerf_steps or None,
                                batch_rays=s.nerf_batch_rays or None, seed=s.seed,
                                checkpoint_every=min(500, s.nerf_steps) if s.nerf_steps else None)


def multistyle_config(s: Settings) -> config_lib.MultistyleConfig:
  return config_lib.override(config_lib.MultistyleConfig(), steps=s.ms_steps,
                             batch_rays=s.ms_batch_rays, seed=s.seed,
                             checkpoint_every=max(1, min(500, s.ms_steps)))


def feature_config(s: Settings) -> config_lib.FeatureConfig:
  return config_lib.override(config_lib.FeatureConfig(), steps=s.features_steps,
                             batch_cells=s.features_batch_cells,
                             lr_decay_steps=max(1, s.features_steps), seed=s.seed,
                             checkpoint_every=max(1, min(500, s.features_steps)))


def paint_config(s: Settings) -> config_lib.PaintConfig:
  return config_lib.override(config_lib.PaintConfig(), steps=s.paint_steps,
                             init_steps=min(100, s.paint_steps // 10),
                             lr_decay_steps=max(1, s.paint_steps), seed=s.seed,
                             checkpoint_every=max(1, min(250, s.paint_steps)),
                             crop=s.paint_crop, path_views=s.paint_path_views)


def check_inputs(data: str, styles: Sequence[str], out: str, decoder: Optional[str],
                 s: Settings) -> None:
  """Cheap checks of every input before any stage starts."""
  if not os.path.isdir(data):
    raise UserError(f"{data}: no such scene folder")
  if not styles:
    raise UserError("--styles: give at least one style image")
  for path in styles:
    if not os.path.isfile(path):
      raise UserError(f"{path}: no such style image")
  if os.path.exists(out) and not os.path.isdir(out):
    raise UserError(f"{out}: is a file, expected an output folder")
  if decoder is not None and not os.path.isfile(os.path.join(decoder, "run.json")):
    raise UserError(f"{decoder}: not an AdaIN run folder (no run.json)")
  if s.preset not in config_lib.PRESETS:
    raise UserError(f"--preset {s.preset}: choose from {', '.join(config_lib.PRESETS)}")
  for name in ("adain_steps", "ms_steps", "adain_batch", "ms_batch_rays", "fps", "grid_views",
               "features_batch_cells"):
    if getattr(s, name) < 1:
      raise UserError(f"--{name.replace('_', '-')} {getattr(s, name)}: must be >= 1")
  for name in ("nerf_steps", "nerf_batch_rays", "frames", "chunk", "downscale",
               "features_steps", "paint_steps", "paint_path_views"):
    if getattr(s, name) < 0:
      raise UserError(f"--{name.replace('_', '-')} {getattr(s, name)}: must be >= 0")
  if s.paint_crop and s.paint_crop < config_lib.MIN_CROP:
    raise UserError(f"--paint-crop {s.paint_crop}: must be 0 (whole views) or at least "
                    f"{config_lib.MIN_CROP}")
  if s.adain_size < 16 or s.adain_size % 8:
    raise UserError(f"--adain-size {s.adain_size}: must be a multiple of 8, at least 16")
