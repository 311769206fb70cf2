"""Runs one `msnerf` command and makes the disk fail at a chosen moment (used by
test_machine_faults.py; not a test itself).

  python tests/fault_injection.py MODE DISK TRIGGER SNAPSHOT [--no-estimate] -- ARGV...

MODE: how the disk fails.
  tmpfs   DISK is a small tmpfs; a filler file fills it to the last byte (ENOSPC), as a
          real full disk does.
  rlimit  SIMULATION for machines where mounting is not allowed: the process's file-size
          limit (RLIMIT_FSIZE) drops to 0, so every write fails in the kernel with EFBIG,
          for Python and for orbax's C++ writers alike, as on a full disk (ENOSPC).
TRIGGER: when.  start | checkpoint:N (after the Nth checkpoint of a training run) |
  image:N (after the Nth image written, e.g. of a stylized dataset) | video (when the first
  video is about to be written, its frames rendered).
SNAPSHOT: JSON file (outside DISK) that receives {relative path: sha256} of every file under
  DISK at the moment of the fault, to check that earlier outputs stay byte-identical.
--no-estimate: switches off the up-front free-space estimate of checkpoints, so the save
  itself runs into the full disk (orbax's failure path) instead of being refused before.
"""

import errno
import hashlib
import json
import os
import resource
import sys


def file_hashes(folder):
  """{path relative to `folder`: sha256} of every file under it but the filler."""
  hashes = {}
  for root, _, names in os.walk(folder):
    for name in names:
      if name != "filler":
        with open(os.path.join(root, name), "rb") as f:
          hashes[os.path.relpath(os.path.join(root, name), folder)] = hashlib.sha256(
              f.read()).hexdigest()
  return hashes


def snapshot(disk, path):
  with open(path, "w") as f:
    json.dump(file_hashes(disk), f)


def fail_disk(mode, disk, snapshot_path):
  snapshot(disk, snapshot_path)
  if mode == "rlimit":
    _, hard = resource.getrlimit(resource.RLIMIT_FSIZE)
    resource.setrlimit(resource.RLIMIT_FSIZE, (0, hard))
    return
  with open(os.path.join(disk, "filler"), "wb", buffering=0) as f:
    for size in (1 << 20, 4096, 1):
      try:
        while True:
          f.write(b"\0" * size)
      except OSError as e:
        assert e.errno == errno.ENOSPC, e


def main():
  mode, disk, trigger, snapshot_path, *rest = sys.argv[1:]
  no_estimate = "--no-estimate" in rest[: rest.index("--")]
  argv = rest[rest.index("--") + 1:]
  # pylint: disable=g-import-not-at-top
  from msnerf_jax import cli
  from msnerf_jax.core import checkpoint
  from msnerf_jax.data import video
  from msnerf_jax.data import images
  from msnerf_jax.train import loop
  if no_estimate:
    checkpoint.checkpoint_bytes = lambda tree: 0
  what, _, count = trigger.partition(":")
  count = int(count or 0)
  if what == "start":
    fail_disk(mode, disk, snapshot_path)
  elif what == "checkpoint":
    fit = loop.fit

    def fit_with_fault(*args, **kwargs):
      seen = []

      def callback(step, params):
        seen.append(step)
        if len(seen) == count:
          fail_disk(mode, disk, snapshot_path)
      return fit(*args, **{**kwargs, "callback": callback})
    loop.fit = fit_with_fault
  elif what == "image":
    write_image = images.write_image
    written = []

    def write_with_fault(path, image):
      write_image(path, image)
      written.append(path)
      if len(written) == count:
        fail_disk(mode, disk, snapshot_path)
    images.write_image = write_with_fault
  elif what == "video":
    write_video = video.write_video

    def video_with_fault(*args, **kwargs):
      if not os.path.exists(snapshot_path):
        fail_disk(mode, disk, snapshot_path)
      return write_video(*args, **kwargs)
    video.write_video = video_with_fault
  sys.exit(cli.main(argv))


if __name__ == "__main__":
  main()
