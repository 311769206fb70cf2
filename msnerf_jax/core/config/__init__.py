"""Frozen configuration dataclasses, each with `validate()` (the one place its values are
refused), the NeRF presets, and their JSON round trip: `msnerf_jax.core.config.NerfConfig`
and so on, whichever module of this package defines it."""

from msnerf_jax.core.config.base import (NAMED_FIRST, bad_setting, check_at_least,
                                         check_hash_settings, check_positive, diff, flat_fields,
                                         from_dict, help_of, nested_class, override, setting,
                                         setting_of, to_dict)
from msnerf_jax.core.config.optim import OptimConfig, optimisation
from msnerf_jax.core.config.nerf import (DEFAULT_PRESET, PRESETS, SAMPLERS, TRUNKS, DataConfig,
                                         NerfConfig, nerf_preset)
from msnerf_jax.core.config.paint import MIN_CROP, PAINT_LOSSES, PaintConfig
from msnerf_jax.core.config.style import (DECODE_TARGETS, FEATURE_LOSSES, SHIFT_MIN_SIZE,
                                          SHIFT_SOURCES, UPSAMPLE_MODES, AdainConfig,
                                          FeatureConfig, MultistyleConfig)

__all__ = ["NAMED_FIRST", "bad_setting", "check_at_least", "check_hash_settings",
           "check_positive", "diff", "flat_fields", "from_dict", "help_of", "nested_class",
           "override", "setting", "setting_of", "to_dict", "OptimConfig", "optimisation",
           "DEFAULT_PRESET", "PRESETS",
           "SAMPLERS", "TRUNKS", "DataConfig", "NerfConfig", "nerf_preset", "DECODE_TARGETS",
           "FEATURE_LOSSES", "SHIFT_MIN_SIZE", "SHIFT_SOURCES", "UPSAMPLE_MODES", "AdainConfig",
           "FeatureConfig", "MultistyleConfig", "MIN_CROP", "PAINT_LOSSES", "PaintConfig"]
