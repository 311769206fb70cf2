"""The trainer's lock on a run folder: one trainer at a time per run folder.

The trainers take it in `runs.prepare_run_dir(..., lock=True)`, before anything is written,
and release it when they end (`released_after`). `acquire(run_dir)` creates RUN/trainer.lock
(exclusively) with the process id, host, start time and command of this trainer; a second
trainer on the same folder gets a UserError naming the running one and writes nothing. A lock whose process is gone (killed, crashed:
the process id is no longer running on this host, or now belongs to a process started
later) is stale and taken over. `release(run_dir)` removes it (training ends, or fails);
locks still held at exit are removed then.
"""

import atexit
import functools
import inspect
import json
import os
import socket
import sys
import time
from typing import Any, Callable, Dict, Optional

from msnerf_jax.core.errors import UserError

LOCK_FILE = "trainer.lock"
_held = set()  # lock files this process holds


def _start_ticks(pid: int) -> Optional[int]:
  """The process's start time in clock ticks since boot (Linux /proc), None if unknown."""
  try:
    with open(f"/proc/{pid}/stat") as f:
      stat = f.read()
  except OSError:
    return None
  fields = stat[stat.rindex(")") + 2:].split()  # after the command name, which may hold spaces
  return int(fields[19]) if fields[0] != "Z" else -1  # field 22; a zombie has ended


def _alive(holder: Dict[str, Any]) -> bool:
  """Whether the lock's process still runs (unknown processes on other hosts count as alive)."""
  if holder.get("host") != socket.gethostname():
    return True
  pid = holder.get("pid")
  if not isinstance(pid, int) or pid <= 0:
    return False
  try:
    os.kill(pid, 0)
  except ProcessLookupError:
    return False
  except PermissionError:
    pass  # another user's process
  ticks = _start_ticks(pid)
  if ticks == -1:
    return False
  return ticks is None or holder.get("start") in (None, ticks)


def _read(path: str) -> Optional[Dict[str, Any]]:
  try:
    with open(path) as f:
      holder = json.load(f)
    return holder if isinstance(holder, dict) else {}
  except FileNotFoundError:
    return None
  except (OSError, ValueError):
    return {}  # unreadable or half written: no live holder can be named


def acquire(run_dir: str) -> None:
  """Takes the lock of an existing run folder for this process (again: a no-op).

  Raises:
    UserError naming the running trainer (process id, host, command) when another live
    process holds the lock.
  """
  path = os.path.join(run_dir, LOCK_FILE)
  if path in _held:
    return
  record = {"pid": os.getpid(), "host": socket.gethostname(), "start": _start_ticks(os.getpid()),
            "since": time.strftime("%Y-%m-%d %H:%M:%S"), "command": " ".join(sys.argv)}
  # The record goes to a private file first, then is hard-linked as the lock: the link is
  # created exclusively and whole, so no trainer ever reads a half-written lock.
  private = f"{path}.{os.getpid()}"
  with open(private, "w") as f:
    json.dump(record, f)
  try:
    for _ in range(3):
      try:
        os.link(private, path)
      except FileExistsError:
        holder = _read(path)
        if holder is None:
          continue  # released meanwhile
        if holder and _alive(holder):
          raise UserError(
              f"{run_dir}: another trainer is running on it (process {holder.get('pid')} on "
              f"{holder.get('host')} since {holder.get('since')}: {holder.get('command')!r}); "
              f"wait for it or stop it (if it is gone, delete {path})") from None
        try:
          os.remove(path)  # stale: its process is gone
        except FileNotFoundError:
          pass
        continue
      if not _held:
        atexit.register(_release_all)
      _held.add(path)
      return
  finally:
    os.remove(private)
  raise UserError(f"{path}: could not take the lock (other trainers keep starting)")


def release(run_dir: str) -> None:
  """Removes this process's lock of run_dir, if it holds it."""
  path = os.path.join(run_dir, LOCK_FILE)
  if path in _held:
    _held.discard(path)
    try:
      os.remove(path)
    except FileNotFoundError:
      pass


def _release_all() -> None:
  for path in list(_held):
    release(os.path.dirname(path))


def released_after(train_fn: Callable) -> Callable:
  """Decorates a trainer `train_fn(..., run_dir, ...)`: the lock on its run_dir (taken by
  runs.prepare_run_dir(..., lock=True)) is released when it returns or raises."""
  signature = inspect.signature(train_fn)

  @functools.wraps(train_fn)
  def trainer(*args, **kwargs):
    run_dir = signature.bind(*args, **kwargs).arguments["run_dir"]
    try:
      return train_fn(*args, **kwargs)
    finally:
      release(run_dir)
  return trainer
