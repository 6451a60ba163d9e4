"""A tiny progress bar on stderr that appears only once a run has taken more than a second."""
from __future__ import annotations

import sys
import time
from typing import TextIO


class ProgressBar:
    """Call with the fraction done (0..1); call `close()` at the end."""

    def __init__(self, label: str = "", delay: float = 1.0, stream: TextIO | None = None, width: int = 30,
                 only_tty: bool = True):
        self.label, self.delay, self.width = label, delay, width
        self.stream = sys.stderr if stream is None else stream
        if only_tty and not getattr(self.stream, "isatty", lambda: False)():
            self.delay = float("inf")                 # no bar in logs and pipes
        self.start = time.monotonic()
        self.last = 0.0
        self.shown = False

    def __call__(self, fraction: float) -> None:
        now = time.monotonic()
        if now - self.start < self.delay or (now - self.last < 0.1 and fraction < 1.0):
            return
        self.last, self.shown = now, True
        fraction = min(max(fraction, 0.0), 1.0)
        filled = int(round(self.width * fraction))
        elapsed = now - self.start
        eta = elapsed * (1 - fraction) / fraction if fraction > 0 else float("nan")
        self.stream.write(f"\r{self.label} [{'#' * filled}{'.' * (self.width - filled)}] "
                          f"{100 * fraction:5.1f}%  {elapsed:6.1f} s elapsed, {eta:6.1f} s left ")
        self.stream.flush()

    def close(self) -> None:
        if self.shown:
            self.stream.write("\n")
            self.stream.flush()
