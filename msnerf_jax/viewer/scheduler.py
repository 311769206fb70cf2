"""Progressive, latest-wins rendering for every connected client, on one worker thread.

Each client keeps only its latest request. After a change the client gets a low-resolution
frame at its next turn; once the request has not changed for `settle` seconds, the full
frame. A full frame in progress is abandoned (between bands) when its client sends a newer
request. Low frames come first, clients in turn, and between two bands of a full frame the
worker draws the low frames others wait for, so moving cameras stay responsive whatever
the others do. One band renders at a time: on a CPU the renderer already uses every core.
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
  __slots__ = ("request", "version", "changed_at", "low_done", "full_done", "full_shown")

  def __init__(self):
    self.request, self.version, self.changed_at = None, 0, 0.0
    self.low_done = self.full_done = self.full_shown = 0


class Scheduler:
  """The render worker. `update(client, request)` from any thread; `remove(client)` when a
  client leaves; `stop()` ends the worker after its current band."""

  def __init__(self, render: RenderFn, deliver: DeliverFn, settle: float = 0.15):
    self._render, self._deliver, self._settle = render, deliver, settle
    self._clients: Dict[Hashable, _Client] = {}
    self._order: collections.deque = collections.deque()
    self._cond = threading.Condition()
    self._stopped = False
    self._served_since_full = set()  # clients given a low frame since the last full one
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

  def settled(self, client: Hashable) -> bool:
    """Whether the client's latest request has had its full frame delivered."""
    with self._cond:
      state = self._clients.get(client)
      return state is not None and state.full_shown == state.version

  def remove(self, client: Hashable) -> None:
    with self._cond:
      if self._clients.pop(client, None) is not None:
        self._order.remove(client)
      for level in ("low", "full"):
        self.frames.pop((client, level), None)
      self._served_since_full.discard(client)
      self._cond.notify_all()

  def stop(self, timeout: float = 10.0) -> None:
    with self._cond:
      self._stopped = True
      self._cond.notify_all()
    self._thread.join(timeout)

  def _next(self) -> Optional[Tuple[Hashable, Any, int, str]]:
    """The next job (client, request, version, level), waiting for one; None once stopped.

    Low frames, clients in turn; once every client waiting for one got one since the last
    full frame, a full frame: for the client whose camera came to rest most recently (its
    user is looking now) among those that have rested `settle` seconds.
    """
    with self._cond:
      while not self._stopped:
        now, wake, full, low = time.monotonic(), None, None, []
        for client in self._order:
          state = self._clients[client]
          if state.low_done < state.version:
            low.append(client)
          elif state.full_done < state.version:
            ready = state.changed_at + self._settle
            if ready > now:
              wake = ready if wake is None else min(wake, ready)
            elif full is None or state.changed_at > self._clients[full].changed_at:
              full = client
        if full is not None and all(c in self._served_since_full for c in low):
          self._served_since_full.clear()
          return self._take(full, self._clients[full], "full")
        if low:
          return self._take(low[0], self._clients[low[0]], "low")
        self._cond.wait(None if wake is None else max(0.0, wake - now))
      return None

  def _take(self, client, state, level):
    self._order.remove(client)  # served: to the back of the queue.
    self._order.append(client)
    if level == "low":
      state.low_done = state.version
      self._served_since_full.add(client)
    return client, state.request, state.version, level

  def _current(self, client: Hashable, version: int) -> bool:
    state = self._clients.get(client)
    return state is not None and state.version == version

  def _work(self) -> None:
    while True:
      job = self._next()
      if job is None:
        return
      self._run(job)

  def _run(self, job) -> None:
    client, request, version, level = job
    if level == "full":
      def cancelled():  # called between the bands of a full frame
        self._serve_low_frames()
        return self._stopped or not self._current(client, version)
    else:
      cancelled = lambda: self._stopped  # a low frame is quick and always shown.
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
        return
      if level == "full" and state.version == version:
        state.full_done = version  # also after a failure: not retried in a loop.
      if frame is None:
        return
      self.frames[(client, level)] += 1
    try:
      self._deliver(client, frame, level, seconds)
    except Exception:  # pylint: disable=broad-except
      traceback.print_exc()  # e.g. the client left while the frame was sent.
      return
    if level == "full":
      with self._cond:
        state.full_shown = max(state.full_shown, version)

  def _serve_low_frames(self) -> None:
    """Between two bands of a full frame: the low frames clients wait for (each once), so
    that moving cameras stay responsive while a full frame renders."""
    with self._cond:
      waiting = [c for c in self._order if self._clients[c].low_done < self._clients[c].version]
    for client in waiting:
      with self._cond:
        state = self._clients.get(client)
        if self._stopped or state is None or state.low_done >= state.version:
          continue
        job = self._take(client, state, "low")
      self._run(job)
