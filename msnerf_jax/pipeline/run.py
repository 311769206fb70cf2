"""Every stage in one call: AdaIN decoder -> NeRF -> stylized dataset -> multi-style NeRF ->
feature field -> painted colour fields -> renders.

Each stage writes one subfolder of the output folder:

  inputs/      the scene's training views (the decoder's content images) and the style images
  adain/       the AdaIN decoder run            (skipped when a decoder run is given)
  nerf/        the NeRF run
  stylized/    the stylized dataset (every view in every style, plus the original)
  multistyle/  the multi-style NeRF run (the paper's model)
  features/    the feature-field run (AdaIN in 3D; skipped with features_steps 0)
  painted/     the painted run (colour fields per style; skipped with paint_steps 0)
  renders/     one video of every style side by side per model (painted.mp4, features.mp4,
               styles.mp4 for the paper's model, each also .gif), a style morph along the
               orbit of the first of them (painted_morph.mp4, or morph.mp4 without a painted
               run) and grid.png (styles x views: painted, feature field, the paper's model
               and per-frame AdaIN side by side)

plus pipeline.json (what each stage was run with) and summary.json / summary.txt.

Caching: a stage whose output is complete and whose settings are those recorded in
pipeline.json is skipped. Otherwise it is run, and resumes: the trainers continue from their
latest checkpoint and the stylized dataset from its last finished image, so an interrupted
pipeline re-run with the same command picks up where it stopped.
"""

import dataclasses
import json
import os
import time
from typing import Any, Callable, Dict, Optional, Sequence

from msnerf_jax.core import files
from msnerf_jax.core import memory
from msnerf_jax.core.errors import UserError
from msnerf_jax.data import images as images_lib
from msnerf_jax.data.stylized import ORIGINAL, style_name
from msnerf_jax.pipeline.settings import Settings, check_inputs
from msnerf_jax.pipeline.stages import STAGES, Context

RECORD = "pipeline.json"


def _load_record(out: str) -> Dict[str, Any]:
  path = os.path.join(out, RECORD)
  if not os.path.exists(path):
    return {"stages": {}}
  record = images_lib.read_json(path, "; delete it to re-check every stage")
  if not isinstance(record, dict) or not isinstance(record.get("stages"), dict):
    raise UserError(f"{path}: not a pipeline record; delete it to re-check every stage")
  return record


def _save_record(out: str, record: Dict[str, Any]) -> None:
  files.write_json(os.path.join(out, RECORD), record)


def run_pipeline(data: str, styles: Sequence[str], out: str, decoder: Optional[str] = None,
                 settings: Settings = Settings(), progress: bool = True,
                 log: Callable[[str], None] = print) -> Dict[str, Any]:
  """Runs (or completes) every stage of stages.STAGES; returns the summary (also in
  OUT/summary.json and OUT/summary.txt)."""
  check_inputs(data, styles, out, decoder, settings)
  styles = [os.path.abspath(p) for p in styles]
  c = Context(out=out, data=os.path.abspath(data), styles=styles,
              decoder=os.path.abspath(decoder) if decoder else None, settings=settings,
              progress=progress, log=log, names=[style_name(p) for p in styles] + [ORIGINAL])
  os.makedirs(out, exist_ok=True)
  record = _load_record(out)
  t_all = time.time()
  results = [_run_stage(c, k, stage, record, decoder) for k, stage in enumerate(STAGES, 1)]
  summary = {"out": os.path.abspath(out), "data": c.data, "styles": styles,
             "seconds": round(time.time() - t_all, 1), "stages": results,
             "settings": dataclasses.asdict(settings)}
  files.atomic_write_bytes(os.path.join(out, "summary.json"),
                           json.dumps(summary, indent=2).encode())
  files.atomic_write_bytes(os.path.join(out, "summary.txt"), format_summary(summary).encode())
  return summary


def _run_stage(c: Context, k: int, stage, record: Dict[str, Any], given_decoder):
  """Skips, or runs and records, one stage; returns its row of the summary."""
  tag = f"[{k}/{len(STAGES)}] {stage.name}"
  skip = stage.skip(c)
  if skip is not None:
    status, message = skip
    c.log(f"{tag}: {message}")
    return {"stage": stage.name, "status": status, "seconds": 0.0,
            "outputs": [given_decoder] if status == "given" else []}
  key = stage.key(c)
  saved = record["stages"].get(stage.name, {})
  if saved.get("key") == key and stage.done(c):
    outputs = stage.outputs(c)
    c.log(f"{tag}: already complete, skipped ({outputs[0]})")
    return {"stage": stage.name, "status": "skipped", "seconds": 0.0,
            "trained_seconds": saved.get("seconds", 0.0), "outputs": outputs}
  c.log(f"{tag}: running ...")
  t0 = time.time()
  outputs = stage.run(c)
  seconds, peak = time.time() - t0, memory.peak_gib()
  memory.release(compiled=not stage.keep_compiled)
  c.log(f"{tag}: done in {seconds:.1f} s (memory: peak so far {peak:.2f} GiB, "
        f"{memory.current_gib():.2f} GiB after it)")
  record["stages"][stage.name] = {"key": key, "seconds": round(seconds, 1), "outputs": outputs}
  _save_record(c.out, record)
  return {"stage": stage.name, "status": "ran", "seconds": round(seconds, 1),
          "peak_memory_gib": round(peak, 2), "outputs": outputs}


def format_summary(summary: Dict[str, Any]) -> str:
  """The summary as aligned text lines (printed at the end and saved as summary.txt)."""
  lines = [f"pipeline {summary['out']}: {summary['seconds']:.1f} s in all"]
  for r in summary["stages"]:
    if r["status"] == "ran":
      what = f"ran in {r['seconds']:.1f} s, peak memory so far {r['peak_memory_gib']:.2f} GiB"
    elif r["status"] == "skipped":
      what = f"skipped (done before, took {r.get('trained_seconds', 0.0):.1f} s)"
    else:
      what = r["status"]
    lines.append(f"  {r['stage']:<11} {what}")
    for path in r["outputs"]:
      lines.append(f"  {'':<11}   {path}")
  painted = summary["settings"].get("paint_steps")
  if painted:
    lines.append(f"its painted styles (strokes in 3D): msnerf render --run "
                 f"{os.path.join(summary['out'], 'painted')} --out VIDEO")
  if summary["settings"].get("features_steps"):
    lines.append(f"paint it in any style: msnerf render --run "
                 f"{os.path.join(summary['out'], 'features')} --style IMG --out VIDEO")
  lines.append(f"look around it in the browser: msnerf view --run "
               f"{os.path.join(summary['out'], 'painted' if painted else 'multistyle')}")
  return "\n".join(lines) + "\n"
