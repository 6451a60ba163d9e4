"""Communication steps chosen for a global tolerance (the run's `tolerance`).

What is controlled: the error of the recorded variables at the communication points, each relative
to the largest magnitude it reaches in the run (the values seen, not a model's scale), over the whole
run: the run aims at max_t |y(t) - y_exact(t)| / max_t |y(t)| of about TOL/2 for every recorded y.
Nothing here knows the models; the error measures come from the FMUs' values.

How (docs/scenarios.md, "Steps that keep a tolerance"):

1. Local error: the extrapolation defect of the coupling. Over a step [t, t + h] a connected input
   follows the polynomial the master handed over at t (its value, plus its derivatives with
   higher-order coupling; coupling.py). At t + h the master reads the true value; the defect
   d = max |u(t + h) - P(h)| / max_t |u| is the coupling error the step made, O(h^p) with p the
   global order (coupling order + 1). It is measured on the inputs of FMUs that integrate them
   (FMUs with an output not fed through from an input, i.e. with states; an FMU whose outputs all
   depend on its inputs is treated as static: its inputs act through its outputs at the
   communication points). A step with d > 2 eps is rejected: every FMU is rolled back
   (fmi2SetFMUstate) and the step retried shorter. The next step is h (eps / d)^(1/p), in [h/5, 2h]:
   every step makes a defect of about eps, an error per unit step (an input's defect acts on the
   solution for as long as the step lasts).
2. Global error: lockstep Richardson extrapolation. A shadow copy of the FMUs (FMUs without
   connected inputs are shared: their outputs depend on time only) takes one step of 2h for every
   two steps of h of the main copy, over the same communication points. Global errors go as h^p, so
   the main copy's global error is E = |y_shadow - y_main| / (rho - 1) per recorded variable,
   relative to its largest magnitude, with rho = 2^p, or the ratio of the two copies' defects over
   the run where that is larger (a long step outside the asymptotic range). A long step whose
   defect exceeds what a step of 2h may make (2^p * 2 eps) has left that range, typically the
   stability limit of explicit coupling of a stiff loop: the step is rejected and halved, and that
   bound is learnt (it rises by 2 % per step).
3. Calibration: how much global error a defect level eps produces (what accumulates, how fast the
   closed loop forgets) depends on the models. The run measures C = max_t E(t) (t - t0) / int eps
   dt and keeps eps = min(aim, aim / C), aim = TOL/2. It starts at eps = aim and never rises
   within a run (an estimate grows only after the error has accumulated: raising eps on a small
   early estimate spends the budget in the initial transient).
4. A second run: when the run's largest estimate ends outside [0.2, 1.5] TOL although the steps
   were not held by the maximum step or the stability bound, the scenario is run again with
   eps = aim / C from the first run's calibration (the global error is proportional to eps).

A step below the resolution of time (4 ulp of the horizon's end, as `options.experiment` refuses for a
fixed step) ends the run with `StepBelowResolution`: a tolerance that the values' rounding cannot
meet (e.g. 1e-15, where a defect of a few ulp is rejected) would otherwise shrink the step until
t + h == t and hand a step of 0 to fmi2DoStep, which the first FMU refuses with its own message.

Cost: the shadow copy adds half a step of every FMU with inputs per communication step, plus an
FMU-state save of both copies per two steps (rollback). The report gives the steps taken and
rejected, the runs, and the estimated error.
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any, Callable, Mapping

from . import implicit
from .errors import ScenarioError, SimulationError
from .fmustate import States
from .history import History, taylor

AIM = 0.5             # aim of the global error, relative to the tolerance
REJECT = 2.0          # a step with a defect above REJECT * eps is retried
SAFETY = 0.9
GROW, SHRINK = 2.0, 0.2
LOW, HIGH = 0.2, 1.5  # a run whose estimate ends outside [LOW, HIGH] * tolerance is run again
SUBSTEPS = 2          # steps of the main copy per step of the shadow copy
LEVEL_FLOOR = 1e-4    # eps never falls below this times the aim (a diverging estimate cannot stall the run)
STABLE_GROWTH = 1.02  # a step bound learnt from an unstable long step rises this much per step
KEEP = 1.5            # implicit coupling: a step that could grow by less than this keeps its size (as
                      # stiff solvers keep h and their Jacobian, e.g. Radau5): a new size costs a new Jacobian
ITERATION = 0.1       # implicit coupling: the inputs' residual at the end of a step, relative to eps
RUNG = 2 ** 0.25      # implicit coupling: steps on the rungs h_max / RUNG^k, so that step sizes recur and
                      # the iteration's Jacobians kept per size (implicit.py) serve them again


class StepBelowResolution(SimulationError):
    """The step the control wants is below the resolution of time: the run's tolerance cannot be kept.
    The message names the tolerance as `describe(names)` spells it (the command line: --tolerance)."""

    def __init__(self, template: str, **fields: Any):
        self.template, self.fields = template, fields
        super().__init__(self.describe())

    def describe(self, names: Mapping[str, str] | None = None) -> str:
        return self.template.format(tolerance=(names or {}).get("tolerance", "tolerance"), **self.fields)


def resolution(t0: float, t_stop: float) -> float:
    """The smallest communication step [s] time can resolve over [t0, t_stop]: 4 ulp of its far end
    (the bound `options.experiment` puts on a fixed step)."""
    return 4 * math.ulp(max(abs(t0), abs(t_stop)))


@dataclass
class StepReport:
    """What the error-controlled run did."""

    tolerance: float
    coupling_order: int           # derivatives passed on the connections (0: zero-order hold)
    accepted: int = 0             # communication steps taken
    rejected: int = 0             # steps rolled back and retried (each of two communication steps)
    h_min: float = math.inf       # smallest and largest communication step taken [s]
    h_max: float = 0.0
    estimated_error: float = 0.0  # largest global error estimate of the run (relative, see module doc)
    level: float = 0.0            # final defect level eps
    held: float = 0.0             # fraction of the steps held by the maximum step or the stability bound
    passes: int = 1               # runs made (a second one when the first missed the aim, see `run`)
    next_level: float | None = None   # the level a second run should take (None: none needed)

    def summary(self) -> str:
        again = f" in {self.passes} runs" if self.passes > 1 else ""
        held = f", {100 * self.held:.0f}% held by the maximum step or stability" if self.held >= 0.05 else ""
        return (f"{self.accepted} communication steps{again} ({self.rejected} rejected), steps {self.h_min:.3g} s to "
                f"{self.h_max:.3g} s{held}, estimated error {self.estimated_error:.2g} (tolerance {self.tolerance:g}, "
                f"coupling order {self.coupling_order})")


class _Defect:
    """The extrapolation defect of the connected inputs of a copy (module docstring, 1).

    With implicit coupling (implicit.py) an input follows the chord from u(t) to u(t + h), which
    meets u(t + h) by construction; its defect is then the chord's distance from the parabola through
    the point before, u(t) and u(t + h): |u''| h^2 / 8 with u'' their second divided difference, the
    O(h^2) deviation of a second-order coupling (at the first step, with no point before: |u(t + h) - u(t)|)."""

    def __init__(self, stepper):
        self.slots = stepper.slots
        d = stepper.derivatives
        self.implicit = stepper.implicit
        self.chord = stepper.implicit is not None
        inputs = stepper.plan.input_slots
        dynamic = [(name, s) for name, s in inputs if name.partition(".")[0] in stepper.plan.dynamic]
        if self.chord:                                  # the implicit inputs; their derivatives from `implicit`
            self.inputs = [(s, []) for s in stepper.implicit.slots]
        else:
            self.inputs = [(s, d.polynomial(name) if d is not None else []) for name, s in dynamic or inputs]
        self.dvalues = d.values if d is not None else []
        self.scale = [0.0] * len(self.inputs)
        self.start: list = []
        self.d_start: list[float] = []
        self.history = History()                           # t -> start of the points before (chords)
        self.before: tuple[float, list] | None = None

    def observe(self, t: float) -> None:
        """Take the polynomials handed over at the point t (after resolve)."""
        slots, dv, scale = self.slots, self.dvalues, self.scale
        start = []
        for i, (s, ds) in enumerate(self.inputs):
            v = slots[s]
            if abs(v) > scale[i]:
                scale[i] = abs(v)
            start.append((v, [dv[j] for j in ds]))
        self.start = start
        if self.chord:
            self.d_start = self.implicit.source_derivatives()
            self.before = self.history.last(t)          # a rolled-back step leaves no point behind
            self.t = t
            self.history.add(t, start)

    def measure(self, h: float) -> float:
        """max |u(t + h) - P(h)| / max |u| after a step of h (after resolve at t + h)."""
        if self.chord:
            return self._chord(h)
        slots, scale = self.slots, self.scale
        worst = 0.0
        for i, ((s, _), (v, ders)) in enumerate(zip(self.inputs, self.start)):
            p = taylor(v, ders, h)
            new = slots[s]
            sc = max(scale[i], abs(new))
            if sc > 0:
                worst = max(worst, abs(new - p) / sc)
        return worst

    def _chord(self, h: float) -> float:
        slots, scale, mode = self.slots, self.scale, self.implicit.mode
        d_end = self.implicit.source_derivatives()
        worst = 0.0
        for i, ((s, _), (v, _)) in enumerate(zip(self.inputs, self.start)):
            new = slots[s]
            u_prev, h_prev = (None, 0.0) if self.before is None else (self.before[1][i][0], self.t - self.before[0])
            d_prev, d = (self.d_start[i], d_end[i]) if d_end and self.d_start else (None, 0.0)
            e = implicit.deviation(mode, u_prev, h_prev, d_prev, v, new, d, h)
            sc = max(scale[i], abs(new))
            if sc > 0:
                worst = max(worst, e / sc)
        return worst


def check_rollback(stepper, t0: float, h: float) -> None:
    """Step, restore the state, step again: both must give the same values, or an FMU does not
    really restore its state (e.g. an integrator state kept outside its registered variables)."""
    fmus = States(stepper.order, "the step control rolls it back")
    states = fmus.save(t0)
    rows = []
    implicit, stepper.implicit = stepper.implicit, None     # the FMUs' rollback only (an iteration's
    try:                                                      # Jacobian would differ between the two)
        for _ in range(2):
            stepper.t = t0
            stepper.resolve()
            stepper.step(t0, h)
            stepper.t = t0 + h
            stepper.resolve()
            rows.append(stepper.row())
            fmus.restore(states, t0)
    finally:
        fmus.free(states)
        stepper.implicit = implicit
    stepper.t = t0
    stepper.n_steps -= 2
    if rows[0] != rows[1]:
        bad = [c for c, a, b in zip(stepper.plan.columns, *rows) if a != b]
        raise ScenarioError(f"error-controlled steps need FMU-state rollback, but repeating a restored step "
                            f"changes {', '.join(bad[:4])}: an FMU does not restore its full state")


@dataclass
class _Trial:
    """One trial of a double step of the main copy (two steps of h) and of the shadow copy (one of 2h) from t."""

    t: float
    H: float                      # the double step
    last: bool                    # it ends the run
    states: list                  # the FMU states at t (rolled back to on rejection)
    rows: list                    # [(time, row)] of the main copy at its two points
    worst: float = 0.0            # the main copy's largest defect
    far_worst: float = 0.0        # the shadow copy's defect
    end: float = 0.0              # the time reached
    factor: float | None = None   # None: accepted; else the step is rejected and shrunk by this factor
    failure: SimulationError | None = None


class StepControl:
    """The error-controlled run of the copies `main` (recorded into `result`) and `shadow` (steppers over
    the same scenario, initialized at t0): `run` tries a double step (`try_step`), then `accept`s or
    `reject`s it, until t_stop. h0: first step; h_max: largest step; coupling_order: the degree of the
    inputs' polynomials; level: the defect level to start from (default: the aim). When the run's largest
    estimate misses the aim by far (below LOW or above HIGH times the tolerance, and the steps were not held
    by h_max), the report's next_level is the level a second run should keep: aim / C with the calibration
    C of this whole run (tolerance proportionality: the error scales with the level)."""

    def __init__(self, main, shadow, result, t0: float, t_stop: float, tolerance: float, h0: float, h_max: float,
                 coupling_order: int, progress: Callable[[float], None] | None = None, level: float | None = None):
        self.main, self.shadow, self.result, self.progress = main, shadow, result, progress
        self.t0, self.t_stop, self.h_max = t0, t_stop, h_max
        self.p = coupling_order + 1
        self.report = StepReport(tolerance, coupling_order)
        self.aim = AIM * tolerance
        self.level = level
        self.eps = self.aim if level is None else level
        self.capped = self.macro = 0
        self.calibration = 0.0
        self.spent = 0.0                                     # integral of the level eps over the run
        self.near = self.far_sum = 0.0                       # integrals of the two copies' defects
        self.fmus = States(main.order + shadow.order, "a rejected step rolls it back")
        self.defect, self.far_defect = _Defect(main), _Defect(shadow)
        self.h = min(h0, h_max)
        self.h_floor = resolution(t0, t_stop)
        self.h_stable = math.inf
        self.t = t0
        self.last_defect = (0.0, 0.0)                        # the two copies' defects at the last rejection

    def run(self) -> StepReport:
        try:
            self.start()
            while self.t < self.t_stop:
                trial = self.try_step()
                if trial.factor is None:
                    self.accept(trial)
                else:
                    self.reject(trial)
        except SimulationError as exc:
            exc.result = self.result
            raise
        return self.finish()

    def start(self) -> None:
        for copy in (self.main, self.shadow):
            copy.t = self.t0
            copy.resolve()
        row = self.main.row()
        self.result.append(self.t0, row)
        self.scale = [abs(v) for v in row]
        self.largest = [0.0] * len(row)                      # largest absolute estimate of each variable

    def try_step(self) -> _Trial:
        """Two steps of h of the main copy and one of 2h of the shadow copy from t; the trial's factor says
        whether and how to reject it (a defect too large, or an FMU that failed on the long step)."""
        main, shadow, t, eps = self.main, self.shadow, self.t, self.eps
        if main.implicit is not None:
            self.h = self.h_max / RUNG ** math.ceil(math.log(self.h_max / self.h, RUNG) - 1e-9)
        if self.h < self.h_floor:
            self._below_resolution()
        H = min(SUBSTEPS * self.h, self.t_stop - t)
        last = self.t_stop - (t + H) <= 0.1 * H
        if last:
            H = self.t_stop - t
        trial = _Trial(t, H, last, self.fmus.save(t), [], end=t)
        for copy in (main, shadow):
            if copy.implicit is not None:                    # the inputs agree to a tenth of the defect level
                copy.implicit.tolerance = max(ITERATION * eps, implicit.ITERATION_FLOOR)
        if main.implicit is not None:                        # chords after a target refused order 2
            self.p = main.implicit.degree + 1
        p = self.p
        try:
            tt = t
            for j in range(SUBSTEPS):
                t_next = self.t_stop if last and j == SUBSTEPS - 1 else t + (j + 1) * H / SUBSTEPS
                self.defect.observe(tt)
                main.step(tt, t_next - tt)
                main.t = t_next
                main.resolve()
                trial.worst = max(trial.worst, self.defect.measure(t_next - tt))
                trial.rows.append((t_next, main.row()))
                tt = t_next
            trial.end = tt
            if trial.worst > REJECT * eps:
                trial.factor = SAFETY * (eps / trial.worst) ** (1.0 / p)
                return trial
            self.far_defect.observe(t)
            shadow.step(t, tt - t)
            shadow.t = tt
            shadow.resolve()
            trial.far_worst = self.far_defect.measure(tt - t)
            if trial.far_worst > SUBSTEPS ** p * REJECT * eps:
                trial.factor = 0.5                           # the long step left the asymptotic range (unstable?)
            elif trial.worst > 0.1 * eps and trial.far_worst < 0.5 * SUBSTEPS ** p * trial.worst:
                trial.factor = 0.5                           # h and 2h make alike defects: not asymptotic either
        except SimulationError as exc:
            if H <= 1e-9 * max(1.0, abs(t)):
                self.fmus.free(trial.states)
                raise
            trial.factor, trial.failure = SHRINK, exc
        return trial

    def _below_resolution(self) -> None:
        """End the run: the next step is below the resolution of time (StepBelowResolution)."""
        edge = max(abs(self.t0), abs(self.t_stop))
        raise StepBelowResolution(
            "error-controlled steps: the step fell to {h:.3g} s at t = {t:.9g} s, below the resolution of time "
            "near t = {edge:g} s (4 x {ulp:.3g} s): {tolerance} {tol:g} cannot be kept (coupling defects of the last "
            "rejected step: {near:.2g} in steps of h, {far:.2g} in one of 2h, against a level of {eps:.2g}); give a "
            "larger {tolerance}", h=self.h, t=self.t, edge=edge, ulp=math.ulp(edge), tol=self.report.tolerance,
            near=self.last_defect[0], far=self.last_defect[1], eps=self.eps)

    def reject(self, trial: _Trial) -> None:
        """Roll both copies back to the trial's start and shorten the step; a bound is learnt from a step
        that left the asymptotic range or failed (explicit coupling only: implicit coupling has no stability
        limit, its step grows back at once)."""
        t = trial.t
        self.fmus.restore(trial.states, t)
        self.fmus.free(trial.states)
        for copy in (self.main, self.shadow):
            copy.t = t
            copy.resolve()
        self.report.rejected += 1
        self.last_defect = (trial.worst, trial.far_worst)
        self.h = trial.H / SUBSTEPS * max(SHRINK, min(trial.factor, 0.5))
        if (trial.failure is not None or trial.factor == 0.5) and self.main.implicit is None:
            self.h_stable = self.h                           # raised slowly (STABLE_GROWTH) from here

    def accept(self, trial: _Trial) -> None:
        """Record the trial's rows, update the global estimate and the calibration, choose the next step."""
        self.fmus.free(trial.states)
        t, tt, H, worst, eps = trial.t, trial.end, trial.H, trial.worst, self.eps
        far = self.shadow.row()
        estimate = 0.0
        self.near += worst * (tt - t)
        self.far_sum += trial.far_worst * (tt - t)
        richardson = max(SUBSTEPS ** self.p, self.far_sum / self.near if self.near > 0 else 0.0) - 1
        scale, largest, rows = self.scale, self.largest, trial.rows
        for i, (a, b) in enumerate(zip(rows[-1][1], far)):
            for _, r in rows:
                if abs(r[i]) > scale[i]:
                    scale[i] = abs(r[i])
            if abs(a - b) / richardson > largest[i]:
                largest[i] = abs(a - b) / richardson
            if scale[i] > 0:
                estimate = max(estimate, abs(a - b) / scale[i])
        estimate /= richardson
        for tr, r in rows:
            self.result.append(tr, r)
        report = self.report
        report.accepted += SUBSTEPS
        report.h_min = min(report.h_min, H / SUBSTEPS)
        report.h_max = max(report.h_max, H / SUBSTEPS)
        self.spent += eps * (tt - t)
        self.calibration = max(self.calibration, estimate * (tt - self.t0) / self.spent)
        if self.calibration > 0:
            self.eps = max(min(eps, self.aim / self.calibration), self.aim * LEVEL_FLOOR)
        self.t = tt
        factor = SAFETY * (self.eps / worst) ** (1.0 / self.p) if worst > 0 else GROW
        self.h_stable *= STABLE_GROWTH
        wanted = H / SUBSTEPS * min(GROW, max(SHRINK, factor))
        if self.main.implicit is not None and 1.0 <= factor <= KEEP and not trial.last:
            wanted = H / SUBSTEPS                            # implicit coupling: the iteration's Jacobian stays valid
        self.h = min(self.h_max, self.h_stable, wanted)
        self.macro += 1
        self.capped += self.h < wanted
        if self.progress is not None:
            self.progress((self.t - self.t0) / (self.t_stop - self.t0))

    def finish(self) -> StepReport:
        report = self.report
        report.level = self.eps
        report.held = self.capped / self.macro if self.macro else 0.0
        # the norm of the run (module docstring): each variable's largest error over its largest magnitude
        # over the whole run (during the run only the magnitudes seen so far are known: the estimate of
        # `accept`, which calibrates eps, is larger early on)
        report.estimated_error = max((e / s for e, s in zip(self.largest, self.scale) if s > 0), default=0.0)
        E, tolerance = report.estimated_error, report.tolerance
        if self.level is None and self.calibration > 0 and (E > HIGH * tolerance or
                                                            (E < LOW * tolerance and report.held < 0.9)):
            report.next_level = self.aim / self.calibration
        if self.progress is not None:
            self.progress(1.0)
        return report
