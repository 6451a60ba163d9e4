"""Stop a run cleanly on SIGINT (Ctrl-C) and SIGTERM, between two communication points.

Why not Python's default: the FMUs of this suite are Python code running in the host's interpreter
(pythonfmu), so the KeyboardInterrupt of the default SIGINT handler is raised in whatever frame runs,
often inside a slave's do_step called from C; pythonfmu turns it into a fatal FMU error with a
misleading message (and an interrupted run once ended in a SIGSEGV). SIGTERM's default ends the
process at once, so nothing computed is kept.

`on_signals()` (the command line wraps each command in it) only records the first signal; the
master's result recorder (`Result.append`) calls `check()` at every communication point and raises
`Interrupted` there, so the run stops between FMU calls and what it computed is kept. A second
signal raises `Signalled` (a KeyboardInterrupt) at once: a run stuck inside an FMU can still be
stopped. A process that runs no FMU itself (the sweep's client) uses graceful=False: every signal
raises `Signalled` at once.
"""
from __future__ import annotations

import signal
import threading
from contextlib import contextmanager
from typing import Iterator

from .errors import Interrupted

SIGNALS = (signal.SIGINT, signal.SIGTERM)
_requested: int | None = None            # the first signal received inside `on_signals`, if any


class Signalled(KeyboardInterrupt):
    """Raised at once by a signal (see `on_signals`); `signal` is its number. A KeyboardInterrupt, so
    that no `except Exception` on the way swallows it."""

    def __init__(self, signum: int):
        super().__init__(signal.Signals(signum).name)
        self.signal = signum


def requested() -> int | None:
    """The signal that asked the run to stop (None: go on)."""
    return _requested


def check() -> None:
    """Raise `Interrupted` if a stop was requested."""
    if _requested is not None:
        raise Interrupted(_requested)


@contextmanager
def on_signals(graceful: bool = True) -> Iterator[None]:
    """Handle SIGINT and SIGTERM inside the block. graceful: record the first signal (see `check`),
    raise `Signalled` on the second; not graceful: raise `Signalled` at once. Outside the main
    thread this does nothing."""
    global _requested
    if threading.current_thread() is not threading.main_thread():
        yield
        return

    def handler(signum, frame):
        global _requested
        if not graceful or _requested is not None:
            raise Signalled(signum)
        _requested = signum

    previous = {s: signal.signal(s, handler) for s in SIGNALS}
    _requested = None
    try:
        yield
    finally:
        for s, h in previous.items():
            signal.signal(s, h)
        _requested = None
