"""Several processes (on one host or many) training one run, through `jax.distributed`.

Every process runs the same command with its own `--process-id`; `initialize` joins them
(`jax.distributed.initialize`; on CPU their collectives go through gloo), after which
`jax.devices()` lists every process's devices and parallel.data_mesh spans them all.
Process 0 is the primary: it alone writes the run folder (run.json, its lock, history,
videos); checkpoints are written through orbax, which every process takes part in.

JAX ends a process with an abort, not an exception, when its coordinator cannot be
reached or a process never joins, so `initialize` first meets the others itself on the
coordinator's port (a plain TCP handshake with a deadline): a wrong address, a process id
out of range or given twice, a different process count, or a process that never comes
then ends with one line naming it.
"""

import hashlib
import json
import socket
import time
from typing import Any, Callable, Optional

import jax
import numpy as np
from jax.experimental import multihost_utils

from msnerf_jax.core.errors import UserError

HELLO = "msnerf-join"
HEARTBEAT_SECONDS = 30
SHUTDOWN_SECONDS = 30


def parse_address(coordinator: str):
  """'HOST:PORT' -> (host, port); UserError otherwise."""
  host, sep, port = coordinator.rpartition(":")
  if not sep or not host or not port.isdigit() or not 0 < int(port) < 65536:
    raise UserError(f"coordinator {coordinator!r}: expected HOST:PORT with a port in 1..65535")
  return host.strip("[]"), int(port)


def _read_line(conn: socket.socket, deadline: float) -> str:
  data = b""
  while not data.endswith(b"\n"):
    conn.settimeout(max(0.05, deadline - time.monotonic()))
    chunk = conn.recv(256)
    if not chunk or len(data) > 4096:
      break
    data += chunk
  return data.decode("utf-8", "replace").strip()


def _gather_joins(port: int, num_processes: int, timeout: float, coordinator: str) -> None:
  """Process 0: waits for processes 1..N-1 to say hello, then answers them all."""
  server = socket.socket(socket.AF_INET, socket.SOCK_STREAM)
  server.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
  try:
    server.bind(("", port))
  except OSError as e:
    server.close()
    raise UserError(f"coordinator {coordinator}: cannot listen on port {port} "
                    f"({e.strerror})") from None
  server.listen(num_processes)
  deadline = time.monotonic() + timeout
  joined, problem, connections = set(), None, []
  try:
    while len(joined) < num_processes - 1 and problem is None:
      left = deadline - time.monotonic()
      if left <= 0:
        missing = sorted(set(range(1, num_processes)) - set(joined))
        raise UserError(f"coordinator {coordinator}: process{'es' if len(missing) > 1 else ''} "
                        f"{', '.join(map(str, missing))} of {num_processes} did not join "
                        f"within {timeout:.0f} s")
      server.settimeout(left)
      try:
        conn, _ = server.accept()
      except socket.timeout:
        continue
      try:  # one of ours says hello at once
        words = _read_line(conn, min(deadline, time.monotonic() + 5.0)).split()
      except OSError:
        words = []
      if len(words) != 3 or words[0] != HELLO or not all(w.isdigit() for w in words[1:]):
        conn.close()  # not one of ours (a port scan): ignore it
        continue
      connections.append(conn)
      pid, count = int(words[1]), int(words[2])
      if count != num_processes:
        problem = (f"process {pid} was started with --num-processes {count}, process 0 "
                   f"with {num_processes}")
      elif pid in joined or pid == 0:
        problem = f"two processes were started with --process-id {pid}"
      elif pid >= num_processes:
        problem = f"process id {pid} is out of range 0..{num_processes - 1}"
      joined.add(pid)
    reply = f"error {problem}\n" if problem else "ok\n"
    for conn in connections:
      try:
        conn.sendall(reply.encode())
      except OSError:
        pass
    if problem:
      raise UserError(f"coordinator {coordinator}: {problem}")
  finally:
    for conn in connections:
      conn.close()
    server.close()


def _join(host: str, port: int, num_processes: int, process_id: int, timeout: float,
          coordinator: str) -> None:
  """Processes 1..N-1: says hello to process 0 (retrying until it listens), waits for ok."""
  deadline = time.monotonic() + timeout
  while True:
    left = deadline - time.monotonic()
    if left <= 0:
      raise UserError(f"coordinator {coordinator}: process 0 could not be reached within "
                      f"{timeout:.0f} s (is it started, with this address?)")
    try:
      conn = socket.create_connection((host, port), timeout=min(left, 2.0))
    except OSError:
      time.sleep(min(0.2, max(0.0, left)))
      continue
    with conn:
      try:
        conn.sendall(f"{HELLO} {process_id} {num_processes}\n".encode())
        answer = _read_line(conn, deadline)
      except OSError:
        answer = ""
    if answer == "ok":
      return
    if answer.startswith("error "):
      raise UserError(f"coordinator {coordinator}: {answer[len('error '):]}")
    time.sleep(0.2)  # the coordinator went away meanwhile: try again (until the deadline)


def initialize(coordinator: str, num_processes: Optional[int] = None,
               process_id: Optional[int] = None, timeout: float = 300.0) -> None:
  """Joins this process to the others (before any other JAX call).

  Args:
    coordinator: 'HOST:PORT' of process 0 (reachable from every process; process 0 listens
      on PORT), or 'auto': jax.distributed's own cluster detection (SLURM, Open MPI, TPU
      and cloud environments), which then supplies the count and the ids.
    num_processes, process_id: N and this process's id in 0..N-1 (with HOST:PORT).
    timeout: seconds to wait for every process to join.
  Raises:
    UserError with one line for a bad address, id or count, a coordinator that cannot be
    reached, a process that does not join, or a port already taken.
  """
  jax.config.update("jax_cpu_collectives_implementation", "gloo")
  if coordinator == "auto":
    try:
      jax.distributed.initialize(initialization_timeout=int(timeout))
    except (ValueError, RuntimeError) as e:
      raise UserError(f"--coordinator auto: {str(e).splitlines()[0]}") from None
    return
  host, port = parse_address(coordinator)
  if num_processes is None or process_id is None:
    raise UserError(f"coordinator {coordinator}: also give --num-processes and --process-id")
  if num_processes < 1:
    raise UserError(f"--num-processes {num_processes}: must be at least 1")
  if not 0 <= process_id < num_processes:
    raise UserError(f"--process-id {process_id}: out of range 0..{num_processes - 1} "
                    f"for {num_processes} processes")
  if timeout <= 0:
    raise UserError(f"--coordinator-timeout {timeout}: must be positive")
  if num_processes == 1:
    return
  if process_id == 0:
    _gather_joins(port, num_processes, timeout, coordinator)
  else:
    _join(host, port, num_processes, process_id, timeout, coordinator)
  # A process that stops alone (an error on one process) waits at most SHUTDOWN_SECONDS
  # for the others at exit; they end when it has gone (JAX's heartbeat) instead of waiting
  # in their next collective for ever.
  jax.distributed.initialize(coordinator, num_processes, process_id,
                             initialization_timeout=int(timeout),
                             heartbeat_timeout_seconds=HEARTBEAT_SECONDS,
                             shutdown_timeout_seconds=SHUTDOWN_SECONDS)


def is_primary() -> bool:
  """Whether this is process 0 (the one that writes the run folder)."""
  return jax.process_index() == 0


def _allgather(values: np.ndarray) -> np.ndarray:
  """[P, ...]: every process's `values` (int32), on every process."""
  return np.asarray(multihost_utils.process_allgather(np.asarray(values, np.int32)))


def check_same(value: Any, what: str) -> None:
  """UserError on every process unless `value` (JSON-able) is the same on all of them."""
  if jax.process_count() == 1:
    return
  digest = hashlib.sha256(json.dumps(value, sort_keys=True, default=str).encode()).digest()
  every = _allgather(np.frombuffer(digest, np.uint8))
  differ = [i for i in range(len(every)) if not np.array_equal(every[i], every[0])]
  if differ:
    raise UserError(f"the {what} of process{'es' if len(differ) > 1 else ''} "
                    f"{', '.join(map(str, differ))} differ from process 0's: start every "
                    "process with the same options")


def primary_first(fn: Callable, *args, **kwargs) -> Any:
  """`fn(*args, **kwargs)` on process 0 only (what writes the run folder); the others wait
  for it and stop too (UserError) when it fails. Returns fn's result on process 0, None on
  the others."""
  if jax.process_count() == 1:
    return fn(*args, **kwargs)
  result, error = None, None
  if is_primary():
    try:
      result = fn(*args, **kwargs)
    except BaseException as e:  # pylint: disable=broad-except
      error = e
  flags = _allgather(np.asarray([error is None]))
  if error is not None:
    raise error
  if not flags.all():
    raise UserError("process 0 stopped (see its message); this process stops too")
  return result


def agreed_stop(signum: Optional[int]) -> Optional[int]:
  """With several processes, a stop request (signal number) any of them received, so all
  stop at the same step; with one, `signum` itself."""
  if jax.process_count() == 1:
    return signum
  every = _allgather(np.asarray([signum or 0])).reshape(-1)
  return int(every.max()) or None
