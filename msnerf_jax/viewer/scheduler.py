"""Progressive, latest-wins rendering for every connected client, on one worker thread.

Each client keeps only its latest request. After a change the client gets a low-resolution
frame as soon as the worker is free; once the request has not changed for `settle` seconds,
the full frame. A full frame in progress is abandoned (between bands) when its client sends
a newer request. Clients are served in turn, low frames before full ones, so one client
moving its camera non-stop cannot starve the others. One frame renders at a time: on a CPU
the renderer already uses every core.
"""

import collections
import threading
import time
import traceback
from typing import Any, Callable, Dict, Hashable, Optional, Tuple

# render(request, level, cancelled) -> frame or None (cancelled).
RenderFn = Callable[[Any, str, Callable[[], bool]], Any]
# deliver(client, frame, level, seconds)
DeliverFn = Callable[[Hashable, Any, str, float], None]


class _Client:
  __slots__ = ("request", "version", "changed_at", "low_done", "full_done")

  def __init__(self):
    self.request, self.version, self.changed_at = None, 0, 0.0
    self.low_done = self.full_done = 0


class Scheduler:
  """The render worker. `update(client, request)` from any thread; `remove(client)` when a
  client leaves; `stop()` ends the worker after its current band."""

  def __init__(self, render: RenderFn, deliver: DeliverFn, settle: float = 0.15):
    self._render, self._deliver, self._settle = render, deliver, settle
    self._clients: Dict[Hashable, _Client] = {}
    self._order: collections.deque = collections.deque()
    self._cond = threading.Condition()
    self._stopped = False
    self.frames = collections.Counter()  # (client, level) -> frames delivered
    self._thread = threading.Thread(target=self._work, name="msnerf-render", daemon=True)
    self._thread.start()

  def update(self, client: Hashable, request: Any) -> None:
    """The client's latest request (replaces any pending one)."""
    with self._cond:
      state = self._clients.get(client)
      if state is None:
        state = self._clients[client] = _Client()
        self._order.append(client)
      state.request, state.changed_at = request, time.monotonic()
      state.version += 1
      self._cond.notify_all()

  def remove(self, client: Hashable) -> None:
    with self._cond:
      if self._clients.pop(client, None) is not None:
        self._order.remove(client)
      for level in ("low", "full"):
        self.frames.pop((client, level), None)
      self._cond.notify_all()

  def stop(self, timeout: float = 10.0) -> None:
    with self._cond:
      self._stopped = True
      self._cond.notify_all()
    self._thread.join(timeout)

  def _next(self) -> Optional[Tuple[Hashable, Any, int, str]]:
    """The next job (client, request, version, level), waiting for one; None once stopped."""
    with self._cond:
      while not self._stopped:
        now, wake = time.monotonic(), None
        for level in ("low", "full"):
          for client in self._order:
            state = self._clients[client]
            if level == "low" and state.low_done < state.version:
              return self._take(client, state, level)
            if level == "full" and state.full_done < state.version:
              ready = state.changed_at + self._settle
              if ready <= now:
                return self._take(client, state, level)
              wake = ready if wake is None else min(wake, ready)
        self._cond.wait(None if wake is None else max(0.0, wake - now))
      return None

  def _take(self, client, state, level):
    self._order.remove(client)  # served: to the back of the queue.
    self._order.append(client)
    if level == "low":
      state.low_done = state.version
    return client, state.request, state.version, level

  def _current(self, client: Hashable, version: int) -> bool:
    state = self._clients.get(client)
    return state is not None and state.version == version

  def _work(self) -> None:
    while True:
      job = self._next()
      if job is None:
        return
      client, request, version, level = job
      # A low frame is quick and always shown; a full one is dropped when outdated.
      cancelled = ((lambda: self._stopped or not self._current(client, version))
                   if level == "full" else (lambda: self._stopped))
      start = time.perf_counter()
      failed = False
      try:
        frame = self._render(request, level, cancelled)
      except Exception:  # pylint: disable=broad-except
        traceback.print_exc()  # a bad frame must not end the viewer for every client.
        frame, failed = None, True
      seconds = time.perf_counter() - start
      with self._cond:
        state = self._clients.get(client)
        if state is None or (frame is None and not failed):
          continue
        if level == "full" and state.version == version:
          state.full_done = version  # also after a failure: not retried in a loop.
        if frame is None:
          continue
        self.frames[(client, level)] += 1
      try:
        self._deliver(client, frame, level, seconds)
      except Exception:  # pylint: disable=broad-except
        traceback.print_exc()  # e.g. the client left while the frame was sent.
