"""Run folders: run.json (kind, config, data), the config check on resume, `load_run` and
`scene_of` (each kind's config class and params come from msnerf_jax.kinds.registry). The orbax checkpoints inside a run folder
are `msnerf_jax.core.checkpoint`."""

import dataclasses
import json
import os
from typing import Any, Dict, Optional

import numpy as np

from msnerf_jax.core import config as config_lib
from msnerf_jax.core import run_lock
from msnerf_jax.core.checkpoint import CHECKPOINT_DIR, Checkpoints
from msnerf_jax.data.images import read_json
from msnerf_jax.core.files import write_json
from msnerf_jax.data.scene import drop_legacy_data_keys, load_scene
from msnerf_jax.data.stylized import style_views
from msnerf_jax.core.errors import UserError
from msnerf_jax.kinds.base import check_param_shapes
from msnerf_jax.kinds.registry import KINDS, get_kind

RUN_FILE = "run.json"


def read_run_file(run_dir: str, kind: Optional[str] = None) -> Dict[str, Any]:
  """The parsed run.json of a run folder ({"kind", "config", ...}); with `kind`, a UserError
  unless the run is of that kind."""
  if not os.path.exists(run_dir):
    raise UserError(f"{run_dir}: no such run folder")
  if not os.path.isdir(run_dir):
    raise UserError(f"{run_dir}: is a file, expected a run folder")
  path = os.path.join(run_dir, RUN_FILE)
  if not os.path.exists(path):
    raise UserError(f"{path}: missing; {run_dir} is not a msnerf run folder")
  run = read_json(path)
  if not isinstance(run, dict) or "kind" not in run or "config" not in run:
    raise UserError(f"{path}: missing 'kind' or 'config'")
  if isinstance(run.get("data"), dict):
    drop_legacy_data_keys(run["data"], path)
  if kind is not None and run["kind"] != kind:
    raise UserError(f"{path}: a {run['kind']!r} run, not a {kind!r} run (train one with "
                    f"`{_train_command(kind)}`)")
  return run


def load_config(path: str, kind: str) -> Any:
  """The config of a saved run, to start another from: `path` is a run folder or its
  run.json; UserError unless it is a run of `kind`."""
  run_dir = os.path.dirname(path) if os.path.basename(path) == RUN_FILE else path
  if os.path.isfile(path) and os.path.basename(path) != RUN_FILE:
    raise UserError(f"{path}: expected a run folder or its {RUN_FILE}")
  run = read_run_file(run_dir, kind)
  return config_lib.from_dict(get_kind(kind).config_class, run["config"],
                              os.path.join(run_dir, RUN_FILE))


def prepare_run_dir(run_dir: str, kind: str, run: Dict[str, Any], lock: bool = False) -> bool:
  """Creates a run folder or checks that an existing one was made with the same settings.

  Args:
    run_dir: the folder.
    kind: "nerf", "adain", "multistyle".
    run: JSON-able dict with at least "config"; saved as run.json together with `kind`.
    lock: a trainer's call: take the run folder's lock (msnerf_jax.core.run_lock) once the
      settings are checked, before run.json is written; a trainer already running there
      makes this a UserError naming it, and nothing is written.
  Returns:
    True when the folder already held this run (training resumes), False when new.
  Raises:
    UserError when the path is a file, or the folder holds a run of another kind or config
    (its checkpoints are never touched then).
  """
  record = {"kind": kind, **run}
  if os.path.exists(run_dir) and not os.path.isdir(run_dir):
    raise UserError(f"{run_dir}: is a file, expected a run folder")
  path = os.path.join(run_dir, RUN_FILE)
  if os.path.exists(path):
    saved = read_run_file(run_dir)
    if saved.get("kind") != kind:
      raise UserError(f"{run_dir}: holds a {saved.get('kind')!r} run, not {kind!r}; "
                      "choose another --out")
    # A run.json written before a config field existed holds that field's default.
    saved["config"] = config_lib.to_dict(config_lib.from_dict(
        get_kind(kind).config_class, saved["config"], path))
    # Compare what defines the run; "steps" may grow to train longer.
    mismatch = config_lib.diff(_defining(saved), _defining(record))
    if mismatch:
      raise UserError(f"{run_dir}: was made with another config ({mismatch}); "
                      "use another --out, or the same options to resume")
    if lock:
      run_lock.acquire(run_dir)
    write_json(path, record)
    return True
  if os.path.isdir(run_dir) and os.listdir(run_dir):
    if os.path.exists(os.path.join(run_dir, CHECKPOINT_DIR)):
      raise UserError(f"{run_dir}: has checkpoints but no {RUN_FILE}; refusing to overwrite")
  try:
    os.makedirs(run_dir, exist_ok=True)
    if lock:
      run_lock.acquire(run_dir)
    write_json(path, record)
  except PermissionError:
    raise UserError(f"{run_dir}: not writable") from None
  except OSError as e:
    raise UserError(f"{run_dir}: cannot create run folder ({e.strerror})") from None
  return False


def write_summary(run_dir: str, summary: Dict[str, Any]) -> None:
  """Saves a trainer's summary of its last training in the run's run.json (atomically; not
  part of what defines the run)."""
  record = read_run_file(run_dir)
  record["summary"] = summary
  write_json(os.path.join(run_dir, RUN_FILE), record)


def _defining(record: Dict[str, Any]) -> Dict[str, Any]:
  record = json.loads(json.dumps(record))  # deep copy, tuples -> lists
  config = record.get("config", {})
  config.pop("steps", None)  # an AdaIN run's
  config.get("optim", {}).pop("steps", None)
  record.pop("summary", None)
  return record


@dataclasses.dataclass(frozen=True)
class Run:
  """A saved run: its kind, config (frozen dataclass), params pytree and step."""
  run_dir: str
  kind: str
  config: Any
  params: Any
  step: int
  record: Dict[str, Any]


def load_run(run_dir: str, kind: Optional[str] = None) -> Run:
  """Loads a run folder: config from run.json and params of its latest checkpoint; with
  `kind`, refuses a run of another kind before reading any checkpoint.

  Returns:
    `Run` with `.config`, `.params` (nested dict of numpy arrays) and `.step`.
  """
  record = read_run_file(run_dir, kind)
  kind = record["kind"]
  config = config_lib.from_dict(get_kind(kind).config_class, record["config"],
                                os.path.join(run_dir, RUN_FILE))
  checkpoints = Checkpoints(run_dir)
  try:
    step = checkpoints.latest_step()
    if step is None:
      raise UserError(f"{run_dir}: no checkpoint yet (train first)")
    restored = checkpoints.restore()
  finally:
    checkpoints.close()
  params = _to_numpy(restored["params"])
  where = os.path.join(run_dir, CHECKPOINT_DIR, str(step))
  check_param_shapes(params, expected_params(kind, config), where)
  if get_kind(kind).check_params is not None:
    get_kind(kind).check_params(params, config, record, where)
  return Run(run_dir=run_dir, kind=kind, config=config, params=params, step=int(step),
             record=record)


def scene_of(run: Run):
  """(scene, data config) a loaded run was trained on, reloaded: for a NeRF trained on one
  style of a stylized dataset (run.json's "style"), that style's views are its images."""
  source = os.path.join(run.run_dir, RUN_FILE)
  scene, data = _load_scene(_data_config(run.record, source), source)
  style = run.record.get("style")
  if style is not None:
    if not isinstance(style, dict) or not {"stylized", "name"} <= set(style):
      raise UserError(f"{source}: 'style' needs 'stylized' and 'name'")
    scene = style_views(style["stylized"], style["name"], scene)
  return scene, data


def _data_config(record: Dict[str, Any], source: str) -> config_lib.DataConfig:
  """The DataConfig of a run.json record read by read_run_file (`source` names it)."""
  if "data" not in record:
    raise UserError(f"{source}: a {record['kind']!r} run has no scene")
  config = config_lib.from_dict(config_lib.DataConfig, record["data"], f"{source}: data")
  if not config.path:
    raise UserError(f"{source}: data: path is empty (which scene was the run trained on?)")
  return config


def run_scene(run_dir: str):
  """The scene (its cameras and normalised world) a run folder was trained on, without
  loading its checkpoint."""
  source = os.path.join(run_dir, RUN_FILE)
  return _load_scene(_data_config(read_run_file(run_dir), source), source)[0]


def _load_scene(data: config_lib.DataConfig, source: str):
  """load_scene of a run's recorded data; a setting it refuses (`--format X: ...`, as the
  loaders word an option) was read from `source`, which the message names."""
  try:
    return load_scene(data)
  except UserError as e:
    if str(e).startswith("--"):
      raise UserError(f"{source}: data: {str(e)[2:]}") from None
    raise


def load_run_and_scene(run_dir: str, kind: str):
  """(run, scene) of a run folder of the given kind, the scene reloaded as it was trained."""
  run = load_run(run_dir, kind)
  return run, scene_of(run)[0]


def _to_numpy(tree):
  if isinstance(tree, dict):
    return {k: _to_numpy(v) for k, v in tree.items()}
  if isinstance(tree, (list, tuple)):
    return type(tree)(_to_numpy(v) for v in tree)
  return np.asarray(tree)


def _train_command(kind: str) -> str:
  return KINDS[kind].train_command if kind in KINDS else "msnerf"


def expected_params(kind: str, config: Any):
  """Shapes (jax.ShapeDtypeStruct leaves) the params of a run of this kind and config have,
  from its registered initialiser (None: checked elsewhere)."""
  import jax  # pylint: disable=g-import-not-at-top
  init = get_kind(kind).init_params
  if init is None:
    return None
  return jax.eval_shape(lambda: init(config, jax.random.PRNGKey(0)))
