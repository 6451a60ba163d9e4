"""The error of a fixed-step co-simulation, estimated by step doubling on a sample of its steps.

A fixed step h that is too long for the loop (explicit coupling past its stability limit, or a step that
does not resolve the loop's fastest mode) gives a wrong result without any FMU failing. So every
fixed-step run estimates its own coupling error, without a second run:

1. At the sampled communication points t_n (`sampled`: n = 0, then every EVERY steps) the master saves
   every FMU's state (fmi2GetFMUstate) and the coupling's histories, takes two steps of h/2 (resolving
   the values and derivatives at t_n + h/2 as a run of step h/2 would), reads the recorded variables
   y_half at t_n + h, restores the states and takes the run's own step of h. At t_n + h the run's row
   y_h gives the doubling difference d = |y_h - y_half| per recorded variable.
2. The local error of the step of h is then e = d 2^p / (2^p - 1), p the global order of the coupling
   (coupling order + 1; implicit coupling 3): e = C h^(p+1) and two half steps make C h^(p+1) / 2^p.
3. The global error is bounded by the sum of the local errors of every step, as long as the loop does
   not amplify errors (a stable closed loop forgets them; an unstable one makes the local errors
   themselves grow, and then the estimate grows with them). Each sample stands for the steps up to the
   next one: E = sum_i e_i (n_{i+1} - n_i). For a loop that forgets its errors at a rate lam over a
   horizon T the bound is loose by up to a factor lam T; docs/scenarios.md gives the measured ratio to
   the true error on the paper's scenarios.
4. Relative to each recorded variable's range over the run (max - min; max |y| for a constant one): the
   run is *accepted* when every relative estimate is at most a threshold (THRESHOLD; the command line's
   --error-threshold). Nothing here knows the models: the values are the FMUs'.

Cost: a sample is one save and restore of every FMU, two half steps and three resolutions: about four
steps' worth, every EVERY = 50 steps: under 10 % of the run (benchmarks/bench_master.py prints it).
FMUs that cannot save their state (canGetAndSetFMUstate false) get no estimate (`ErrorEstimate.note`).
"""
from __future__ import annotations

import math
import time
from dataclasses import dataclass, field
from typing import Callable

from .errors import SimulationError
from .fmustate import States

THRESHOLD = 1e-2        # default: a run whose estimate exceeds this fraction of a variable's range is not accepted
FLOOR = 1e-2           # a variable's scale is at least this times its largest magnitude (`relative`)
FIRST = 16              # the first window: the first FIRST steps (at most a twentieth of the run)
SHORT = 20              # a run of at most SHORT steps is doubled whole
EVERY = 100             # then a window every EVERY steps
LENGTH = 2              # ... of LENGTH steps


@dataclass
class ErrorEstimate:
    """The estimated global coupling error of a fixed-step run, per recorded variable (module doc)."""

    columns: list[str]
    order: int                                  # p, the global order of the coupling
    steps: int = 0                              # communication steps of the run
    samples: int = 0                            # steps doubled
    absolute: list[float] = field(default_factory=list)    # E per recorded variable, in its unit
    low: list[float] = field(default_factory=list)         # its smallest and largest value over the run
    high: list[float] = field(default_factory=list)
    seconds: float = 0.0                        # wall time spent on the estimate
    note: str = ""                              # why there is no estimate, if there is none
    failure: str = ""                           # a doubled window that failed at half the step (not accepted)

    def relative(self) -> dict[str, float]:
        """E / scale per recorded variable: its range over the run (max - min), but at least FLOOR times its
        largest magnitude (a variable that swings by less than that about a large value, such as a bias flux
        or an energy, is judged against its value)."""
        out = {}
        for name, e, lo, hi in zip(self.columns, self.absolute, self.low, self.high):
            scale = max(hi - lo, FLOOR * max(abs(lo), abs(hi)))
            out[name] = e / scale if scale > 0 else (0.0 if e == 0 else math.inf)
        return out

    def worst(self) -> tuple[str, float]:
        """The recorded variable with the largest relative estimate, and that estimate."""
        rel = self.relative()
        if not rel:
            return "", 0.0
        name = max(rel, key=lambda k: rel[k])
        return name, rel[name]

    @property
    def available(self) -> bool:
        return not self.note and not self.failure and self.samples > 0

    def accepted(self, threshold: float = THRESHOLD) -> bool:
        """Every recorded variable's relative estimate at most `threshold` (True when there is no estimate,
        False when a doubled window failed where the run's own steps did not: the result depends on the step)."""
        if self.failure:
            return False
        return not self.available or self.worst()[1] <= threshold

    def summary(self) -> str:
        if self.failure:
            return f"coupling error: not estimated: {self.failure}"
        if not self.available:
            return f"coupling error: not estimated ({self.note or 'no step sampled'})"
        name, value = self.worst()
        return (f"estimated coupling error (step doubling on {self.samples} of {self.steps} steps, order {self.order}): "
                f"at most {value:.2g} of its range ({name})")


class StepDoubling:
    """Step doubling on windows of a fixed-step run's steps (module doc); driven by master._run_fixed."""

    def __init__(self, stepper, columns: list[str], order: int, n_steps: int):
        self.stepper = stepper
        self.report = ErrorEstimate(list(columns), order, steps=n_steps, absolute=[0.0] * len(columns))
        self.windows = windows(n_steps)
        unable = [name for name, inst in stepper.instances.items()
                  if not inst.model_description.coSimulation.canGetAndSetFMUstate]
        if unable:
            self.report.note = f"{', '.join(unable)} cannot save its state"
            self.windows = {}
        self.fmus = None if unable else States(list(stepper.instances.values()),
                                               "the master estimates the coupling error by step doubling")
        self._pending: dict[int, tuple[list[float], int]] = {}     # step -> (y_half there, its window's start)
        self._largest: dict[int, list[float]] = {}                  # window start -> largest |y_h - y_half|

    def sampled(self, n: int) -> bool:
        return n in self.windows

    def observe(self, n: int, row: list[float]) -> None:
        """The row recorded at step n (without its time): the values' range, and the doubling difference at a
        window's end."""
        r = self.report
        if not r.low:
            r.low, r.high = list(row), list(row)
        else:
            r.low = [min(a, b) for a, b in zip(r.low, row)]
            r.high = [max(a, b) for a, b in zip(r.high, row)]
        pending = self._pending.pop(n, None)
        if pending is not None:                   # a point of a doubled window: the largest difference so far
            half, start = pending
            largest = self._largest[start]
            self._largest[start] = [max(e, abs(a - b)) for e, a, b in zip(largest, row, half)]
            length, weight = self.windows[start]
            if n == start + length:               # the window's end: it stands for `weight` times its steps
                gain = 2 ** r.order / (2 ** r.order - 1) * weight
                r.absolute = [e + gain * d for e, d in zip(r.absolute, self._largest.pop(start))]

    def double(self, n: int, t: float, t_at: Callable[[int], float]) -> None:
        """At the window's first point t = t_at(n) (resolved, recorded): its steps taken as halves from the
        saved states, the values at its end kept, the states and the coupling's histories restored and t
        resolved again. t_at(m): the time of step m (the run's grid)."""
        tic = time.perf_counter()
        stepper = self.stepper
        length = self.windows[n][0]
        saved = _coupling_state(stepper)
        try:
            states = self.fmus.save(t)
        except SimulationError as exc:            # an FMU that declares state saving but refuses it: no estimate
            self.report.note = f"{exc}"
            self.windows = {}
            return
        try:
            try:
                self._halves(n, length, t_at)
            except SimulationError as exc:        # the main path goes on; its own failure, if any, is the run's
                self.fmus.restore(states, t)
                self.report.failure = f"the window from t = {t:.9g} s failed at half the step: {exc}"
                self.windows, self._pending, self._largest = {}, {}, {}
            else:
                self.fmus.restore(states, t)
        finally:
            self.fmus.free(states)
        _restore_coupling(stepper, saved)
        stepper.n_steps -= 2 * length
        stepper.t = t
        stepper.resolve()
        if not self.report.failure:
            self._largest[n] = [0.0] * len(self.report.columns)
            self.report.samples += length
        self.report.seconds += time.perf_counter() - tic

    def _halves(self, n: int, length: int, t_at: Callable[[int], float]) -> None:
        """The window's steps n .. n + length - 1 as two halves each; the rows at its points kept."""
        stepper = self.stepper
        for m in range(n, n + length):
            a, b = t_at(m), t_at(m + 1)
            middle = a + (b - a) / 2
            stepper.step(a, middle - a)
            stepper.t = middle
            stepper.resolve()
            stepper.step(middle, b - middle)
            stepper.t = b
            stepper.resolve()
            self._pending[m + 1] = (stepper.row(), n)


def windows(n_steps: int) -> dict[int, tuple[int, float]]:
    """The windows doubled: first step -> (its length in steps, the steps it stands for / its length). The
    first window covers the initial transient (FIRST steps, a twentieth of a run of more than EVERY steps if
    shorter; a run of at most SHORT steps is doubled whole, a Richardson estimate of its global error at a cost
    of milliseconds) and stands for itself; then one of LENGTH steps every EVERY steps (in a run of fewer, one in
    its middle), each standing for the steps from its start to the next window's (the second one also for those
    between the first window and itself): every step is counted once."""
    if n_steps <= SHORT:
        return {0: (n_steps, 1.0)}
    first = max(1, min(FIRST, n_steps // 20)) if n_steps > EVERY else min(FIRST, n_steps // 2)
    starts = [0] + list(range(max(EVERY, first), n_steps - 1, EVERY))
    if len(starts) == 1:
        starts.append(max(first, min(n_steps // 2, n_steps - LENGTH)))
    out = {0: (first, 1.0)}
    for i, n in enumerate(starts[1:], start=1):
        length = min(LENGTH, n_steps - n)
        following = starts[i + 1] if i + 1 < len(starts) else n_steps
        out[n] = (length, (following - (first if i == 1 else n)) / length)
    return out


def _histories(stepper) -> list:
    """The coupling's histories of the points before t (coupling.py): what a resolution records."""
    out = []
    d = stepper.derivatives
    if d is not None:
        out += [e.history for e in d.extrapolations]
        if d.guard is not None:
            out.append(d.guard.history)
    return out


def _coupling_state(stepper) -> tuple:
    """What the coupling learns from point to point (coupling.py, implicit.py), to be restored after a window."""
    guard = stepper.derivatives.guard if stepper.derivatives is not None else None
    return ([list(h.points) for h in _histories(stepper)],
            None if guard is None or guard.held is None else list(guard.held),
            None if stepper.implicit is None else stepper.implicit.save())


def _restore_coupling(stepper, saved: tuple) -> None:
    points, held, implicit = saved
    for history, kept in zip(_histories(stepper), points):
        history.points[:] = kept
    guard = stepper.derivatives.guard if stepper.derivatives is not None else None
    if guard is not None:
        guard.held = held
    if implicit is not None:
        stepper.implicit.restore(implicit)
