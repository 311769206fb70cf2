"""Run folders (msnerf_jax.kinds.runs): saved settings from earlier versions still load."""

import json
import os

import pytest

from msnerf_jax.core import config as config_lib
from msnerf_jax.kinds import runs
from msnerf_jax.core.errors import UserError


def _nerf_record(data):
  return {"config": config_lib.to_dict(config_lib.NerfConfig()), "data": data}


def test_run_json_with_the_removed_llff_spherify_key_still_loads(tmp_path):
  run = str(tmp_path / "run")
  data = config_lib.to_dict(config_lib.DataConfig(path="scene"))
  runs.prepare_run_dir(run, "nerf", _nerf_record(data))
  path = os.path.join(run, runs.RUN_FILE)
  record = json.load(open(path))
  record["data"]["llff_spherify"] = False  # as written before the flag was removed
  json.dump(record, open(path, "w"))
  assert runs.read_run_file(run, "nerf")["data"] == data
  assert runs.prepare_run_dir(run, "nerf", _nerf_record(data)) is True  # resumes
  record["data"]["llff_spherify"] = True  # never loadable: named, not ignored
  json.dump(record, open(path, "w"))
  with pytest.raises(UserError, match="run.json: llff_spherify True is not supported"):
    runs.read_run_file(run)


def test_stylized_manifest_with_the_removed_llff_spherify_key_still_loads(tmp_path):
  from msnerf_jax.data import stylized  # pylint: disable=g-import-not-at-top
  data = config_lib.to_dict(config_lib.DataConfig(path="scene"))
  manifest = {"data": dict(data, llff_spherify=False), "height": 4, "width": 4, "n_views": 1,
              "splits": {"train": [0]}, "styles": [], "done": []}
  json.dump(manifest, open(tmp_path / stylized.MANIFEST, "w"))
  assert stylized.read_manifest(str(tmp_path))["data"] == data
