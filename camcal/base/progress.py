"""A one-line progress bar on stderr: count, rate and time left of a long run.

On a terminal the line is redrawn in place (at most ten times a second);
in a log (stderr not a terminal) a plain line is printed every
``log_interval_s`` seconds, so farm logs show progress without control
characters.
"""

from __future__ import annotations

import sys
import time
from typing import TextIO

__all__ = ["Progress"]


class Progress:
    """Progress of ``total`` items: ``label [#####-----] 12/240  3.2 frames/s  ETA 1m11s``.

    Parameters
    ----------
    total : int
        Items expected.
    label : str
        What is counted (printed first).
    unit : str
        Unit of the rate (``frames`` gives ``frames/s``).
    stream : text stream, optional
        Where to draw (default ``sys.stderr``).
    log_interval_s : float
        Seconds between lines when ``stream`` is not a terminal.
    enabled : bool
        False draws nothing.
    """

    def __init__(self, total: int, label: str = "", unit: str = "items", stream: TextIO | None = None,
                 log_interval_s: float = 10.0, enabled: bool = True) -> None:
        self.total = int(total)
        self.label = label
        self.unit = unit
        self.stream = stream if stream is not None else sys.stderr
        self.enabled = enabled
        self.done = 0
        self.failed = 0
        self._start = time.perf_counter()
        self._tty = bool(getattr(self.stream, "isatty", lambda: False)())
        self._interval = 0.1 if self._tty else float(log_interval_s)
        self._last_draw = self._start

    @property
    def rate(self) -> float:
        """Items per second since the start."""
        elapsed = time.perf_counter() - self._start
        return self.done / elapsed if elapsed > 0 else 0.0

    def line(self, width: int = 24) -> str:
        """The text of the bar as it is now."""
        finished = self.done + self.failed
        share = finished / self.total if self.total else 1.0
        filled = int(round(share * width))
        rate = self.rate
        left = self.total - finished
        eta = f"ETA {_duration(left / rate)}" if rate > 0 and left > 0 else ""
        failed = f"  {self.failed} failed" if self.failed else ""
        return (f"{self.label} [{'#' * filled}{'-' * (width - filled)}] {finished}/{self.total}  "
                f"{rate:.2f} {self.unit}/s{failed}  {eta}").rstrip()

    def advance(self, failed: bool = False) -> None:
        """Count one finished item (``failed``: one that failed); redraw when due."""
        if failed:
            self.failed += 1
        else:
            self.done += 1
        now = time.perf_counter()
        if self.enabled and now - self._last_draw >= self._interval:
            self._draw()
            self._last_draw = now

    def report(self, done: int, total: int) -> None:
        """Callback form ``report(done, total)`` for numerical code: set the count, redraw when due, close at the end."""
        self.total = int(total)
        self.done = int(done) - self.failed
        now = time.perf_counter()
        if self.enabled and now - self._last_draw >= self._interval and done < total:
            self._draw()
            self._last_draw = now
        if done >= total:
            self.close()

    def close(self) -> None:
        """Draw the final state and end the line."""
        if self.enabled:
            self._draw()
            if self._tty:
                self.stream.write("\n")
            self.stream.flush()

    def _draw(self) -> None:
        if self._tty:
            self.stream.write("\r" + self.line() + "\x1b[K")
        else:
            self.stream.write(self.line() + "\n")
        self.stream.flush()


def _duration(seconds: float) -> str:
    seconds = int(round(seconds))
    if seconds < 60:
        return f"{seconds}s"
    if seconds < 3600:
        return f"{seconds // 60}m{seconds % 60:02d}s"
    return f"{seconds // 3600}h{seconds % 3600 // 60:02d}m"
