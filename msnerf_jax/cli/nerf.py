"""`msnerf nerf train | eval | render | camera-path`: the geometry stage."""

import json
import os
import time

import numpy as np

from msnerf_jax.core import config as config_lib
from msnerf_jax.cli.common import (add_camera_path_arguments, add_fast_argument,
                                   add_parallel_arguments,
                                   check_path_options, load_run_and_scene, output_stem,
                                   print_summary, print_training_summary, render_cameras,
                                   start_processes)
from msnerf_jax.cli.config_args import (add_config_arguments, add_config_option,
                                        config_overrides, start_config)
from msnerf_jax.core.errors import UserError


# NerfConfig fields with options of their own above the generated ones.
# The options `msnerf nerf train --help` lists first; the group "every other NeRF setting"
# has the rest of the config's fields.
_MAIN = ("steps", "batch_rays", "checkpoint_every", "net_depth", "net_width", "n_coarse",
         "n_fine", "random_background", "distortion_weight", "seed")


def register(commands, formatter):
  nerf = commands.add_parser("nerf", help="train, evaluate and render a vanilla NeRF",
                             formatter_class=formatter,
                             description="The geometry stage: a vanilla NeRF on posed photos.")
  verbs = nerf.add_subparsers(dest="verb", metavar="VERB", required=True)

  _register_train(verbs, formatter)
  _register_eval(verbs, formatter)
  _register_render(verbs, formatter)
  _register_camera_path(verbs, formatter)


def _register_train(verbs, formatter):
  p = verbs.add_parser("train", formatter_class=formatter,
                       help="train a NeRF (re-run the same command to resume)",
                       description="Train a NeRF on a Blender or LLFF scene. Re-running the same "
                       "command resumes from the latest checkpoint; --steps may be raised to "
                       "train longer.")
  p.add_argument("--data", required=True, help="scene folder (Blender or LLFF, auto-detected)")
  p.add_argument("--out", required=True, help="run folder for config, checkpoints and logs")
  p.add_argument("--preset", default=config_lib.DEFAULT_PRESET, choices=config_lib.PRESETS,
                 help="paper = reference architecture and defaults; cpu = small MLP for a "
                      "laptop; fast = hash-grid trunk and occupancy-grid sampling "
                      "(instant-NGP's recipe)")
  add_config_arguments(p, config_lib.DataConfig, config_lib.DataConfig(), names=("downscale",))
  add_config_arguments(p, config_lib.NerfConfig, None, names=_MAIN)
  add_parallel_arguments(p)
  p.add_argument("--stylized", default=None, metavar="DIR",
                 help="train on one style's views of this stylized dataset (`msnerf "
                      "stylize-scene` of the same scene) instead of the photos: the "
                      "single-style baseline; needs --style")
  p.add_argument("--style", default=None, metavar="NAME", help="the style, with --stylized")
  add_config_option(p, "NeRF")
  add_config_arguments(p, config_lib.NerfConfig, None, title="every other NeRF setting",
                       skip=_MAIN)
  add_config_arguments(p, config_lib.DataConfig, config_lib.DataConfig(),
                       title="scene loading", skip=("path", "downscale"))
  p.set_defaults(func=cmd_train)


def _register_eval(verbs, formatter):
  p = verbs.add_parser("eval", formatter_class=formatter, help="PSNR/SSIM on a held-out split",
                       description="Render a split of the run's scene and report PSNR and SSIM.")
  p.add_argument("--run", required=True, help="run folder made by `msnerf nerf train`")
  p.add_argument("--split", default="val", choices=("train", "val", "test"), help="which views")
  p.add_argument("--chunk", type=int, default=None, help="rays per rendering call")
  p.set_defaults(func=cmd_eval)


def _register_render(verbs, formatter):
  p = verbs.add_parser("render", formatter_class=formatter,
                       help="video along the scene's render path (MP4 + GIF, plus depth)",
                       description="Render the dataset's render path (Blender: orbit; LLFF: "
                       "spiral) to FILE.mp4 and FILE.gif, and depth to FILE_depth.*.")
  p.add_argument("--run", required=True, help="run folder made by `msnerf nerf train`")
  p.add_argument("--out", required=True, help="output file stem (.mp4/.gif are added)")
  add_camera_path_arguments(p)
  p.add_argument("--chunk", type=int, default=None, help="rays per rendering call")
  add_fast_argument(p)
  p.set_defaults(func=cmd_render)


def _register_camera_path(verbs, formatter):
  p = verbs.add_parser("camera-path", formatter_class=formatter,
                       help="write the scene's render path as a nerfstudio camera_path.json",
                       description="Write the render path of a run's scene (Blender: orbit; "
                       "LLFF: spiral; captures: orbit or spiral) as a nerfstudio "
                       "camera_path.json in the scene's normalised world, to edit, script or "
                       "render with --camera-path.",
                       epilog="example: msnerf nerf camera-path --run runs/cup --out path.json "
                              "--frames 50 && msnerf nerf render --run runs/cup --out fly "
                              "--camera-path path.json")
  p.add_argument("--run", required=True, help="run folder made by `msnerf nerf train` (or a "
                 "multi-style run)")
  p.add_argument("--out", required=True, help="the .json file to write")
  p.add_argument("--frames", type=int, default=0, help="number of cameras (0 = whole path)")
  p.add_argument("--fps", type=float, default=24, help="frames per second recorded in the file")
  p.set_defaults(func=cmd_camera_path)


def cmd_train(args):
  # pylint: disable=g-import-not-at-top
  from msnerf_jax.data.scene import load_scene
  from msnerf_jax.train import nerf
  shows = start_processes(args)
  data_config = config_lib.override(
      config_lib.DataConfig(path=os.path.abspath(args.data)),
      **config_overrides(args, config_lib.DataConfig))
  if os.path.isfile(args.out):
    raise UserError(f"{args.out}: is a file, expected a run folder")
  if (args.stylized is None) != (args.style is None):
    raise UserError("--stylized and --style go together (a dataset folder and one of its styles)")
  scene, data_config = load_scene(data_config.validate())
  style = None
  if args.stylized is not None:
    from msnerf_jax.data.stylized import style_views
    style = {"stylized": os.path.abspath(args.stylized), "name": args.style}
    scene = style_views(style["stylized"], args.style, scene)
  config = start_config(args, "nerf", config_lib.nerf_preset(
      args.preset, data_config.format, **config_overrides(args, config_lib.NerfConfig)))
  if shows:
    print(f"scene {data_config.path}: {data_config.format}, {len(scene.split('train'))} "
          f"training views of {scene.width}x{scene.height}; "
          + (f"{scene.layout}; " if scene.layout else "")
          + (f"config of {args.config}" if args.config else f"preset {args.preset}")
          + (f"; style {args.style} of {args.stylized}" if style else ""))
  summary = nerf.train(scene, config, data_config, args.out, n_devices=args.devices, style=style,
                       parallel=args.parallel)
  if shows:
    print_training_summary("NeRF training done", summary, "",
                           f"msnerf nerf eval --run {args.out}; msnerf nerf render --run "
                           f"{args.out} --out {os.path.join(args.out, 'video')}")


def _load(run_dir):
  """(run, scene) of a nerf run folder."""
  return load_run_and_scene(run_dir, "nerf")


def cmd_eval(args):
  # pylint: disable=g-import-not-at-top
  from msnerf_jax.data.images import write_image
  from msnerf_jax.core.files import atomic_write_bytes
  from msnerf_jax.eval.evaluate import evaluate_nerf
  run, scene = _load(args.run)
  t0 = time.time()
  rows, mean, renders = evaluate_nerf(scene, run.params, run.config, args.split, args.chunk)
  out_dir = os.path.join(args.run, f"eval_{args.split}")
  for row, out in zip(rows, renders):
    write_image(os.path.join(out_dir, os.path.splitext(row["view"])[0] + ".png"), out["rgb"])
  nan_to_none = lambda row: {k: None if isinstance(v, float) and np.isnan(v) else v
                             for k, v in row.items()}  # strict JSON has no NaN
  result = {"step": run.step, "split": args.split, "mean": nan_to_none(mean),
            "views": [nan_to_none(row) for row in rows]}
  atomic_write_bytes(os.path.join(out_dir, "metrics.json"), json.dumps(result, indent=2).encode())
  opacity = "opacity_background" in mean
  print(f"{'view':<24} {'PSNR':>7} {'SSIM':>7}"
        + (f" {'opacity empty':>14} {'opacity object':>15}" if opacity else ""))
  for row in rows:
    print(f"{row['view']:<24} {row['psnr']:7.2f} {row['ssim']:7.4f}"
          + (f" {row['opacity_background']:14.3f} {row['opacity_object']:15.3f}"
             if opacity else ""))
  lines = [("mean PSNR", f"{mean['psnr']:.2f} dB"), ("mean SSIM", f"{mean['ssim']:.4f}")]
  if opacity:  # ground-truth alpha 0 / 255: fog in empty space, holes in the object.
    lines += [("mean opacity", f"{mean['opacity_background']:.3f} on empty space, "
                               f"{mean['opacity_object']:.3f} on the object")]
  print_summary(f"NeRF eval on {args.split} (step {run.step})", lines + [
      ("time", f"{time.time() - t0:.1f} s"), ("renders", out_dir)])


def cmd_render(args):
  # pylint: disable=g-import-not-at-top
  from msnerf_jax.core.progress import progress_bar
  from msnerf_jax.data import video
  from msnerf_jax.kinds.baked import baked_views
  from msnerf_jax.kinds.views import render_view
  run, scene = _load(args.run)
  poses, fps, size = render_cameras(scene, args)
  stem = output_stem(args.out)
  draw = lambda c2w: render_view(scene, run.params, run.config, c2w, args.chunk)
  if getattr(args, "fast", False):
    draw = baked_views(run, scene)
  t0 = time.time()
  frames, depths = [], []
  for c2w in progress_bar(poses, desc="rendering"):
    out = draw(c2w)
    frames.append(out["rgb"])
    depths.append(out)
  # One depth scale for the whole video.
  valid = np.concatenate([d["depth"][d["accumulation"] > 0.5] for d in depths]) \
      if any((d["accumulation"] > 0.5).any() for d in depths) else np.array([0.0, 1.0])
  lo, hi = np.percentile(valid, 1), np.percentile(valid, 99)
  depth_frames = [video.depth_to_image(d["depth"], d["accumulation"], lo, hi) for d in depths]
  written = video.write_videos(stem, frames, fps)
  written += video.write_videos(stem + "_depth", depth_frames, fps)
  seconds = time.time() - t0
  print_summary("NeRF render done", [
      ("frames", f"{len(frames)} of {size}"),
      ("time", f"{seconds:.1f} s ({len(frames) / seconds:.2f} frames/s)"),
      ("written", ", ".join(written))])


def cmd_camera_path(args):
  # pylint: disable=g-import-not-at-top
  from msnerf_jax.data.camera_path import write_camera_path
  from msnerf_jax.kinds.runs import run_scene
  check_path_options(args.frames, args.fps)
  scene = run_scene(args.run)
  poses = scene.path_poses(args.frames)
  write_camera_path(args.out, poses, scene.K, scene.height, scene.width, args.fps)
  print_summary("camera path written", [
      ("cameras", f"{len(poses)} of {scene.width}x{scene.height}, {args.fps:g} fps"),
      ("written", args.out),
      ("next", f"msnerf nerf render --run {args.run} --out video --camera-path {args.out}")])
