"""Benchmarks AdaIN: stylizing one image (after compilation) and decoder training throughput.

  python experiments/benchmarks/bench_adain.py               # 400x400 stylize + 256x256 training
  taskset -c 0 python experiments/benchmarks/bench_adain.py  # pinned to one core
  python experiments/benchmarks/bench_adain.py --decoder /work/runs/adain_cpu2   # a trained decoder

Prints seconds per stylized image (median of --repeats, compilation excluded) for
(a) the full path (encode content and style, AdaIN, decode) and (b) a style given by its
precomputed relu4_1 statistics (the NeRF case: one style, many views), and training images/s.
For (b) it also prints the FLOPs of one stylization (VGG16 to relu4_1 on the content + the
decoder; counted from the layer shapes, and as XLA counts the compiled program), the implied
GFLOP/s, and this machine's float32 matmul rate measured just before, so that the time can be
compared with what the hardware can do at all.
"""

import argparse
import os
import platform
import time

import jax
import jax.numpy as jnp
import numpy as np

from msnerf_jax.core import config as config_lib
from msnerf_jax.core.parallel import data_parallel
from msnerf_jax.kinds import stylized_scenes
from msnerf_jax.style import transfer as stylize_lib
from msnerf_jax.models import decoder as decoder_lib
from msnerf_jax.models import vgg
from msnerf_jax.train import adain as train_adain
from common import call_times


def timed(fn, repeats):
  """Median and best wall time of fn() after a warm-up call (compilation)."""
  times = call_times(fn, repeats)
  return float(np.median(times)), float(np.min(times))


def conv_flops(h: int, w: int) -> dict:
  """Multiply-add FLOPs (2 per MAC) of one stylization of an h x w image with known style stats.

  encoder: the 8 VGG16 convs to relu4_1 on the content; decoder: its 9 convs as in the
  reference architecture (3x3 conv after each x2 nearest upsampling); decoder_fused: what our
  decoder executes (the 3 convs after an upsampling are 2x2 convs of 4x the output channels on
  the low-resolution map: 16/36 of their reference FLOPs). Bias, ReLU, pooling, padding and
  AdaIN are < 0.5% and not counted.
  """
  enc, cin, scale = 0, 3, 1
  for v in vgg.VGG16_TO_RELU4_1:
    if v == "M":
      scale *= 2
      continue
    enc += 2 * 9 * cin * v * (h // scale) * (w // scale)
    cin = v
  dec = dec_fused = 0
  cin, upsampled = 512, False
  for v in decoder_lib.DECODER_LAYOUT:
    if v == "U":
      scale //= 2
      upsampled = True
      continue
    f = 2 * 9 * cin * v * (h // scale) * (w // scale)
    dec += f
    dec_fused += f * 16 // 36 if upsampled else f
    cin, upsampled = v, False
  return {"encoder": enc, "decoder": dec, "decoder_fused": dec_fused}


def matmul_gflops(n: int = 2048, repeats: int = 5) -> float:
  """float32 [n, n] @ [n, n] rate of this machine (best of `repeats`), GFLOP/s."""
  a = jnp.asarray(np.random.default_rng(0).random((n, n), np.float32))
  f = jax.jit(lambda x: x @ x)
  best = min(call_times(lambda: f(a), repeats))
  return 2 * n ** 3 / best / 1e9


def cpu_name():
  try:
    for line in open("/proc/cpuinfo"):
      if line.startswith("model name"):
        return line.split(":", 1)[1].strip()
  except OSError:
    pass
  return platform.processor()


def main():
  parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
  parser.add_argument("--size", type=int, default=400, help="side of the stylized image")
  parser.add_argument("--repeats", type=int, default=5)
  parser.add_argument("--decoder", help="trained run folder (default: random decoder weights)")
  parser.add_argument("--train-size", type=int, default=256, help="training crop side (0: skip)")
  parser.add_argument("--train-batch", type=int, default=8)
  parser.add_argument("--train-steps", type=int, default=3, help="timed steps after compilation")
  args = parser.parse_args()

  affinity = len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else os.cpu_count()
  print(f"device: {jax.devices()[0].platform} ({jax.devices()[0].device_kind}); CPU {cpu_name()}, "
        f"{affinity} of {os.cpu_count()} cores usable; jax {jax.__version__}")
  enc = vgg.load_vgg_params()
  if args.decoder:
    dec = stylized_scenes.load_decoder(args.decoder)
    params, upsample = dec.params, dec.config.upsample
  else:
    params, upsample = decoder_lib.init_decoder(jax.random.PRNGKey(0)), "nearest"
  rng = np.random.default_rng(0)
  s = args.size
  content = jnp.asarray(rng.random((1, s, s, 3), np.float32))
  style = jnp.asarray(rng.random((1, s, s, 3), np.float32))
  weights = jnp.ones((1,), jnp.float32)

  full = jax.jit(stylize_lib.stylize_arrays, static_argnames=("upsample",))
  med, best = timed(lambda: full(params, enc, content, style, weights, 1.0, upsample=upsample),
                    args.repeats)
  print(f"stylize {s}x{s}, content + style encoded each call: median {med:.3f} s, best {best:.3f} s")
  mean, std = jax.jit(stylize_lib.style_stats_relu4_1)(enc, style)
  cached = jax.jit(stylize_lib.decode_with_stats, static_argnames=("upsample",))
  gflops = matmul_gflops()
  med, best = timed(lambda: cached(params, enc, content, mean, std, 1.0, upsample=upsample),
                    args.repeats)
  print(f"stylize {s}x{s}, style statistics precomputed:     median {med:.3f} s, best {best:.3f} s")
  flops = conv_flops(s, s)
  executed = flops["encoder"] + (flops["decoder_fused"] if upsample == "nearest" else flops["decoder"])
  reference = flops["encoder"] + flops["decoder"]
  try:
    xla = cached.lower(params, enc, content, mean, std, 1.0, upsample=upsample).compile().cost_analysis()
    xla = xla[0] if isinstance(xla, (list, tuple)) else xla
    xla_flops = float(xla.get("flops", 0.0))
  except Exception:  # pylint: disable=broad-except
    xla_flops = 0.0
  print(f"  FLOPs: encoder {flops['encoder'] / 1e9:.1f} G + decoder {flops['decoder'] / 1e9:.1f} G "
        f"= {reference / 1e9:.1f} GFLOP (reference layers); executed with the fused upsampling "
        f"convs: {executed / 1e9:.1f} GFLOP" + (f" (XLA cost analysis: {xla_flops / 1e9:.1f})" if xla_flops else ""))
  print(f"  implied rate: {executed / med / 1e9:.1f} GFLOP/s executed ({reference / med / 1e9:.1f} "
        f"reference-equivalent); float32 2048^3 matmul on this machine now: {gflops:.1f} GFLOP/s")
  print(f"  lower bound at the matmul rate: {executed / gflops / 1e9:.2f} s per image "
        f"(target 1 s needs >= {executed / 1e9:.0f} GFLOP/s)")

  if args.train_size:
    config = config_lib.AdainConfig(size=args.train_size, batch=args.train_batch)
    step = train_adain.compile_train_step(config, data_parallel(1), enc)
    state = train_adain.new_state(decoder_lib.init_decoder(jax.random.PRNGKey(0)), config)
    x = rng.random((args.train_batch, args.train_size, args.train_size, 3)).astype(np.float32)
    y = rng.random((args.train_batch, args.train_size, args.train_size, 3)).astype(np.float32)
    t = time.perf_counter()
    state, m = step(state, (x, y, None, None))
    jax.block_until_ready(m)
    compile_s = time.perf_counter() - t
    t = time.perf_counter()
    for _ in range(args.train_steps):
      state, m = step(state, (x, y, None, None))
      jax.block_until_ready(m)
    dt = (time.perf_counter() - t) / args.train_steps
    print(f"train {args.train_size}x{args.train_size} (style weight {config.style_weight:g}), "
          f"batch {args.train_batch}: {dt:.2f} s/step, "
          f"{args.train_batch / dt:.2f} images/s (first step incl. compile {compile_s:.1f} s)")


if __name__ == "__main__":
  main()
