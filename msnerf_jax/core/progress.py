"""Progress of long work: a tqdm bar on a terminal, plain lines in a log or a pipe.

tqdm redraws its bar with carriage returns, which a log file or CI keeps as hundreds of
kilobytes of partial lines. Where the stream is not a terminal, `progress` prints one plain
line every `every_seconds` seconds or `every_percent` percent instead (whichever comes
first; the environment variable MSNERF_PROGRESS_PERCENT changes the 10), one at the start
and one at the end, so a summary printed afterwards stays the last line. `progress_bar`
picks one.
"""

import os
import sys
import time
from typing import Any, Iterable, Optional, TextIO

from tqdm.auto import tqdm


def _is_terminal(stream: TextIO) -> bool:
  try:
    return stream.isatty()
  except (AttributeError, ValueError):  # closed or replaced streams
    return False


class LineProgress:
  """The part of tqdm's interface the project uses (iterate, update, set_postfix, close),
  printed as plain lines: `desc: 250/3000 (8%) 12s loss=0.0123`."""

  def __init__(self, iterable: Optional[Iterable] = None, total: Optional[int] = None,
               initial: int = 0, desc: str = "", file: Optional[TextIO] = None,
               every_seconds: float = 60.0, every_percent: float = 10.0):
    self.iterable = iterable
    if total is None and iterable is not None and hasattr(iterable, "__len__"):
      total = initial + len(iterable)
    self.total, self.n, self.desc = total, initial, desc
    self.file = file or sys.stderr
    self.every_seconds, self.every_percent = every_seconds, every_percent
    self.postfix = ""
    self.start = self.last_time = time.time()
    self.last_n = initial
    self.closed = False
    self._print(self.start)  # where it starts (a resumed run: the step it resumes from)

  def __iter__(self):
    try:
      for item in self.iterable:
        yield item
        self.update(1)
    finally:
      self.close()

  def __len__(self):
    return self.total or 0

  def set_postfix(self, **values: Any) -> None:
    self.postfix = " ".join(f"{k}={v}" for k, v in values.items())

  def update(self, n: int = 1) -> None:
    self.n += n
    now = time.time()
    due = now - self.last_time >= self.every_seconds
    if self.total:
      step = max(1, round(self.total * self.every_percent / 100))
      due = due or self.n // step > self.last_n // step
    if due and self.n != self.total:
      self._print(now)

  def _print(self, now: float) -> None:
    count = (f"{self.n}/{self.total} ({100 * self.n / self.total:.0f}%)" if self.total
             else f"{self.n}")
    line = f"{self.desc}: {count} {now - self.start:.0f}s"
    print(f"{line} {self.postfix}".rstrip(), file=self.file, flush=True)
    self.last_time, self.last_n = now, self.n

  def close(self) -> None:
    if not self.closed:
      self.closed = True
      if self.n != self.last_n:
        self._print(time.time())


def progress_bar(iterable: Optional[Iterable] = None, *, total: Optional[int] = None,
                 initial: int = 0, desc: str = "", disable: Optional[bool] = False,
                 leave: bool = True, file: Optional[TextIO] = None):
  """A progress wrapper of `iterable` on `file` (default stderr): tqdm on a terminal,
  LineProgress elsewhere, or a silent tqdm when `disable` (None: silent off a terminal, for
  short work such as loading images)."""
  file = file or sys.stderr
  if disable is None:
    disable = not _is_terminal(file)
  if disable or _is_terminal(file):
    return tqdm(iterable, total=total, initial=initial, desc=desc, disable=disable,
                leave=leave, dynamic_ncols=True, file=file)
  every = os.environ.get("MSNERF_PROGRESS_PERCENT", "10")  # e.g. 1 for a line a percent
  try:
    every_percent = max(float(every), 0.001)
  except ValueError:
    every_percent = 10.0
  return LineProgress(iterable, total=total, initial=initial, desc=desc, file=file,
                      every_percent=every_percent)
