"""Stop requests during training: SIGTERM (a cluster's preemption, `kill`) and Ctrl-C.

While `stop_requests()` is active the first SIGTERM or SIGINT only records itself; the
training loop sees it after the step in flight, saves a checkpoint at that step and raises
`Interrupted`. A second signal stops at once (KeyboardInterrupt), as users expect of a
second Ctrl-C. Handlers can only be set from the main thread; elsewhere nothing changes.
"""

import contextlib
import signal
import threading
from typing import Callable, Iterator, Optional

STOP_SIGNALS = (signal.SIGTERM, signal.SIGINT)


@contextlib.contextmanager
def stop_requests() -> Iterator[Callable[[], Optional[int]]]:
  """Yields `requested()`: the number of the first stop signal received, or None."""
  if threading.current_thread() is not threading.main_thread():
    yield lambda: None
    return
  received = []

  def handler(signum, frame):  # pylint: disable=unused-argument
    if received:
      raise KeyboardInterrupt
    received.append(signum)

  previous = {s: signal.signal(s, handler) for s in STOP_SIGNALS}
  try:
    yield lambda: received[0] if received else None
  finally:
    for s, h in previous.items():
      signal.signal(s, h)
