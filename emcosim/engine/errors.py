"""Errors the master reports as one line (the CLI prints the message and exits non-zero)."""
from __future__ import annotations

import signal as _signal


class ScenarioError(Exception):
    """A scenario, FMU or setting that cannot run; the message names the file or variable."""


class SimulationError(ScenarioError):
    """An FMU failed during the run. `result` holds what was computed before the failure."""

    def __init__(self, message: str, result=None):
        super().__init__(message)
        self.result = result


class Interrupted(SimulationError):
    """The run was stopped by a signal (SIGINT: Ctrl-C, SIGTERM: kill); `signal` is its number.
    The command line exits with 128 + signal, as a shell does for a process killed by it."""

    def __init__(self, signum: int, result=None):
        super().__init__(f"interrupted by {_signal.Signals(signum).name}", result)
        self.signal = signum
