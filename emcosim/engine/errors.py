"""Errors the master reports as one line (the CLI prints the message and exits non-zero)."""
from __future__ import annotations


class ScenarioError(Exception):
    """A scenario, FMU or setting that cannot run; the message names the file or variable."""


class SimulationError(ScenarioError):
    """An FMU failed during the run. `result` holds what was computed before the failure."""

    def __init__(self, message: str, result=None):
        super().__init__(message)
        self.result = result
