"""Errors the engine reports: one line each, with fields a caller can read.

The engine names its settings as its Python API does (`step_size`, `max_steps`, `start_values`); a caller
with other names for them (the command line's flags) renders the message with its own names:
`error.describe(names)`. The command line prints that line and exits non-zero.
"""
from __future__ import annotations

import signal as _signal
from typing import Any, Mapping

# how a message names an option when the caller gives no names of its own (the Python API's words)
API_NAMES = {"start_values": "start value"}


class ScenarioError(Exception):
    """A scenario, FMU or setting that cannot run; the message names the file or variable."""

    def describe(self, names: Mapping[str, str] | None = None) -> str:
        """The message, with options named as `names` says (option -> the caller's name for it)."""
        return str(self)


class OptionError(ScenarioError):
    """A setting of a run that cannot be used: `options` are the settings the message names (by their API
    names: "step_size", "max_steps", "start_values", ...), `fields` the numbers in it. The message is a
    template in which each option appears as {option}; `describe(names)` fills in the caller's names."""

    def __init__(self, template: str, *options: str, **fields: Any):
        self.template, self.options, self.fields = template, options, fields
        super().__init__(self.describe())

    def describe(self, names: Mapping[str, str] | None = None) -> str:
        spelled = {**API_NAMES, **(names or {})}
        return self.template.format(**{o: spelled.get(o, o) for o in self.options}, **self.fields)


class LimitError(OptionError):
    """A run or an archive beyond a limit (`option`: the option that raises it, e.g. "max_steps")."""

    def __init__(self, template: str, option: str, *options: str, **fields: Any):
        self.option = option
        super().__init__(template, option, *options, **fields)


class SimulationError(ScenarioError):
    """An FMU failed during the run. `result` holds what was computed before the failure."""

    def __init__(self, message: str, result=None):
        super().__init__(message)
        self.result = result


class ResultNotAccepted(SimulationError):
    """The run completed, but its result is not accepted (verdict.py: its estimated coupling error above the
    threshold, a value that is not finite, or the horizon not reached). `verdict` says why, `result` holds
    the rows (a partial result: plot it, marked). `emcosim.run` raises it (accept="warn" returns the result
    with a warning instead); the command line warns, keeps the rows as NAME.partial.csv and exits with
    status 5 (docs/cli.md)."""

    def __init__(self, verdict, result=None):
        self.verdict = verdict
        super().__init__(verdict.describe(), result)

    def describe(self, names: Mapping[str, str] | None = None) -> str:
        return self.verdict.describe(names)


NotAccepted = ResultNotAccepted               # its name before issue 41


class Interrupted(SimulationError):
    """The run was stopped by a signal (SIGINT: Ctrl-C, SIGTERM: kill); `signal` is its number.
    The command line exits with 128 + signal, as a shell does for a process killed by it."""

    def __init__(self, signum: int, result=None):
        super().__init__(f"interrupted by {_signal.Signals(signum).name}", result)
        self.signal = signum
