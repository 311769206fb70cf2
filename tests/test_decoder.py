"""AdaIN decoder (shapes, reflect padding, upsampling) and decoder training (loop, resume, NaN)."""

import dataclasses
import os

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from PIL import Image

from msnerf_jax.kinds import runs
from msnerf_jax.core import config as config_lib
from msnerf_jax.core.errors import UserError
from msnerf_jax.core.parallel import data_parallel
from msnerf_jax.models import decoder
from msnerf_jax.train import adain as train_adain
from msnerf_jax.train import adain_losses
from msnerf_jax.train import adain_data


def test_decoder_shapes_and_layers():
  params = decoder.init_decoder(jax.random.PRNGKey(0))
  kernels = [params["params"][f"conv{i}"]["Conv_0"]["kernel"].shape for i in range(9)]
  assert [k[2:] for k in kernels] == [(512, 256), (256, 256), (256, 256), (256, 256), (256, 128),
                                     (128, 128), (128, 64), (64, 64), (64, 3)]
  for mode in decoder.UPSAMPLE_MODES:  # shapes only: traced, not compiled (the values are
    # checked against the unfused path in test_fused_upsample_conv_equals_upsample_then_conv)
    out = jax.eval_shape(decoder.Decoder(mode).apply, params, jnp.ones((2, 3, 5, 512)))
    assert out.shape == (2, 24, 40, 3)
  with pytest.raises(AssertionError):
    decoder.Decoder().apply(params, jnp.ones((1, 4, 4, 256)))


def test_upsampling_modes():
  x = jnp.arange(4.0).reshape(1, 2, 2, 1)
  near = decoder.upsample2x(x, "nearest")
  np.testing.assert_array_equal(near[0, :, :, 0], [[0, 0, 1, 1], [0, 0, 1, 1], [2, 2, 3, 3], [2, 2, 3, 3]])
  row = decoder.upsample2x(jnp.array([0.0, 4.0]).reshape(1, 1, 2, 1), "bilinear")[0, 0, :, 0]
  # PyTorch bilinear, align_corners=False: [a, .75a + .25b, .25a + .75b, b].
  np.testing.assert_allclose(row, [0.0, 1.0, 3.0, 4.0], atol=1e-6)


def test_fused_upsample_conv_equals_upsample_then_conv():
  """The nearest-upsampling conv computed on the low-resolution map (4 phases of 2x2 taps)
  equals the 3x3 reflect-padded conv of the upsampled map, borders included."""
  x = jax.random.normal(jax.random.PRNGKey(5), (2, 3, 4, 6))
  kernel = jax.random.normal(jax.random.PRNGKey(6), (3, 3, 6, 5))
  bias = jax.random.normal(jax.random.PRNGKey(7), (5,))
  fused = decoder.upsample_nearest_reflect_conv3x3(x, kernel, bias)
  up = decoder.upsample2x(x, "nearest")
  padded = jnp.pad(up, ((0, 0), (1, 1), (1, 1), (0, 0)), mode="reflect")
  ref = jax.lax.conv_general_dilated(padded, kernel, (1, 1), "VALID",
                                     dimension_numbers=("NHWC", "HWIO", "NHWC")) + bias
  assert fused.shape == ref.shape == (2, 6, 8, 5)
  np.testing.assert_allclose(fused, ref, atol=1e-4)
  np.testing.assert_allclose(decoder.reflect_conv3x3(up, kernel, bias), ref, atol=1e-4)
  # The module fuses it when asked to upsample (nearest) before its conv.
  out = decoder.ReflectConv(5, upsample="nearest").apply(
      {"params": {"Conv_0": {"kernel": kernel, "bias": bias}}}, x)
  np.testing.assert_allclose(out, ref, atol=1e-4)


def test_reflect_padding():
  conv = decoder.ReflectConv(1)
  x = jax.random.normal(jax.random.PRNGKey(1), (1, 4, 5, 1))
  kernel = jnp.zeros((3, 3, 1, 1)).at[0, 0, 0, 0].set(1.0)  # picks the top-left neighbour
  out = conv.apply({"params": {"Conv_0": {"kernel": kernel, "bias": jnp.zeros(1)}}}, x)
  # Top-left output reads x[1, 1] (reflection of row/col -1), not a zero.
  np.testing.assert_allclose(out[0, 0, 0, 0], x[0, 1, 1, 0], atol=1e-6)
  np.testing.assert_allclose(out[0, 2, 3, 0], x[0, 1, 2, 0], atol=1e-6)


def _write_images(folder, n, rng, size=(40, 36)):
  os.makedirs(folder, exist_ok=True)
  modes = ["RGB", "L", "RGBA", "I;16"]
  for i in range(n):
    mode = modes[i % len(modes)]
    if mode == "I;16":
      image = Image.fromarray((rng.random(size[::-1]) * 65535).astype(np.uint16))
    else:
      image = Image.fromarray((rng.random(size[::-1] + (3,)) * 255).astype(np.uint8)).convert(mode)
    image.save(os.path.join(folder, f"img{i}.{'jpg' if mode in ('RGB', 'L') else 'png'}"))


TINY = config_lib.AdainConfig(size=32, resize=36, batch=2, steps=2, lr=1e-4, sample_every=2,
                              checkpoint_every=2, holdout_every=3)


@pytest.fixture()
def folders(tmp_path):
  rng = np.random.default_rng(0)
  _write_images(str(tmp_path / "content"), 4, rng)
  _write_images(str(tmp_path / "styles"), 3, rng, size=(30, 50))
  return str(tmp_path / "content"), str(tmp_path / "styles")


def test_train_writes_checkpoints_samples_and_resumes(tmp_path, folders):
  content, styles = folders
  run = str(tmp_path / "run")
  result = train_adain.train(TINY, [content], styles, run, progress=False, log=lambda *_: None)
  assert result.step == 2 and np.isfinite(result.metrics["loss"])
  assert os.path.exists(os.path.join(run, "samples", "step_0000002.png"))
  grid = np.asarray(Image.open(os.path.join(run, "samples", "step_0000002.png")))
  assert grid.shape == (2 * 32 + 4, 3 * 32 + 8, 3)
  held = open(os.path.join(run, "holdout.txt")).read().split()
  assert [os.path.basename(p) for p in held] == ["img2.png"]
  loaded = runs.load_run(run)
  assert loaded.kind == "adain" and loaded.step == 2
  assert loaded.config == TINY
  before = loaded.params["params"]
  # Resume: more steps continue from step 2.
  longer = config_lib.AdainConfig(**{**config_lib.to_dict(TINY), "steps": 3})
  result = train_adain.train(longer, [content], styles, run, progress=False, log=lambda *_: None)
  assert result.step == 3
  after = runs.load_run(run)
  assert after.step == 3
  assert not np.allclose(before["conv0"]["Conv_0"]["kernel"], after.params["params"]["conv0"]["Conv_0"]["kernel"])
  # Another config in the same folder is refused, checkpoints untouched.
  with pytest.raises(UserError, match="another config"):
    train_adain.train(config_lib.AdainConfig(**{**config_lib.to_dict(TINY), "size": 24}),
                      [content], styles, run, progress=False, log=lambda *_: None)
  assert runs.load_run(run).step == 3


def test_nan_loss_stops_and_keeps_last_good_checkpoint(tmp_path, folders, monkeypatch):
  content, styles = folders
  run = str(tmp_path / "run")
  train_adain.train(TINY, [content], styles, run, progress=False, log=lambda *_: None)
  real = train_adain.compile_train_step

  def nan_step(*args):
    step = real(*args)  # the compiled step, with its loss turned into NaN

    def run_step(state, batch):
      state, metrics = step(state, batch)
      return state, {k: v * jnp.nan for k, v in metrics.items()}
    return run_step

  monkeypatch.setattr(train_adain, "compile_train_step", nan_step)
  longer = config_lib.AdainConfig(**{**config_lib.to_dict(TINY), "steps": 4})
  with pytest.raises(UserError, match=r"step 3: loss is nan.*last good checkpoint: step 2"):
    train_adain.train(longer, [content], styles, run, progress=False, log=lambda *_: None)
  assert runs.load_run(run).step == 2


def test_training_reduces_loss():
  """A few Adam steps on one fixed batch lower the AdaIN loss (the gradient is right)."""
  from msnerf_jax.models import vgg  # pylint: disable=g-import-not-at-top
  config = TINY
  enc = vgg.load_vgg_params()
  state = train_adain.new_state(decoder.init_decoder(jax.random.PRNGKey(0)), config)
  step = train_adain.compile_train_step(config, data_parallel(1), enc)
  rng = np.random.default_rng(1)
  content = rng.random((2, 32, 32, 3)).astype(np.float32)
  style = (rng.random((2, 32, 32, 3)) ** 2).astype(np.float32)
  losses = []
  for _ in range(8):
    state, m = step(state, (content, style, None, None))
    losses.append(float(m["loss"]))
  assert max(losses[-3:]) < 0.7 * losses[0], losses


def test_crops_flips_and_holdout_split():
  image = np.arange(10 * 12 * 3, dtype=np.uint8).reshape(10, 12, 3)
  batch = adain_data.random_crops(np.random.default_rng(0), [[image]], 16, 8)
  assert batch.shape == (16, 8, 8, 3) and batch.dtype == np.float32
  assert batch.max() <= 1.0
  assert adain_data.split_holdout(list("abcdefg"), 3) == (list("abdeg"), list("cf"))
  assert adain_data.split_holdout(list("ab"), 0) == (list("ab"), [])


def test_reflect_conv_equals_valid_conv_of_padded_input():
  x = jax.random.normal(jax.random.PRNGKey(2), (2, 6, 7, 4))
  kernel = jax.random.normal(jax.random.PRNGKey(3), (3, 3, 4, 5))
  bias = jax.random.normal(jax.random.PRNGKey(4), (5,))
  out = decoder.ReflectConv(5).apply({"params": {"Conv_0": {"kernel": kernel, "bias": bias}}}, x)
  padded = jnp.pad(x, ((0, 0), (1, 1), (1, 1), (0, 0)), mode="reflect")
  ref = jax.lax.conv_general_dilated(padded, kernel, (1, 1), "VALID",
                                     dimension_numbers=("NHWC", "HWIO", "NHWC")) + bias
  assert out.shape == (2, 6, 7, 5)
  np.testing.assert_allclose(out, ref, atol=1e-5)


# ----------------------------------------------------------------------------- shift consistency


def test_random_shifts_are_sub_cell_and_deterministic():
  shifts = adain_data.random_shifts(np.random.default_rng([3, 7]), 500)
  assert shifts.shape == (500, 2) and shifts.dtype == np.int32
  assert shifts.min() == 1 and shifts.max() == train_adain.CELL - 1  # never 0, never a cell.
  np.testing.assert_array_equal(shifts, adain_data.random_shifts(np.random.default_rng([3, 7]), 500))


def test_window_is_the_moved_crop():
  images = jnp.arange(2 * 10 * 12 * 3, dtype=jnp.float32).reshape(2, 10, 12, 3)
  corners = jnp.array([[1, 3], [4, 0]], jnp.int32)
  out = adain_losses.window(images, corners, 5)
  np.testing.assert_array_equal(out[0], images[0, 1:6, 3:8])
  np.testing.assert_array_equal(out[1], images[1, 4:9, 0:5])


def test_shift_loss_compares_the_moved_decode_with_the_same_window():
  """shift_loss against its definition written out with numpy slices, for two shifts."""
  from msnerf_jax.style import adain as adain_lib  # pylint: disable=g-import-not-at-top
  from msnerf_jax.models import vgg  # pylint: disable=g-import-not-at-top
  enc = vgg.load_vgg_params()
  params = decoder.init_decoder(jax.random.PRNGKey(0))
  rng = np.random.default_rng(2)
  content = rng.random((2, 40, 40, 3)).astype(np.float32)
  output = rng.random((2, 40, 40, 3)).astype(np.float32)
  mean = jnp.asarray(rng.random((2, 512)), jnp.float32)
  std = jnp.asarray(rng.random((2, 512)) + 0.5, jnp.float32)
  shifts = np.array([[1, 7], [5, 2]], np.int32)
  got = adain_losses.shift_loss(params, enc, content, output, mean, std, shifts, "nearest")
  side, margin = 40 - train_adain.CELL, adain_losses.SHIFT_MARGIN
  expected = []
  for b, (dy, dx) in enumerate(shifts):
    moved = content[b:b + 1, dy:dy + side, dx:dx + side]
    t = adain_lib.adain_from_stats(adain_lib.encode(enc, moved)["relu4_1"], mean[b:b + 1],
                                   std[b:b + 1])
    decoded = np.asarray(decoder.Decoder("nearest").apply(params, t))[0]
    same = output[b, dy:dy + side, dx:dx + side]
    inner = slice(margin, side - margin)
    expected.append(np.mean((decoded[inner, inner] - same[inner, inner]) ** 2))
  np.testing.assert_allclose(float(got), np.mean(expected), rtol=1e-4)


def test_resample_cells_is_bilinear_between_neighbouring_cells():
  """Written out per cell with numpy; a shift of 0 keeps the map, a whole cell moves it by one."""
  rng = np.random.default_rng(4)
  feats = rng.random((2, 4, 5, 3)).astype(np.float32)
  shifts = np.array([[3, 6], [0, 8]], np.int32)
  got = np.asarray(adain_losses.resample_cells(jnp.asarray(feats), jnp.asarray(shifts)))
  assert got.shape == (2, 3, 4, 3)
  for b, (dy, dx) in enumerate(shifts / train_adain.CELL):
    for i in range(3):
      for j in range(4):
        want = ((1 - dy) * (1 - dx) * feats[b, i, j] + (1 - dy) * dx * feats[b, i, j + 1]
                + dy * (1 - dx) * feats[b, i + 1, j] + dy * dx * feats[b, i + 1, j + 1])
        np.testing.assert_allclose(got[b, i, j], want, rtol=1e-6, atol=1e-7)
  np.testing.assert_array_equal(got[1], feats[1, :-1, 1:])  # (0, CELL): one cell to the left.


def test_shift_loss_of_features_decodes_the_resampled_map():
  """source="features": the crop's own map resampled by the shift is decoded and compared with
  the same window; the encoder is not run again (the content pixels do not matter)."""
  from msnerf_jax.models import vgg  # pylint: disable=g-import-not-at-top
  enc = vgg.load_vgg_params()
  params = decoder.init_decoder(jax.random.PRNGKey(0))
  rng = np.random.default_rng(3)
  content = rng.random((2, 40, 40, 3)).astype(np.float32)
  output = rng.random((2, 40, 40, 3)).astype(np.float32)
  target = rng.normal(size=(2, 5, 5, 512)).astype(np.float32)
  mean, std = jnp.zeros((2, 512)), jnp.ones((2, 512))
  shifts = np.array([[2, 5], [7, 1]], np.int32)
  got = adain_losses.shift_loss(params, enc, content, output, mean, std, shifts, "nearest",
                               "features", target)
  again = adain_losses.shift_loss(params, enc, np.zeros_like(content), output, mean, std, shifts,
                                 "nearest", "features", target)
  np.testing.assert_allclose(float(got), float(again), rtol=1e-6)
  side, margin = 40 - train_adain.CELL, adain_losses.SHIFT_MARGIN
  inner = slice(margin, side - margin)
  moved = adain_losses.resample_cells(jnp.asarray(target), jnp.asarray(shifts))
  decoded = np.asarray(decoder.Decoder("nearest").apply(params, moved))
  expected = [np.mean((decoded[b][inner, inner]
                       - output[b, dy:dy + side, dx:dx + side][inner, inner]) ** 2)
              for b, (dy, dx) in enumerate(shifts)]
  np.testing.assert_allclose(float(got), np.mean(expected), rtol=1e-4)
  photo = adain_losses.shift_loss(params, enc, content, output, mean, std, shifts, "nearest")
  assert abs(float(photo) - float(got)) > 1e-3 * float(got)  # the two sources differ.


def test_shift_weight_adds_the_loss_and_its_gradient_lowers_it():
  """With only the shift term weighted, a few Adam steps on one batch lower it; with weight 0
  the loss is the paper's (no "shift" entry, the same total)."""
  from msnerf_jax.models import vgg  # pylint: disable=g-import-not-at-top
  enc = vgg.load_vgg_params()
  params = decoder.init_decoder(jax.random.PRNGKey(0))
  rng = np.random.default_rng(1)
  content = rng.random((2, 32, 32, 3)).astype(np.float32)
  style = (rng.random((2, 32, 32, 3)) ** 2).astype(np.float32)
  shifts = np.array([[3, 4], [7, 1]], np.int32)
  losses = jax.jit(adain_losses.losses, static_argnums=4)  # one compile, not one per op
  plain = dataclasses.replace(TINY, shift_weight=0.0)
  total, metrics = losses(params, enc, content, style, plain, shifts)
  assert "shift" not in metrics
  with_shift = dataclasses.replace(TINY, shift_weight=2.0)
  total2, metrics2 = losses(params, enc, content, style, with_shift, shifts)
  np.testing.assert_allclose(float(total2), float(total) + 2.0 * float(metrics2["shift"]),
                             rtol=1e-5)
  for source in config_lib.SHIFT_SOURCES:
    only_shift = dataclasses.replace(TINY, content_weight=0.0, style_weight=0.0, shift_weight=1.0,
                                     shift_source=source)
    # The step donates its inputs: a copy of the params.
    state = train_adain.new_state(jax.tree_util.tree_map(jnp.copy, params), only_shift)
    step = train_adain.compile_train_step(only_shift, data_parallel(1), enc)
    values = []
    for _ in range(6):
      state, m = step(state, (content, style, shifts, None))
      values.append(float(m["shift"]))
    assert values[-1] < 0.7 * values[0], (source, values)


def test_init_from_starts_from_that_decoder_and_checks_it(tmp_path, folders):
  content, styles = folders
  source = str(tmp_path / "source")
  train_adain.train(TINY, [content], styles, source, progress=False, log=lambda *_: None)
  trained = runs.load_run(source).params
  tuned = dataclasses.replace(TINY, init_from=source, shift_weight=1.0)
  start = train_adain.initial_decoder(tuned)
  jax.tree_util.tree_map(np.testing.assert_array_equal, start, trained)
  # A resumed run restores its own checkpoint: the init is only the structure.
  fresh = train_adain.initial_decoder(tuned, resuming=True)
  assert jax.tree_util.tree_structure(fresh) == jax.tree_util.tree_structure(trained)
  # A bilinear decoder may start from it (same parameters, another upsampling).
  bilinear = train_adain.initial_decoder(dataclasses.replace(tuned, upsample="bilinear"))
  jax.tree_util.tree_map(np.testing.assert_array_equal, bilinear, trained)
  # A decoder of another encoder cannot; nothing of the new run is written.
  other = dataclasses.replace(tuned, encoder="vgg19")
  run = str(tmp_path / "tuned")
  with pytest.raises(UserError, match=r"source/run.json: decoder made with encoder 'vgg16"):
    train_adain.train(other, [content], styles, run, progress=False, log=lambda *_: None)
  assert not os.path.exists(run)
  # Fine-tuning trains from there and records the shift loss.
  result = train_adain.train(tuned, [content], styles, run, progress=False, log=lambda *_: None)
  assert result.step == TINY.steps and np.isfinite(result.metrics["shift"])


@pytest.mark.parametrize("weight, size, needle", [
    (-1.0, 32, "--shift-weight -1.0"),
    (float("nan"), 32, "--shift-weight nan"),
    (1.0, 24, "--size 24: the shift loss needs crops of at least 32 pixels"),
])
def test_bad_shift_settings_are_refused_before_writing(tmp_path, folders, weight, size, needle):
  content, styles = folders
  run = str(tmp_path / "run")
  config = dataclasses.replace(TINY, shift_weight=weight, size=size, resize=size + 4)
  with pytest.raises(UserError) as info:
    train_adain.train(config, [content], styles, run, progress=False, log=lambda *_: None)
  assert needle in str(info.value)
  assert not os.path.exists(run)


def test_device_rows_give_each_device_its_photos_and_feature_crops_styles():
  """Split into consecutive blocks, each device's style rows are its photos' styles, then its
  feature crops' (as `losses` reads them); one device keeps the batch as it is."""
  content = np.arange(4)[:, None] * np.ones((4, 3))  # photos 0..3
  features = 10 + np.arange(2)[:, None] * np.ones((2, 5))  # feature crops 10, 11
  style = np.concatenate([content[:, 0], features[:, 0]])  # style row i belongs to crop i
  shifts = np.stack([style, -style], 1)
  batch = (content, style, shifts, features)
  assert train_adain.device_rows(batch, 1) is batch
  c, s, sh, f = train_adain.device_rows(batch, 2)
  for d in range(2):
    mine = np.concatenate([np.split(c, 2)[d][:, 0], np.split(f, 2)[d][:, 0]])
    np.testing.assert_array_equal(np.split(s, 2)[d], mine)
    np.testing.assert_array_equal(np.split(sh, 2)[d][:, 0], mine)
  no_features = train_adain.device_rows((content, style[:4], shifts[:4], None), 2)
  np.testing.assert_array_equal(no_features[1], style[:4])


TWO_DEVICES = """
import os, sys
os.environ["XLA_FLAGS"] = (os.environ.get("XLA_FLAGS", "")
                           + " --xla_force_host_platform_device_count=2")
import jax, numpy as np
from msnerf_jax import cli
from msnerf_jax.core import config as config_lib
from msnerf_jax.core.parallel import data_parallel
from msnerf_jax.kinds import runs
from msnerf_jax.models import decoder, vgg
from msnerf_jax.train import adain as train_adain
assert jax.local_device_count() == 2
content, styles, out = sys.argv[1:4]
# One step on the same batch. Each device takes one image, so the two devices' gradient (Adam's
# first moment after one step is (1 - b1) times the gradient) and losses are the mean of one
# device's on each image alone, to float32 rounding; the whole batch on one device sums in
# another order, which this loss's float32 gradient feels at ~1% (in float64 the three agree
# to 1e-12).
config = config_lib.AdainConfig(size=32, resize=36, batch=2)  # the command line's below
rng = np.random.default_rng(0)
batch = (rng.random((2, 32, 32, 3), np.float32), rng.random((2, 32, 32, 3), np.float32),
         np.array([[3, 4], [7, 1]], np.int32), None)
enc = vgg.load_vgg_params()
params = jax.tree_util.tree_map(np.asarray, decoder.init_decoder(jax.random.PRNGKey(0)))

def one_step(n, rows):
  dp = data_parallel(n)
  step = train_adain.compile_train_step(config, dp, enc)
  part = jax.tree_util.tree_map(lambda x: x[rows], batch)
  state, stats = step(dp.put_state(train_adain.new_state(params, config)),
                      dp.put_batch(train_adain.device_rows(part, n)))
  return dp.to_host((state.opt_state[0].mu, stats))

mean = lambda trees: jax.tree_util.tree_map(lambda *x: sum(x) / len(x), *trees)
alone = mean([one_step(1, slice(i, i + 1)) for i in range(2)])
two, whole = one_step(2, slice(0, 2)), one_step(1, slice(0, 2))
leaves = jax.tree_util.tree_leaves
worst = lambda a, b: max(float(np.abs(x - y).max()) for x, y in zip(leaves(a), leaves(b)))
scale = max(float(np.abs(x).max()) for x in leaves(alone[0]))
print("two vs alone", worst(two[0], alone[0]), "whole vs alone", worst(whole[0], alone[0]),
      "scale", scale)
assert scale > 0 and worst(two[0], alone[0]) < 1e-5 * scale
assert worst(whole[0], alone[0]) < 3e-2 * scale
for k in alone[1]:
  assert abs(float(two[1][k]) - float(alone[1][k])) <= 1e-5 * abs(float(alone[1][k])), k
  assert abs(float(whole[1][k]) - float(alone[1][k])) <= 1e-4 * abs(float(alone[1][k])), k
# The command line trains on both devices through the shared loop.
run = os.path.join(out, "run")
assert cli.main(["adain", "train", "--content", content, "--styles", styles, "--out", run,
                 "--size", "32", "--resize", "36", "--batch", "2", "--steps", "2",
                 "--sample-every", "2", "--checkpoint-every", "2", "--devices", "2",
                 "--no-progress"]) == 0
assert runs.load_run(run).step == 2
assert os.path.exists(os.path.join(run, "samples", "step_0000002.png"))
"""


@pytest.mark.slow  # 35 s; the NeRF trainer's two-device test stays in the default suite
def test_two_devices_train_the_decoder_as_one(tmp_path, folders):
  import subprocess  # pylint: disable=g-import-not-at-top
  import sys  # pylint: disable=g-import-not-at-top
  content, styles = folders
  result = subprocess.run([sys.executable, "-c", TWO_DEVICES, content, styles, str(tmp_path)],
                          capture_output=True, text=True, timeout=600)
  assert result.returncode == 0, result.stderr[-3000:]


def test_a_batch_that_does_not_split_over_the_devices_is_refused():
  class Three:  # a DataParallel's size is all check_devices reads
    size = 3
  with pytest.raises(UserError, match=r"--batch 2: must be a multiple of the 3 devices"):
    train_adain.check_devices(TINY, Three())

