"""Training and rendering throughput over devices and processes, on this machine.

  python experiments/benchmarks/bench_parallel.py [--data DATA/nerf_synthetic/lego] [--steps 30]

Runs, each in fresh processes (XLA_FLAGS decides the CPU devices of a process):
  training rays/s of the `cpu` preset's NeRF step on lego 100x100 for
    1 process x 1 device (the baseline), 1 process x 2 devices under shard_map and pmap,
    2 processes x 1 device (jax.distributed on 127.0.0.1, gloo);
  the time to render one 100x100 view on 1 device, 2 devices of one process, and the 2
  devices of 2 processes.
On a GPU machine the 1-device rows are that GPU. Prints one table.
"""

import argparse
import json
import os
import socket
import subprocess
import sys
import time

from common import DATA, ROOT


def worker(args):
  # pylint: disable=g-import-not-at-top
  if args.processes > 1:
    from msnerf_jax.core import distributed
    distributed.initialize(f"127.0.0.1:{args.port}", args.processes, args.process_id, 120)
  import jax
  import jax.numpy as jnp
  from msnerf_jax.core import parallel
  from msnerf_jax.core.config import DataConfig, nerf_preset
  from msnerf_jax.data.scene import load_scene
  from msnerf_jax.train import nerf
  from msnerf_jax.kinds.views import render_view
  scene, data = load_scene(DataConfig(path=args.data, downscale=8))
  config = nerf_preset("cpu", data.format)
  dp = parallel.data_parallel(None, args.mode)
  train = scene.split("train")
  images, c2w = jnp.asarray(scene.images[train]), jnp.asarray(scene.c2w[train])
  K = jnp.asarray(scene.K)
  shape = (scene.height, scene.width, scene.focal)
  step = nerf.compile_train_step(config, scene.white_background, dp)
  state = dp.put_state(nerf.init_state(config))

  def batch(i):
    return dp.put_batch(nerf.sample_batch(jax.random.PRNGKey(i), images, c2w, K, config, False,
                                          scene.ndc, shape, scene.near, scene.far))
  for i in range(3):  # compile and warm up
    state, stats = step(state, batch(i))
  dp.to_host(stats)
  t0 = time.perf_counter()
  for i in range(args.steps):
    state, stats = step(state, batch(i))
  dp.to_host(stats)
  seconds = time.perf_counter() - t0
  params = dp.to_host(state.params)
  mesh = parallel.data_mesh() if args.processes > 1 else parallel.local_mesh()
  render_view(scene, params, config, 0, mesh=mesh)  # compile
  t0 = time.perf_counter()
  for _ in range(2):
    render_view(scene, params, config, 0, mesh=mesh)
  render = (time.perf_counter() - t0) / 2
  if jax.process_index() == 0:
    print(json.dumps({"rays_per_s": args.steps * config.batch_rays / seconds,
                      "render_s": render, "devices": dp.size,
                      "platform": jax.devices()[0].platform, "jax": jax.__version__}))


def run(data, steps, devices, processes, mode):
  env = dict(os.environ, XLA_FLAGS=f"--xla_force_host_platform_device_count={devices}",
             PYTHONPATH=ROOT)
  with socket.socket() as s:
    s.bind(("127.0.0.1", 0))
    port = s.getsockname()[1]
  procs = [subprocess.Popen(
      [sys.executable, __file__, "--worker", "--data", data, "--steps", str(steps),
       "--mode", mode, "--processes", str(processes), "--process-id", str(i), "--port",
       str(port)], env=env, stdout=subprocess.PIPE, text=True) for i in range(processes)]
  outs = [p.communicate()[0] for p in procs]
  if any(p.returncode for p in procs):
    raise SystemExit(f"worker failed: {[p.returncode for p in procs]}")
  return json.loads(outs[0].strip().splitlines()[-1])


def main():
  p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
  p.add_argument("--data", default=os.path.join(DATA, "nerf_synthetic", "lego"))
  p.add_argument("--steps", type=int, default=30)
  p.add_argument("--worker", action="store_true", help=argparse.SUPPRESS)
  p.add_argument("--mode", default="shard_map", help=argparse.SUPPRESS)
  p.add_argument("--processes", type=int, default=1, help=argparse.SUPPRESS)
  p.add_argument("--process-id", type=int, default=0, help=argparse.SUPPRESS)
  p.add_argument("--port", type=int, default=0, help=argparse.SUPPRESS)
  args = p.parse_args()
  if args.worker:
    return worker(args)
  print(f"# {os.cpu_count()} cores; lego 100x100, preset cpu, {args.steps} timed steps each; "
        f"command: python experiments/benchmarks/bench_parallel.py --steps {args.steps}")
  rows = [("1 process x 1 device", 1, 1, "shard_map"),
          ("1 process x 2 devices, shard_map", 2, 1, "shard_map"),
          ("1 process x 2 devices, pmap", 2, 1, "pmap"),
          ("2 processes x 1 device, shard_map", 1, 2, "shard_map")]
  base = None
  print(f"{'setting':<36} {'train rays/s':>12} {'vs base':>8} {'render 100x100':>15}")
  for name, devices, processes, mode in rows:
    r = run(args.data, args.steps, devices, processes, mode)
    base = base or r
    print(f"{name:<36} {r['rays_per_s']:12.0f} {r['rays_per_s'] / base['rays_per_s']:7.2f}x "
          f"{r['render_s']:13.2f} s", flush=True)
  print(f"# platform {base['platform']}, jax {base['jax']}")


if __name__ == "__main__":
  main()
