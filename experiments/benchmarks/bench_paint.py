"""What painting costs and how fast a painted view renders, against the photo-real view of
the same run (the same NeRF, the same camera), measured in one process:

  python experiments/benchmarks/bench_paint.py --run RUNS/lego_painted [--repeats 5]

Prints: the run's training time (its summary), the median wall time of a whole test view
rendered photo-real (views.render_view), painted in all M styles at once
(painted.render_painted) and painted from a training view's cached samples (the trainer's
render: a gather and a segment sum), and the machine line.
"""

import argparse
import statistics

from common import call_times, machine


def main(argv=None):
  # pylint: disable=g-import-not-at-top
  import jax
  import jax.numpy as jnp
  from msnerf_jax.kinds.painted import render_painted
  from msnerf_jax.kinds.runs import load_run, scene_of
  from msnerf_jax.kinds.views import render_view
  from msnerf_jax.models.painted_field import trilinear
  from msnerf_jax.nerf import sample_cache
  from msnerf_jax.train.paint_data import CACHE_FILE, cache_source, read_cache
  parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
  parser.add_argument("--run", required=True)
  parser.add_argument("--repeats", type=int, default=5)
  args = parser.parse_args(argv)
  run = load_run(args.run, "painted")
  scene, _ = scene_of(run)
  summary = run.record.get("summary", {})
  m = len(run.record["styles"])
  print(f"run {args.run}: {m} styles, {summary.get('steps')} steps in "
        f"{summary.get('seconds', float('nan')):.0f} s ({summary.get('devices')} device(s)); "
        f"{run.params['paint']['colours'].shape[1] - 1} painted vertices of "
        f"{run.config.resolution}^3, {run.params['paint']['colours'].nbytes / 2 ** 20:.1f} MiB "
        "of colours")
  held_out = next((n for n in ("test", "val") if n in scene.splits and len(scene.split(n))),
                  None)  # a held-out view where the scene has one
  camera = int(scene.split(held_out)[0]) if held_out else 0
  median = lambda fn: statistics.median(call_times(fn, args.repeats))
  photo = median(lambda: render_view(scene, run.params["nerf"], run.config.nerf, camera))
  painted = median(lambda: render_painted(scene, run.params, run.config, camera)["rgb"])
  nerf_run = load_run(run.record["nerf_run"], "nerf")
  cache = read_cache(f"{args.run}/{CACHE_FILE}", cache_source(nerf_run))
  view = jax.tree_util.tree_map(lambda x: jnp.asarray(x[0]), cache)
  paint = jax.tree_util.tree_map(jnp.asarray, run.params["paint"])
  colour = lambda p: jax.nn.sigmoid(trilinear(paint["colours"][:, :], paint["index"], p,
                                              run.config.scene_box))
  cached = jax.jit(lambda v: sample_cache.cached_render(colour, v, jnp.ones(3)))
  from_cache = median(lambda: cached(view))
  size = f"{scene.width}x{scene.height}"
  print(f"a {size} view: photo-real {photo:.3f} s; painted, all {m} styles {painted:.3f} s "
        f"({photo / painted:.2f}x the photo-real's speed); from the cached samples, all {m} "
        f"styles {from_cache * 1e3:.1f} ms")
  print(machine())


if __name__ == "__main__":
  main()
