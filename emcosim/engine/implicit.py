"""Implicit coupling: each communication step iterated until the inputs agree (`emcosim run --implicit`).

Explicit coupling (coupling.py) hands an FMU with states a polynomial for each input at t_n, built from
what the source gives at t_n. Where the loop through that input is stiff at the step (a closed-loop
mode lambda with |lambda| h >> 1, e.g. a controller that feeds back a fast electrical state with a
large gain) every such polynomial extrapolates the mode, and the coupled run diverges unless
h < ~1/|lambda|; the monolithic implicit solver of the same loop has no such limit.

Here an input of an FMU with states follows the chord of the step

    u(t_n + s) = u_n + (c - u_n) s / h,      0 <= s <= h

(the value u_n at t_n and the first derivative (c - u_n) / h, fmi2SetRealInputDerivatives), whose end
value c is the value its source gives at t_{n+1} after the step made with c: c = G(c). On the test
loop x' = u, u = -lambda x this is the trapezoidal rule: stable for every h (A-stable) and of second
order, as the explicit coupling with the extrapolated second order. An input of an FMU that cannot
interpolate its inputs holds c over the step (backward Euler: stable, first order).

The master solves r(c) = G(c) - c = 0 by Newton's method with an approximate Jacobian of r: finite
differences (one more trial step per input) when none is known yet or the iteration stalls, Broyden's
rank-one update after every trial, kept from step to step (in a smooth run most steps end after
their first trial). The first trial takes c by linear extrapolation from the last two points. A trial
rolls the FMUs with implicit inputs back to their state at t_n (fmi2SetFMUstate), sets the chord,
steps them again and resolves the values at t_{n+1}; FMUs without them (static controllers, sources)
step once and get the new inputs at t_{n+1} (FMI 2.0 lets a master set inputs and get outputs again
at the same communication point). The step ends when max_i |r_i| / scale_i <= the iteration tolerance
(scale_i: the largest |u_i| of the run); a step that has not converged after MAX_TRIALS trials ends
the run (with error-controlled steps: is retried shorter).

Nothing here knows the models: every FMU with canGetAndSetFMUstate takes part.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from .coupling import DerivativeTransfer, capabilities
from .errors import ScenarioError, SimulationError

ITERATION_TOL = 1e-6    # fixed steps: the end values agree to this fraction of the inputs' scale
ITERATION_FLOOR = 1e-7  # never asked for less: about what the FMUs' own integration error makes of
                        # an input through a stiff loop (MEMS: rtol 1e-8 of x_e times du/dx_e ~ 1e-7 of u)
MAX_TRIALS = 8          # trial steps per communication step (the first included)
SHARE = 0.1             # ... or to this fraction of the chord's own deviation (`Implicit._converged`)
STALL = 0.5             # a trial that does not shrink the residual below this factor renews the Jacobian
PERTURBATION = 1e-6     # finite-difference perturbation, relative to the input's scale


@dataclass
class Statistics:
    """What the iteration cost over a run."""

    steps: int = 0          # communication steps
    trials: int = 0         # trial steps (>= steps)
    jacobians: int = 0      # finite-difference Jacobians

    def summary(self) -> str:
        per = self.trials / self.steps if self.steps else 0.0
        return (f"implicit coupling: {self.trials} trial steps for {self.steps} communication steps ({per:.2f} per "
                f"step, {self.jacobians} finite-difference Jacobians)")


class NotConverged(SimulationError):
    """A communication step whose inputs did not agree after MAX_TRIALS trials."""


def implicit_inputs(instances: dict, connections, dynamic: set[str]) -> list:
    """The connections whose input is coupled implicitly: every connected input of an FMU with states."""
    out = [c for c in connections if c.end_element in dynamic]
    for c in out:
        if not instances[c.end_element].model_description.coSimulation.canGetAndSetFMUstate:
            raise ScenarioError(f"{instances[c.end_element].path.name}: implicit coupling rolls back "
                                f"'{c.end_element}' to repeat a step, but it does not declare canGetAndSetFMUstate")
    return out


class Implicit:
    """The implicit step of one copy of the FMUs (a master._Stepper).

    stepper: the stepper whose `step` calls this; connections: those of `implicit_inputs`;
    value_slot: full name -> slot of the stepper's value buffer; tolerance: the iteration tolerance."""

    def __init__(self, stepper, connections, value_slot: dict[str, int], tolerance: float = ITERATION_TOL):
        self.stepper = stepper
        self.tolerance = tolerance
        self.inputs = [c.end for c in connections]
        self.slots = [value_slot[c.end] for c in connections]
        by_target: dict[str, list] = {}
        for i, c in enumerate(connections):
            by_target.setdefault(c.end_element, []).append((i, c))
        self.chords = []        # (DerivativeTransfer of order 1, input indices) per FMU that interpolates
        self.holds = []         # FMUs that cannot: (their value transfer, input indices) hold c
        for comp, items in by_target.items():
            inst = stepper.instances[comp]
            if capabilities(inst.model_description).interpolates_inputs:
                self.chords.append((DerivativeTransfer(inst, [(c.end_connector, 1) for _, c in items], getter=False),
                                    [i for i, _ in items]))
            else:
                self.holds.append((stepper.value_setter(comp, [c.end_connector for _, c in items]),
                                   [i for i, _ in items]))
        rolled = set(by_target)
        self.rolled = [(inst, fn, comp) for inst, fn, comp in stepper.do_step if inst.name in rolled]
        self.once = [(inst, fn, comp) for inst, fn, comp in stepper.do_step if inst.name not in rolled]
        n = len(self.inputs)
        self.scale = [0.0] * n
        self.jacobian: np.ndarray | None = None
        self.history: list[tuple[float, list[float]]] = []      # (t, input values) of the points before
        self.statistics = Statistics()

    # ---- one communication step -----------------------------------------------------------------
    def step(self, t: float, h: float) -> None:
        """Step every FMU from t to t + h, the implicit inputs on their converged chords; afterwards
        the values at t + h are resolved (the stepper's resolve without derivatives)."""
        stepper, slots = self.stepper, self.stepper.slots
        u0 = [slots[s] for s in self.slots]
        for i, v in enumerate(u0):
            if abs(v) > self.scale[i]:
                self.scale[i] = abs(v)
        c = self._predict(t, h, u0)
        states = [inst.slave.getFMUstate() for inst, _, _ in self.rolled]
        try:
            r = self._trial(t, h, u0, c, states, first=True)
            trials, fresh = 1, False
            while not self._converged(t, h, u0, c, r):
                if trials >= MAX_TRIALS:
                    raise NotConverged(f"implicit coupling: the inputs {', '.join(self.inputs)} did not agree "
                                       f"within {MAX_TRIALS} trials of the step from t = {t:.9g} s over "
                                       f"h = {h:.3g} s (residual {self._error(r):.2g} of their scale; tolerance "
                                       f"{self.tolerance:.2g}): take a shorter step")
                if self.jacobian is None:
                    self._finite_differences(t, h, u0, c, r, states)
                    trials += len(c)
                    fresh = True
                step = self._solve(r)
                c_new = [ci + di for ci, di in zip(c, step)]
                r_new = self._trial(t, h, u0, c_new, states)
                trials += 1
                self._broyden(step, [a - b for a, b in zip(r_new, r)])
                if self._error(r_new) > STALL * self._error(r) and not fresh:
                    self.jacobian = None                   # renew it before the next trial
                fresh = False
                c, r = c_new, r_new
        finally:
            for (inst, _, _), st in zip(self.rolled, states):
                inst.slave.freeFMUstate(st)
        self.statistics.steps += 1
        self.statistics.trials += trials
        history = self.history
        while history and history[-1][0] >= t:
            history.pop()
        history.append((t, u0))
        del history[:-3]                    # a rollback over two substeps leaves the point before them

    def _predict(self, t: float, h: float, u0: list[float]) -> list[float]:
        """The end values extrapolated by the parabola through the two points before t and u0 (a line
        through one, u0 held at the first step; a rolled-back step leaves no point behind)."""
        history = self.history
        while history and history[-1][0] >= t:
            history.pop()
        if not history:
            return list(u0)
        t1, u1 = history[-1]
        k = h / (t - t1)
        if len(history) < 2:
            return [a + (a - b) * k for a, b in zip(u0, u1)]
        t2, u2 = history[-2]
        s, s1, s2 = t + h, t1, t2                   # Lagrange weights of (t2, t1, t) at t + h
        w0 = (s - s1) * (s - s2) / ((t - s1) * (t - s2))
        w1 = (s - t) * (s - s2) / ((s1 - t) * (s1 - s2))
        w2 = (s - t) * (s - s1) / ((s2 - t) * (s2 - s1))
        return [w0 * a + w1 * b + w2 * c for a, b, c in zip(u0, u1, u2)]

    def _converged(self, t: float, h: float, u0, c, r) -> bool:
        """The residual is below the tolerance, or below a tenth of the chord's own deviation from
        the parabola through the point before, u0 and the end value (stepcontrol's defect of the
        step): iterating further would refine what the coupling's own error swamps."""
        error = self._error(r)
        if error <= self.tolerance:
            return True
        history = self.history
        if not history or error <= ITERATION_FLOOR:
            return error <= ITERATION_FLOOR
        t1, u1 = history[-1]
        h1 = t - t1
        deviation = 0.0
        for i, (a, b, ci, ri) in enumerate(zip(u0, u1, c, r)):
            second = 2.0 * ((ci + ri - a) / h - (a - b) / h1) / (h + h1)
            if self.scale[i] > 0:
                deviation = max(deviation, abs(second) * h * h / 8.0 / self.scale[i])
        return error <= SHARE * deviation

    def _trial(self, t: float, h: float, u0, c, states, first: bool = False) -> list[float]:
        """Step from t with the chords ending at c; the residual G(c) - c at t + h."""
        stepper = self.stepper
        if not first:
            for (inst, _, _), st in zip(self.rolled, states):
                inst.slave.setFMUstate(st)
        for transfer, idx in self.chords:
            values = transfer.values
            for k, i in enumerate(idx):
                values[k] = (c[i] - u0[i]) / h
            self._call(transfer, t)
        for setter, idx in self.holds:
            setter([c[i] for i in idx])
        stepper.step_some(t, h, self.rolled if not first else self.rolled + self.once)
        stepper.t = t + h
        stepper.resolve(with_derivatives=False)
        slots = stepper.slots
        return [slots[s] - ci for s, ci in zip(self.slots, c)]

    def _call(self, transfer: DerivativeTransfer, t: float) -> None:
        try:
            transfer()
        except Exception as exc:               # noqa: BLE001 - fmi2Error, or a chord that is not finite
            inst = transfer.inst
            raise SimulationError(f"implicit coupling: {inst.path.name} (component '{inst.name}') refused the "
                                  f"input chord at t = {t:.9g} s: {exc}") from None

    def _error(self, r: list[float]) -> float:
        return max((abs(ri) / s if s > 0 else abs(ri) for ri, s in zip(r, self.scale)), default=0.0)

    def _finite_differences(self, t, h, u0, c, r, states) -> None:
        n = len(c)
        J = np.empty((n, n))
        for j in range(n):
            delta = PERTURBATION * max(self.scale[j], abs(c[j])) or PERTURBATION
            cj = list(c)
            cj[j] += delta
            rj = self._trial(t, h, u0, cj, states)
            J[:, j] = [(a - b) / delta for a, b in zip(rj, r)]
        self.jacobian = J
        self.statistics.jacobians += 1

    def _solve(self, r: list[float]) -> list[float]:
        try:
            return list(np.linalg.solve(self.jacobian, -np.asarray(r)))
        except np.linalg.LinAlgError:
            raise NotConverged("implicit coupling: the Jacobian of the input residual is singular") from None

    def _broyden(self, dc: list[float], dr: list[float]) -> None:
        """Broyden's update: J <- J + (dr - J dc) dc^T / (dc^T dc)."""
        J = self.jacobian
        if J is None:
            return
        dc_, dr_ = np.asarray(dc), np.asarray(dr)
        norm = float(dc_ @ dc_)
        if norm > 0 and math.isfinite(norm):
            self.jacobian = J + np.outer(dr_ - J @ dc_, dc_) / norm
