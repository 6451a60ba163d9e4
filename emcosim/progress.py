"""Progress bars on stderr for `emcosim run`, `reproduce` and `sweep`, drawn by tqdm.

tqdm (not a bar of our own) handles terminal width, redraw rate, time estimates and several bars at
once; it is small, pure Python and widely used. Bars appear only on a terminal (`only_tty`) and
only once a run has taken longer than `delay` seconds, so logs and pipes stay clean.
"""
from __future__ import annotations

import sys
from typing import TextIO

from tqdm import tqdm

FORMAT = "{desc} {percentage:5.1f}%|{bar}| {elapsed}<{remaining}"


class ProgressBar:
    """A bar for one run: call it with the fraction done (0..1); call `close()` at the end."""

    def __init__(self, label: str = "", delay: float = 1.0, stream: TextIO | None = None,
                 only_tty: bool = True):
        self.stream = sys.stderr if stream is None else stream
        self._bar = tqdm(total=1.0, desc=label, file=self.stream, delay=delay,
                         disable=None if only_tty else False, bar_format=FORMAT,
                         dynamic_ncols=True, mininterval=0.1)

    def __call__(self, fraction: float) -> None:
        fraction = min(max(float(fraction), 0.0), 1.0)
        if fraction > self._bar.n:
            self._bar.update(fraction - self._bar.n)

    def write(self, line: str) -> None:
        """Print a line above the bar (plainly when there is no bar)."""
        self._bar.write(line, file=self.stream)

    def close(self) -> None:
        self._bar.close()


class Counter:
    """A bar counting finished items (runs of a sweep, scenarios of reproduce)."""

    def __init__(self, total: int, label: str = "", unit: str = "run", stream: TextIO | None = None,
                 only_tty: bool = True):
        self.stream = sys.stderr if stream is None else stream
        self._bar = tqdm(total=total, desc=label, unit=unit, file=self.stream,
                         disable=None if only_tty else False, dynamic_ncols=True, mininterval=0.1)

    def advance(self, postfix: str = "") -> None:
        if postfix:
            self._bar.set_postfix_str(postfix, refresh=False)
        self._bar.update(1)

    def write(self, line: str) -> None:
        """Print a line above the bar (or plainly when there is no bar)."""
        self._bar.write(line, file=self.stream)

    def close(self) -> None:
        self._bar.close()
