"""Whether a run's result is accepted: decided once, here, and applied by every caller.

A result is *accepted* when
- its estimated coupling error (doubling.ErrorEstimate, a fixed-step co-simulation's step doubling) is at most
  `threshold` of every recorded variable's range (doubling.THRESHOLD; the command line's --error-threshold);
- every recorded value is finite;
- its last row is at the horizon (the run's stop time).
The engine already ends a run at a value that is not finite or an FMU's failure (a SimulationError, whose
result is partial anyway); the last two checks make the verdict hold for any Result, e.g. one read back
from a file.

Who applies it: `emcosim.run` raises errors.ResultNotAccepted (carrying the Result) or, with
accept="warn", returns the Result with a ResultNotAcceptedWarning; the command line prints the same
message and exits 5 (its rows kept as NAME.partial.csv); `emcosim.sweep` marks the run's row "not accepted:
..."; `emcosim.figure` marks the figure. The engine knows no physics: the values judged are the FMUs'.
"""
from __future__ import annotations

import math
import re
from dataclasses import dataclass, field
from typing import Mapping

from .doubling import THRESHOLD
from .errors import API_NAMES, OptionError

NOT_ACCEPTED = "not accepted: "
"""The start of the status of a run that is not accepted (a sweep's row; a figure's mark)."""

ACCEPT = ("raise", "warn")
"""What `emcosim.run(..., accept=...)` does with a result that is not accepted."""


class ResultNotAcceptedWarning(UserWarning):
    """emcosim.run(..., accept="warn") returned a result that is not accepted (its `verdict` says why)."""


@dataclass
class Verdict:
    """Whether a result is accepted (module doc), and if not why: `reasons` are (what, hint) pairs, `what` a
    plain sentence, `hint` how to get an accepted result, naming options as {option} (their API names: see
    `describe`)."""

    accepted: bool = True
    reasons: list[tuple[str, str]] = field(default_factory=list)
    threshold: float = THRESHOLD

    def summary(self) -> str:
        """One line without the hints: 'accepted', or NOT_ACCEPTED and the reasons."""
        return "accepted" if self.accepted else NOT_ACCEPTED + "; ".join(what for what, _ in self.reasons)

    def describe(self, names: Mapping[str, str] | None = None) -> str:
        """The reasons with their hints, each option named as `names` says (option -> the caller's name for it,
        e.g. the command line's flags; default: the Python API's names)."""
        spelled = {**API_NAMES, **(names or {})}
        return "; ".join(what + (" " + _spell(hint, spelled) if hint else "") for what, hint in self.reasons)

    def to_json(self) -> dict:
        return {"accepted": self.accepted, "threshold": self.threshold,
                "reasons": [what for what, _ in self.reasons]}


def _spell(template: str, names: Mapping[str, str]) -> str:
    """`template` with every {option} replaced by its name in `names` (the option itself if none)."""
    return re.sub(r"\{(\w+)\}", lambda m: names.get(m.group(1), m.group(1)), template)


def check_threshold(value: float | None) -> float:
    """The accepted fraction of a variable's range: `value` (a finite number > 0), or THRESHOLD for None."""
    if value is None:
        return THRESHOLD
    if not (isinstance(value, (int, float)) and math.isfinite(value) and value > 0):
        raise OptionError("{error_threshold} {value}: must be a positive number", "error_threshold",
                          value=f"{value:g}" if isinstance(value, (int, float)) else repr(value))
    return float(value)


def check_accept(value: str) -> str:
    if value not in ACCEPT:
        raise OptionError("{accept} {value!r}: must be one of " + ", ".join(repr(a) for a in ACCEPT), "accept",
                          value=value)
    return value


def judge(result, threshold: float = THRESHOLD, horizon: float | None = None) -> Verdict:
    """The verdict on `result` (a results.Result): its estimate against `threshold`, its values, and whether
    its last row is at `horizon` [s] (not checked for None)."""
    reasons: list[tuple[str, str]] = []
    estimate = getattr(result, "coupling_error", None)
    if estimate is not None and not estimate.accepted(threshold):
        reasons.append((f"{estimate.summary()}: above the accepted {threshold:g} of its range",
                        "({error_threshold}); a shorter {step_size}, {coupling} implicit or {tolerance} gives a "
                        "result that keeps it"))
    where = result.nonfinite
    if where is not None:
        reasons.append((f"{where[1]} is not finite at t = {where[0]:.9g} s", ""))
    last = result.last
    if horizon is not None and (last is None or not reached(last[0], horizon)):
        upto = "no row" if last is None else f"the last row is at t = {last[0]:.9g} s"
        reasons.append((f"the run does not reach its horizon {horizon:.9g} s ({upto})", ""))
    return Verdict(not reasons, reasons, threshold)


def reached(t: float, horizon: float) -> bool:
    """Whether a row at `t` [s] is at the horizon, up to the rounding of a sum of steps."""
    return t >= horizon - 1e-9 * max(abs(horizon), 1e-300)


__all__ = ["ACCEPT", "NOT_ACCEPTED", "ResultNotAcceptedWarning", "Verdict", "check_accept", "check_threshold",
           "judge", "reached"]
