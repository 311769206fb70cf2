"""Every config checks itself: `validate()` is the one place a config's values are refused,
each with one line `--OPTION VALUE: problem`. A table walks every field of every config
with one bad value (or names it among the fields that take any value)."""

import dataclasses

import pytest

from msnerf_jax.core.config import (AdainConfig, DataConfig, FeatureConfig, MultistyleConfig,
                                    NerfConfig, PaintConfig, flat_fields, override)
from msnerf_jax.core.errors import UserError

GRID = {"sampler": "grid"}
HASH = {"trunk": "hash"}
DECODE = {"decode_weight": 1.0}
STYLE_LOSS = {"style_weight": 1.0}

# (config class, settings the bad value needs to matter, field, bad value, option named).
BAD = [
    (NerfConfig, {}, "trunk", "cnn", "--trunk cnn"),
    (NerfConfig, {}, "net_depth", 0, "--net-depth 0"),
    (NerfConfig, {}, "net_width", 0, "--net-width 0"),
    (NerfConfig, {}, "pos_freqs", -1, "--pos-freqs -1"),
    (NerfConfig, {}, "dir_freqs", -1, "--dir-freqs -1"),
    (NerfConfig, HASH, "hash_levels", 0, "--hash-levels 0"),
    (NerfConfig, HASH, "hash_features", 0, "--hash-features 0"),
    (NerfConfig, HASH, "hash_table_size", 1000, "--hash-table-size 1000"),
    (NerfConfig, HASH, "hash_min_res", 0, "--hash-min-res 0"),
    (NerfConfig, HASH, "hash_max_res", 8, "--hash-max-res 8"),
    (NerfConfig, {}, "sampler", "uniform", "--sampler uniform"),
    (NerfConfig, {}, "n_coarse", 0, "--n-coarse 0"),
    (NerfConfig, {}, "n_fine", 0, "--n-fine 0"),
    (NerfConfig, {}, "scene_box", -1.0, "--scene-box -1.0"),
    (NerfConfig, GRID, "grid_resolution", 0, "--grid-resolution 0"),
    (NerfConfig, GRID, "march_steps", 0, "--march-steps 0"),
    (NerfConfig, GRID, "march_segments", 0, "--march-segments 0"),
    (NerfConfig, GRID, "samples_per_ray", 0, "--samples-per-ray 0"),
    (NerfConfig, GRID, "grid_every", 0, "--grid-every 0"),
    (NerfConfig, GRID, "grid_warmup", -1, "--grid-warmup -1"),
    (NerfConfig, GRID, "grid_decay", 1.5, "--grid-decay 1.5"),
    (NerfConfig, GRID, "grid_threshold", -0.1, "--grid-threshold -0.1"),
    (NerfConfig, {}, "raw_noise_std", -1.0, "--raw-noise-std -1.0"),
    (NerfConfig, {}, "batch_rays", 0, "--batch-rays 0"),
    (NerfConfig, {}, "steps", 0, "--steps 0"),
    (NerfConfig, {}, "lr_init", 0.0, "--lr-init 0.0"),
    (NerfConfig, {}, "lr_final", float("nan"), "--lr-final nan"),
    (NerfConfig, {}, "lr_decay_steps", 0, "--lr-decay-steps 0"),
    (NerfConfig, {}, "precrop_steps", -1, "--precrop-steps -1"),
    (NerfConfig, {}, "precrop_frac", 0.0, "--precrop-frac 0.0"),
    (NerfConfig, {}, "distortion_weight", -1.0, "--distortion-weight -1.0"),
    (NerfConfig, {}, "checkpoint_every", 0, "--checkpoint-every 0"),
    (NerfConfig, {}, "keep_checkpoints", 0, "--keep-checkpoints 0"),
    (NerfConfig, {}, "render_chunk", 0, "--render-chunk 0"),
    (NerfConfig, {}, "mlp_chunk", -1, "--mlp-chunk -1"),
    (DataConfig, {}, "llff_holdout", 0, "--llff-holdout 0"),
    (AdainConfig, {}, "size", 20, "--size 20"),
    (AdainConfig, {}, "resize", 8, "--resize 8"),
    (AdainConfig, {}, "batch", 0, "--batch 0"),
    (AdainConfig, {}, "steps", 0, "--steps 0"),
    (AdainConfig, {}, "lr", -1.0, "--lr -1.0"),
    (AdainConfig, {}, "lr_decay", -1.0, "--lr-decay -1.0"),
    (AdainConfig, {}, "content_weight", float("inf"), "--content-weight inf"),
    (AdainConfig, {}, "style_weight", -1.0, "--style-weight -1.0"),
    (AdainConfig, {}, "upsample", "cubic", "--upsample cubic"),
    (AdainConfig, {}, "holdout_every", -1, "--holdout-every -1"),
    (AdainConfig, {}, "sample_every", 0, "--sample-every 0"),
    (AdainConfig, {}, "checkpoint_every", 0, "--checkpoint-every 0"),
    (AdainConfig, {}, "keep_checkpoints", 0, "--keep-checkpoints 0"),
    (AdainConfig, {}, "shift_weight", -1.0, "--shift-weight -1.0"),
    (AdainConfig, {}, "shift_source", "video", "--shift-source video"),
    (AdainConfig, {"content_features": "run"}, "feature_share", 0.0, "--feature-share 0.0"),
    (MultistyleConfig, {}, "style_dim", 0, "--style-dim 0"),
    (MultistyleConfig, {}, "style_hidden", 0, "--style-hidden 0"),
    (MultistyleConfig, {}, "style_hidden2", 0, "--style-hidden2 0"),
    (MultistyleConfig, {}, "rgb_extra_layers", -1, "--rgb-extra-layers -1"),
    (MultistyleConfig, {}, "density_extra_layers", -1, "--density-extra-layers -1"),
    (MultistyleConfig, {}, "batch_rays", 0, "--batch-rays 0"),
    (MultistyleConfig, {}, "style_weight", -1.0, "--style-weight -1.0"),
    (MultistyleConfig, STYLE_LOSS, "style_patch", 8, "--style-patch 8"),
    (MultistyleConfig, STYLE_LOSS, "style_patches", 0, "--style-patches 0"),
    (MultistyleConfig, {}, "steps", 0, "--steps 0"),
    (MultistyleConfig, {}, "lr_init", 0.0, "--lr 0.0"),
    (MultistyleConfig, {}, "lr_final", -1.0, "--lr-final -1.0"),
    (MultistyleConfig, {}, "lr_decay_steps", 0, "--lr-decay-steps 0"),
    (MultistyleConfig, {}, "checkpoint_every", 0, "--checkpoint-every 0"),
    (MultistyleConfig, {}, "keep_checkpoints", 0, "--keep-checkpoints 0"),
    (FeatureConfig, {}, "scene_box", -1.0, "--scene-box -1.0"),
    (FeatureConfig, {}, "dim", 0, "--dim 0"),
    (FeatureConfig, {}, "width", -1, "--width -1"),
    (FeatureConfig, {}, "hash_levels", 0, "--hash-levels 0"),
    (FeatureConfig, {}, "hash_features", 0, "--hash-features 0"),
    (FeatureConfig, {}, "hash_table_size", 3, "--hash-table-size 3"),
    (FeatureConfig, {}, "hash_min_res", 0, "--hash-min-res 0"),
    (FeatureConfig, {}, "hash_max_res", 4, "--hash-max-res 4"),
    (FeatureConfig, {}, "top_k", 0, "--top-k 0"),
    (FeatureConfig, {}, "stylize_scale", 0, "--stylize-scale 0"),
    (FeatureConfig, {}, "rays_per_cell", 0, "--rays-per-cell 0"),
    (FeatureConfig, {}, "batch_cells", 0, "--batch-cells 0"),
    (FeatureConfig, {}, "loss", "huber", "--loss huber"),
    (FeatureConfig, {}, "decode_weight", -1.0, "--decode-weight -1.0"),
    (FeatureConfig, DECODE, "decode_target", "both", "--decode-target both"),
    (FeatureConfig, DECODE, "decode_patches", 0, "--decode-patches 0"),
    (FeatureConfig, DECODE, "decode_cells", 2, "--decode-cells 2"),
    (FeatureConfig, {}, "steps", 0, "--steps 0"),
    (FeatureConfig, {}, "lr_init", 0.0, "--lr 0.0"),
    (FeatureConfig, {}, "lr_final", 0.0, "--lr-final 0.0"),
    (FeatureConfig, {}, "lr_decay_steps", 0, "--lr-decay-steps 0"),
    (FeatureConfig, {}, "checkpoint_every", 0, "--checkpoint-every 0"),
    (FeatureConfig, {}, "keep_checkpoints", 0, "--keep-checkpoints 0"),
    (PaintConfig, {}, "scene_box", -1.0, "--scene-box -1.0"),
    (PaintConfig, {}, "resolution", 1, "--resolution 1"),
    (PaintConfig, {}, "style_loss", "gram", "--style-loss gram"),
    (PaintConfig, {}, "style_weight", -1.0, "--style-weight -1.0"),
    (PaintConfig, {}, "content_weight", float("nan"), "--content-weight nan"),
    (PaintConfig, {}, "tv_weight", float("inf"), "--tv-weight inf"),
    (PaintConfig, {}, "style_size", 8, "--style-size 8"),
    (PaintConfig, {}, "init_steps", -1, "--init-steps -1"),
    (PaintConfig, {}, "path_views", -1, "--path-views -1"),
    (PaintConfig, {}, "steps", 0, "--steps 0"),
    (PaintConfig, {}, "views_per_style", 0, "--views-per-style 0"),
    (PaintConfig, {}, "crop", 16, "--crop 16"),
    (PaintConfig, {}, "cache_threshold", 1.0, "--cache-threshold 1.0"),
    (PaintConfig, {}, "top_k", 0, "--top-k 0"),
    (PaintConfig, {}, "lr_init", 0.0, "--lr 0.0"),
    (PaintConfig, {}, "lr_final", -1.0, "--lr-final -1.0"),
    (PaintConfig, {}, "lr_decay_steps", 0, "--lr-decay-steps 0"),
    (PaintConfig, {}, "checkpoint_every", 0, "--checkpoint-every 0"),
    (PaintConfig, {}, "keep_checkpoints", 0, "--keep-checkpoints 0"),
]

# Fields any value of their type suits (or checked where the value is used, named there).
FREE = {
    NerfConfig: {"skip_layer", "lindisp", "perturb", "random_background", "seed"},
    DataConfig: {"path", "format", "layout", "downscale"},  # the scene loaders check them.
    AdainConfig: {"seed", "encoder", "init_from", "content_features"},  # run folders: loaders.
    MultistyleConfig: {"nerf", "density_aware", "normalize_styles", "seed"},
    FeatureConfig: {"nerf", "seed"},
    PaintConfig: {"nerf", "seed", "colour_transfer"},
}


@pytest.mark.parametrize("cls", list(FREE))
def test_the_table_walks_every_field(cls):
  walked = {field for c, _, field, _, _ in BAD if c is cls}
  assert walked | FREE[cls] == {f.name for _, f in flat_fields(cls)} | {
      f.name for f in dataclasses.fields(cls) if f.name == "nerf"}
  assert not walked & FREE[cls]


@pytest.mark.parametrize("cls", list(FREE))
def test_the_defaults_are_valid(cls):
  assert cls().validate() == cls()


@pytest.mark.parametrize("cls, needs, field, value, option",
                         BAD, ids=[f"{c.__name__}.{f}" for c, _, f, _, _ in BAD])
def test_a_bad_value_is_refused_naming_its_option(cls, needs, field, value, option):
  good = override(cls(), **needs)
  assert good.validate() == good  # the bad value, not its context, is refused
  with pytest.raises(UserError) as error:
    override(good, **{field: value}).validate()
  message = str(error.value)
  assert message.startswith(option + ": ") and "\n" not in message, message
