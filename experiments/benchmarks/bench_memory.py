"""Peak memory (RSS) of rendering one image with the `paper` preset at 200x200, 400x400 and
800x800: it must not grow with resolution beyond the image-sized buffers themselves (rays in,
rgb/depth/disparity/accumulation out), because `render_image` feeds the network fixed-size
chunks of `render_chunk` rays.

Usage:
  python experiments/benchmarks/bench_memory.py [--sizes 200 400 800] [--max-chunks 2]
      [--chunk 4096]

Each size runs in a fresh process (peak RSS = resource.getrusage ru_maxrss) with random
parameters (memory does not depend on the weights). A full 800x800 `paper` render takes over
an hour on a 2-core CPU, so by default only the first `--max-chunks` chunks go through the
network; every later chunk returns a copy of the first chunk's output (same shapes, same
buffers), so the loop, the image-sized inputs and outputs and the per-chunk working set are
exactly those of a full render, without the compute. `--max-chunks 0` renders every chunk.
"""

import argparse
import json
import os
import subprocess
import sys

CHILD = r"""
import json, resource, sys, time
import jax, numpy as np
from msnerf_jax.nerf import rays as rays_lib
from msnerf_jax.nerf import render
from msnerf_jax.core.config import nerf_preset
from msnerf_jax.data.blender import pose_spherical
from msnerf_jax.models.nerf import NerfField, init_nerf_params

size, max_chunks, chunk = (int(a) for a in sys.argv[1:4])
mib = lambda: resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0
config = nerf_preset("paper", "blender")
params = init_nerf_params(config, jax.random.PRNGKey(0))
real, calls, first = render._render_chunk, [0], {}
def limited(*args, **kwargs):
  calls[0] += 1
  if max_chunks and calls[0] > max_chunks:
    return {k: np.copy(v) for k, v in first.items()}
  out = real(*args, **kwargs)
  first.update({k: np.asarray(v) for k, v in out.items()})
  return out
render._render_chunk = limited
before = mib()
focal = 0.5 * size / np.tan(0.5 * 0.6911112070083618)  # lego's camera_angle_x
K = np.array([[focal, 0, size / 2], [0, focal, size / 2], [0, 0, 1]], np.float32)
origins, directions = rays_lib.get_rays(size, size, K, pose_spherical(30.0, -30.0, 4.0)[:3, :4])
bundle = rays_lib.ray_bundle(origins, directions, 2.0, 6.0)
t0 = time.time()
out = render.render_image(NerfField(config), params, bundle, config, True, chunk)
seconds = time.time() - t0
assert out["rgb"].shape == (size, size, 3)
ray_bytes = sum(np.asarray(v).nbytes for v in bundle.values())
out_bytes = sum(v.nbytes for v in out.values())
print(json.dumps({"size": size, "before_mib": before, "peak_mib": mib(),
                  "rays_mib": ray_bytes / 2**20, "outputs_mib": out_bytes / 2**20,
                  "chunks": -(-size * size // chunk), "network_chunks": min(calls[0], max_chunks or calls[0]),
                  "seconds": seconds}))
"""


def main():
  parser = argparse.ArgumentParser(description=__doc__,
                                   formatter_class=argparse.RawDescriptionHelpFormatter)
  parser.add_argument("--sizes", type=int, nargs="+", default=[200, 400, 800])
  parser.add_argument("--max-chunks", type=int, default=2,
                      help="chunks that go through the network (0 = all: a full render)")
  parser.add_argument("--chunk", type=int, default=4096, help="rays per rendering call")
  args = parser.parse_args()
  rows = []
  for size in args.sizes:
    result = subprocess.run([sys.executable, "-c", CHILD, str(size), str(args.max_chunks),
                             str(args.chunk)], capture_output=True, text=True,
                            env=dict(os.environ, JAX_PLATFORMS="cpu"))
    if result.returncode:
      sys.exit(result.stderr[-3000:])
    rows.append(json.loads(result.stdout.strip().splitlines()[-1]))
    r = rows[-1]
    print(f"{size}x{size}: peak RSS {r['peak_mib']:.0f} MiB (before rendering "
          f"{r['before_mib']:.0f}); image buffers: rays {r['rays_mib']:.1f} MiB + outputs "
          f"{r['outputs_mib']:.1f} MiB; {r['chunks']} chunks of {args.chunk} rays, "
          f"{r['network_chunks']} through the network, {r['seconds']:.0f} s", flush=True)
  base = rows[0]
  for r in rows[1:]:
    growth = r["peak_mib"] - base["peak_mib"]
    buffers = (r["rays_mib"] + r["outputs_mib"]) - (base["rays_mib"] + base["outputs_mib"])
    print(f"{base['size']} -> {r['size']}: peak grows {growth:.0f} MiB; the image buffers "
          f"grow {buffers:.0f} MiB (x{growth / buffers if buffers else float('nan'):.2f} of "
          "them: the per-chunk working set does not grow with resolution)")


if __name__ == "__main__":
  main()
