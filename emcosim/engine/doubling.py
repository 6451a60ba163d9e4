"""The coupling error of a fixed-step co-simulation, estimated by step doubling on windows of its steps.

A fixed step h that is too long for the loop (explicit coupling past its stability limit, or a step that
does not resolve the loop's fastest mode) gives a wrong result without any FMU failing. So every
fixed-step run estimates its own coupling error, without a second run:

1. A window (`windows`) opens at a communication point t_n: the master saves every FMU's state
   (fmi2GetFMUstate) and the coupling's histories and takes the window's own steps, noting the pieces
   each was taken in (implicit coupling halves a step that does not converge). At the window's end it
   saves the run's state, goes back to t_n, takes every piece again as two halves (resolving the values
   and derivatives at the midpoints as a run at half the step would), reads the recorded variables y_half
   at the window's points and restores the run's state. d = max |y_h - y_half| per recorded variable.
   Halving the pieces, not the step: a step halved into pieces of 5, 5, 10 and 20 us and a step of half
   its length fall into the same pieces, and comparing them would show nothing.
2. The local error of the window is then e = d 2^p / (2^p - 1), p the global order of the coupling
   (coupling order + 1; implicit coupling 3): e = C h^(p+1) and two half steps make C h^(p+1) / 2^p.
3. The global error is bounded by the sum of the local errors of every step, as long as the loop does
   not amplify errors (a stable closed loop forgets them; an unstable one makes the local errors
   themselves grow, and then the estimate grows with them). Each window stands for the steps up to the
   next one: E = sum_i e_i (n_{i+1} - n_i) / length_i. For a loop that forgets its errors at a rate lam
   over a horizon T the bound is loose by up to a factor lam T; docs/scenarios.md gives the measured ratio
   to the coupling error on the paper's scenarios.
4. Relative to each recorded variable's range over the run (max - min; max |y| for a constant one): the
   run is *accepted* when every relative estimate is at most a threshold (THRESHOLD; the command line's
   --error-threshold). Nothing here knows the models: the values are the FMUs'.

What it is: the coupling error, the distance from what the same FMUs give at a much shorter communication
step. The FMUs' own integration error is the same at every step and is not in it (docs/scenarios.md).
Cost: a budget (`windows`): BUDGET of the run's steps over COST, the measured cost of a doubled step in steps
of the run (a save and restore of every FMU twice, two half steps per piece, their resolutions; implicit
coupling's iterations at a new step size), at least MINIMUM steps: 1-6 % of a run of more than SHORT steps on
the paper scenarios (benchmarks/bench_master.py prints it). FMUs that cannot save their state
(canGetAndSetFMUstate false) get no estimate (`ErrorEstimate.note`).
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
BUDGET = 0.05           # the estimate's cost: about this fraction of the run's own steps (`windows`)
COST = {"explicit": 3.5, "implicit": 6.5}   # a doubled step's nominal cost in steps of the run (measured on
                                            # the paper scenarios: 0.5-4 explicit, 6.5-9 implicit; so the
                                            # estimate costs 1-7 % of a run, docs/scenarios.md)
MINIMUM = 2             # steps doubled at least
FIRST = 16              # the first window: at most FIRST steps (two thirds of the budget)
SHORT = 20              # a run of at most SHORT steps is doubled whole
LENGTH = 2              # the later windows' length in steps
JACOBIANS = 8           # implicit coupling's Jacobians at the halves kept from window to window


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
    """Step doubling on windows of a fixed-step run's steps (module doc); driven by master._run_fixed: `begin` at
    a window's first point (before the run's own step), `observe` at every point, `finish` at a window's last
    point (after the run's own steps and the row there)."""

    def __init__(self, stepper, columns: list[str], order: int, n_steps: int):
        self.stepper = stepper
        self.report = ErrorEstimate(list(columns), order, steps=n_steps, absolute=[0.0] * len(columns))
        self.implicit = stepper.implicit
        self.windows = windows(n_steps, COST["implicit" if self.implicit is not None else "explicit"])
        self.ends = {n + length: n for n, (length, _) in self.windows.items()}
        unable = [name for name, inst in stepper.instances.items()
                  if not inst.model_description.coSimulation.canGetAndSetFMUstate]
        if unable:
            self.report.note = f"{', '.join(unable)} cannot save its state"
            self.windows, self.ends = {}, {}
        self.fmus = None if unable else States(list(stepper.instances.values()),
                                               "the master estimates the coupling error by step doubling")
        self._start: tuple | None = None             # (window start n, t, FMU states, coupling state) while open
        self._rows: dict[int, list[float]] = {}      # step -> the run's own row there (in the open window)
        self._pieces: dict[int, list[tuple[float, float]]] = {}   # step m -> the pieces (t, h) of the run's step m
        self._halved_jacobians: dict[float, object] = {}          # implicit coupling's Jacobians at the halves

    def sampled(self, n: int) -> bool:
        return n in self.windows

    def closes(self, n: int) -> bool:
        return n in self.ends and self._start is not None

    def observe(self, n: int, row: list[float]) -> None:
        """The row recorded at step n (without its time): the values' range; in an open window, the row and the
        pieces the run's step to it was taken in (implicit coupling halves a step that does not converge)."""
        r = self.report
        if not r.low:
            r.low, r.high = list(row), list(row)
        else:
            r.low = [min(a, b) for a, b in zip(r.low, row)]
            r.high = [max(a, b) for a, b in zip(r.high, row)]
        if self._start is not None and n > self._start[0]:
            self._rows[n] = list(row)
            if self.implicit is not None:
                self._pieces[n - 1], self.implicit.pieces = self.implicit.pieces, []

    def begin(self, n: int, t: float) -> None:
        """At a window's first point t (resolved, recorded): every FMU's state and the coupling's saved, the
        pieces of the run's steps traced."""
        try:
            states = self.fmus.save(t)
        except SimulationError as exc:            # an FMU that declares state saving but refuses it: no estimate
            self.report.note = f"{exc}"
            self.windows, self.ends = {}, {}
            return
        self._start = (n, t, states, _coupling_state(self.stepper))
        self._rows, self._pieces = {}, {}
        if self.implicit is not None:
            self.implicit.pieces = []

    def close(self) -> None:
        """Free the states of a window left open (the run ended inside it)."""
        if self._start is not None:
            self.fmus.free(self._start[2])
            self._start = None

    def finish(self, n_end: int, t_end: float, t_at: Callable[[int], float]) -> None:
        """At the window's last point t_end (the run's row there recorded): the run's state saved, the window's
        steps taken again from its first point, every piece of them as two halves, the largest difference of the
        recorded values from the run's own rows kept, and the run's state at t_end restored."""
        tic = time.perf_counter()
        stepper, (n, t, states, saved) = self.stepper, self._start
        self._start = None
        if self.implicit is not None:
            self.implicit.pieces = None
        length = n_end - n
        pieces = {m: self._pieces.get(m) or [(t_at(m), t_at(m + 1) - t_at(m))] for m in range(n, n_end)}
        here, steps = _coupling_state(stepper), stepper.n_steps
        try:
            end_states = self.fmus.save(t_end)
        except SimulationError as exc:
            self.fmus.free(states)
            self.report.note = f"{exc}"
            self.windows, self.ends = {}, {}
            return
        try:
            try:
                self.fmus.restore(states, t)
                _restore_coupling(stepper, saved)
                largest = self._halves(n, n_end, t, pieces)
            except SimulationError as exc:        # the run goes on; its own failure, if any, is its own
                self.report.failure = f"the window from t = {t:.9g} s failed at half the step: {exc}"
                self.windows, self.ends = {}, {}
            else:
                gain = 2 ** self.report.order / (2 ** self.report.order - 1) * self.windows[n][1]
                self.report.absolute = [e + gain * d for e, d in zip(self.report.absolute, largest)]
                self.report.samples += length
            self.fmus.restore(end_states, t_end)
        finally:
            self.fmus.free(states)
            self.fmus.free(end_states)
        _restore_coupling(stepper, here)
        stepper.n_steps = steps
        stepper.t = t_end
        stepper._values_at = None                 # the values at t_end resolved again from the run's states
        stepper.resolve()
        self.report.seconds += time.perf_counter() - tic

    def _halves(self, n: int, n_end: int, t: float, pieces: dict[int, list[tuple[float, float]]]) -> list[float]:
        """The window's steps again from t, each piece of them as two halves (values and derivatives resolved at
        every midpoint, as a run at half the step would); the largest |y_h - y_half| at its points."""
        stepper = self.stepper
        stepper.t = t
        stepper._values_at = None
        stepper.resolve()
        implicit = self.implicit
        if implicit is not None:                  # the halves' own Jacobians, kept from window to window
            own = set(implicit.kept)
            implicit.kept = {**implicit.kept, **self._halved_jacobians}
        largest = [0.0] * len(self.report.columns)
        for m in range(n, n_end):
            for a, h in pieces[m]:
                middle, b = a + h / 2, a + h
                stepper.step(a, middle - a)
                stepper.t = middle
                stepper.resolve()
                stepper.step(middle, b - middle)
                stepper.t = b
                stepper.resolve()
            row = self._rows[m + 1]
            largest = [max(e, abs(x - y)) for e, x, y in zip(largest, row, stepper.row())]
        if implicit is not None:
            halved = [(step, J) for step, J in implicit.kept.items() if step not in own]
            self._halved_jacobians = dict(halved[-JACOBIANS:])
        return largest


def windows(n_steps: int, cost: float = 0.0) -> dict[int, tuple[int, float]]:
    """The windows doubled: first step -> (its length in steps, the steps it stands for / its length).

    A run of at most SHORT steps is doubled whole (a Richardson estimate of its global error). Otherwise the
    budget: BUDGET of the run's steps over `cost`, what a doubled step costs in steps of the run (COST of the
    coupling), but at least MINIMUM steps. Two thirds of it (at most FIRST steps) are the first window, which covers
    the initial transient and stands for itself; the rest are windows of LENGTH steps (one shorter window where
    less is left) in the middles of equal spans of the remaining steps, each standing for the steps from its
    start to the next window's (the first of them also for those between the first window and itself): every
    step is counted once."""
    if n_steps <= SHORT:
        return {0: (n_steps, 1.0)}
    budget = min(n_steps, max(MINIMUM, int(BUDGET * n_steps / (cost or COST["explicit"]))))
    first = min(FIRST, max(1, 2 * budget // 3))
    rest = budget - first
    length = min(LENGTH, rest)
    count = max(1, rest // length)
    span = (n_steps - first) / count
    starts = [first + int(i * span + (span - length) / 2) for i in range(count)]
    out = {0: (first, 1.0)}
    for i, n in enumerate(starts):
        following = starts[i + 1] if i + 1 < count else n_steps
        out[n] = (length, (following - (first if i == 0 else n)) / length)
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
