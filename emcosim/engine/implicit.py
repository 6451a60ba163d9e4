"""Implicit coupling: each communication step iterated until the inputs agree (coupling "implicit").

Explicit coupling (coupling.py) hands an FMU with states a polynomial for each input at t_n, built from
what the source gives at t_n. Where the loop through that input is stiff at the step (a closed-loop
mode lambda with |lambda| h >> 1, e.g. a controller that feeds back a fast electrical state with a
large gain) every such polynomial extrapolates the mode, and the coupled run diverges unless
h < ~1/|lambda|; the monolithic implicit solver of the same loop has no such limit.

Here an input of an FMU with states follows, over the step [t_n, t_n + h], a polynomial fixed by its
value u_n at t_n and by what its source gives at the END of the step, after the step made with it:

- Hermite (the source gives the output's first derivative, the target takes input derivatives up to
  order 2): the parabola with u(0) = u_n, u(h) = c, u'(h) = d, i.e. the input derivatives
      u' = (2 (c - u_n) - d h) / h,   u'' = 2 (d h - (c - u_n)) / h^2          (at t_n),
  with c and d the source's value and derivative at t_n + h. On the test loop x' = u, u = lambda x
  (z = lambda h) a step multiplies x by (1 + z/3) / (1 - 2z/3 + z^2/6): the stability function of the
  two-stage Radau IIA method, L-stable (-> 0 for z -> -inf: a stiff mode is damped in one step, not
  carried on) and of third order.
- Chord (the target takes only the first derivative, or the source gives none): u(s) = u_n + (c - u_n) s/h,
  the trapezoidal rule on the test loop: A-stable (a stiff mode is kept bounded but rings with factor
  -> -1), second order.
- Hold (the target cannot interpolate): u = c over the step, backward Euler: L-stable, first order.

The unknowns z = (c, d) (or c) solve r(z) = G(z) - z = 0, G being what the master reads at t_n + h
after the step made with z. Newton's method with an approximate Jacobian of r: finite differences
(one more trial step per unknown) when none is known yet or the iteration stalls, Broyden's rank-one
update after every trial, kept from step to step and, for the last JACOBIANS_KEPT step sizes, per
size (the Jacobian changes with the step; error-controlled steps return to sizes met before). The
first trial extrapolates z from the points before (a parabola through the last values, a line
through the last derivatives). A trial rolls the FMUs with implicit inputs back to their state at
t_n (fmi2SetFMUstate), sets the polynomial (fmi2SetRealInputDerivatives), steps them again and
resolves the values (and derivatives) at t_n + h; FMUs without implicit inputs (static controllers,
sources) step once and get the new inputs at t_n + h (FMI 2.0 lets a master set inputs and get
outputs again at the same communication point). The step ends when the residual's effect on the
inputs is below the iteration tolerance, a fraction of their scale (the largest magnitude seen).
A step that has not converged after MAX_TRIALS trials is retried as two halves (every FMU rolled
back; fixed-step runs, down to h / 2^MAX_HALVINGS; the communication points and the rows of the
result stay those of the fixed step; `Statistics.halved` counts them): a fast transient (a charging
layer at the start) then costs short steps where it lives, not over the whole run. Past that, or in
error-controlled runs (the step control retries shorter itself), it ends the run. `deviation`
measures the coupling's own error of a step for the step control.

Nothing here knows the models: any FMU with canGetAndSetFMUstate takes part.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from .coupling import capabilities
from .errors import ScenarioError, SimulationError
from .fmi import FMICallException
from .fmustate import States
from .history import History
from .transfer import NonFinite, Transfer

ITERATION_TOL = 1e-6    # fixed steps: the end values agree to this fraction of the inputs' scale
ITERATION_FLOOR = 1e-7  # never asked for less: about what the FMUs' own integration error makes of
                        # an input through a stiff loop (MEMS: rtol 1e-8 of x_e times du/dx_e ~ 1e-7 of u)
MAX_TRIALS = 16         # trial steps per communication step (the first included)
BACKTRACK = 3           # halvings of a Newton step that makes the residual larger
STALL = 0.5             # a trial that does not shrink the residual below this factor renews the Jacobian
JACOBIAN_RANGE = 1.25   # a Jacobian serves steps within this factor of the one it was taken at
JACOBIANS_KEPT = 8      # Jacobians kept for the step sizes met before (error-controlled steps return to them)
PERTURBATION = 1e-6     # finite-difference perturbation, relative to the input's scale
MAX_HALVINGS = 12       # fixed-step runs: a step that does not converge is retried as halves, to h / 4096


@dataclass
class Statistics:
    """What the iteration cost over a run."""

    steps: int = 0          # communication steps
    trials: int = 0         # trial steps (>= steps)
    jacobians: int = 0      # finite-difference Jacobians
    halved: int = 0         # steps that did not converge and were retried as two halves (counted in steps)

    def summary(self) -> str:
        per = self.trials / self.steps if self.steps else 0.0
        halved = (f"; {self.halved} steps did not converge and were taken as two halves, counted as steps"
                  if self.halved else "")
        return (f"implicit coupling: {self.trials} trial steps in {self.steps} steps ({per:.2f} per step, "
                f"{self.jacobians} finite-difference Jacobians{halved}; rolled-back steps and a second run included)")


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


def deviation(mode: str, u_prev: float | None, h_prev: float, d_prev: float | None, u0: float, c: float,
              d: float, h: float) -> float:
    """How far the step's input polynomial lies from the next higher one: the coupling's own error of
    the step (stepcontrol's defect), in the input's unit:

    - hermite: the cubic that also meets the source's derivative d_prev at t_n differs from the
      parabola by m s (1 - s/h)^2, m = d_prev - u'(0), at most 4 |m| h / 27: O(h^3);
    - chord: the parabola through the point before (u_prev, h_prev earlier), u0 and c differs from
      the chord by at most |u''| h^2 / 8 (u'' their second divided difference): O(h^2);
    - hold, or a chord at the first step (no point before): |c - u0|, O(h).
    """
    if mode == "hermite" and d_prev is not None:
        slope = (2.0 * (c - u0) - d * h) / h
        return 4.0 * abs(d_prev - slope) * h / 27.0
    if mode == "hold" or u_prev is None:
        return abs(c - u0)
    second = 2.0 * ((c - u0) / h - (u0 - u_prev) / h_prev) / (h + h_prev)
    return abs(second) * h * h / 8.0


class _Refused(Exception):
    """The target refused the input derivative of order 2 (FMI 2.0 does not declare the orders taken)."""


class Implicit:
    """The implicit step of one copy of the FMUs (a stepper.Stepper).

    stepper: the stepper whose `step` calls this; connections: those of `implicit_inputs`;
    value_slot: full name -> slot of the stepper's value buffer; derivative_slot: input full name ->
    (slot of its source's first derivative in the stepper's derivative plan, the connection's factor),
    for the Hermite polynomial (None: chords); tolerance: the iteration tolerance."""

    def __init__(self, stepper, connections, value_slot: dict[str, int],
                 derivative_slot: dict[str, tuple[int, float]] | None = None, tolerance: float = ITERATION_TOL,
                 halvings: int = MAX_HALVINGS):
        self.stepper = stepper
        self.tolerance = tolerance
        self.inputs = [c.end for c in connections]
        self.slots = [value_slot[c.end] for c in connections]
        by_target: dict[str, list] = {}
        for i, c in enumerate(connections):
            by_target.setdefault(c.end_element, []).append((i, c))
        interpolate = all(capabilities(stepper.instances[comp].model_description).interpolates_inputs
                          for comp in by_target)
        self.mode = "hold" if not interpolate else "hermite" if derivative_slot else "chord"
        self.derivative_slots: list[tuple[int, float]] = (
            [derivative_slot[c.end] for c in connections] if derivative_slot and self.mode == "hermite" else [])
        self.sets = []          # per FMU: (setter of the polynomial, input indices)
        for comp, items in by_target.items():
            inst, idx = stepper.instances[comp], [i for i, _ in items]
            if self.mode == "hold":
                self.sets.append((stepper.value_setter(comp, [c.end_connector for _, c in items]), idx))
            else:
                orders = (1, 2) if self.mode == "hermite" else (1,)
                entries = [(c.end_connector, k) for k in orders for _, c in items]
                self.sets.append((Transfer(inst, [v for v, _ in entries], getter=False, orders=[k for _, k in entries]),
                                  idx))
        rolled = set(by_target)
        self.rolled = [(inst, fn, comp) for inst, fn, comp in stepper.do_step if inst.name in rolled]
        self.states = States([inst for inst, _, _ in self.rolled], "implicit coupling rolls it back")
        self.once = [(inst, fn, comp) for inst, fn, comp in stepper.do_step if inst.name not in rolled]
        # halving a step rolls back the FMUs stepped once too: only where each of them can
        once_can = all(inst.model_description.coSimulation.canGetAndSetFMUstate for inst, _, _ in self.once)
        self.halvings = halvings if once_can else 0
        self.once_states = States([inst for inst, _, _ in self.once], "a step that does not converge is halved")
        self.n = len(self.inputs)
        self.scale = [0.0] * (2 * self.n)       # values, then derivatives
        self.jacobian: np.ndarray | None = None
        self.jacobian_step = 0.0                # the step it was computed for (it changes with the step)
        self.kept: dict[float, np.ndarray] = {}   # step -> the latest Jacobian for it (oldest first)
        self.history = History()                # t -> (values, derivatives) of the points before
        self.statistics = Statistics()
        self.pieces: list[tuple[float, float]] | None = None   # (t, h) of every converged step, while traced (doubling.py)

    def save(self) -> dict:
        """What the iteration learns from step to step (Jacobians, scales, mode, histories, statistics): a
        caller that steps aside from the run (doubling.py) and rolls the FMUs back restores it with `restore`."""
        return {"scale": list(self.scale), "jacobian": self.jacobian, "jacobian_step": self.jacobian_step,
                "kept": dict(self.kept), "mode": self.mode, "derivative_slots": list(self.derivative_slots),
                "sets": list(self.sets), "points": list(self.history.points),
                "statistics": dict(vars(self.statistics))}

    def restore(self, saved: dict) -> None:
        """Back to what `save` returned (the Jacobians are never changed in place, only replaced)."""
        self.scale, self.jacobian, self.jacobian_step = saved["scale"], saved["jacobian"], saved["jacobian_step"]
        self.kept, self.mode, self.derivative_slots = saved["kept"], saved["mode"], saved["derivative_slots"]
        self.sets = saved["sets"]
        vars(self.statistics).update(saved["statistics"])     # in place: the run's result holds this object
        self.history.points[:] = saved["points"]

    @property
    def degree(self) -> int:
        """Degree of the inputs' polynomials: the coupling's global order is one more."""
        return {"hermite": 2, "chord": 1, "hold": 0}[self.mode]

    # ---- one communication step -----------------------------------------------------------------
    def step(self, t: float, h: float, halvings: int | None = None) -> None:
        """Step every FMU from t to t + h, the implicit inputs on their converged polynomials;
        afterwards the values (and, Hermite, the derivatives) at t + h are resolved. A step that does
        not converge is retried as two halves, at most `halvings` times nested (default: self.halvings)."""
        halvings = self.halvings if halvings is None else halvings
        states = self.states.save(t)
        once = self.once_states.save(t) if halvings else None
        try:
            try:
                self._step(t, h, states)
                if self.pieces is not None:
                    self.pieces.append((t, h))
                return
            except NotConverged:
                if not halvings:
                    raise
            self.states.restore(states, t)         # every FMU back at t, its values resolved again
            self.once_states.restore(once, t)
        finally:
            self.states.free(states)
            if once is not None:
                self.once_states.free(once)
        self.statistics.halved += 1
        self.jacobian = None
        stepper = self.stepper
        stepper.t = t
        stepper.resolve(with_derivatives=stepper.derivatives is not None)
        self.step(t, h / 2, halvings - 1)
        self.step(t + h / 2, h / 2, halvings - 1)

    def _step(self, t: float, h: float, states: list) -> None:
        stepper = self.stepper
        u0 = [stepper.slots[s] for s in self.slots]
        d0 = self.source_derivatives()
        for i, v in enumerate(u0 + d0):
            if abs(v) > self.scale[i]:
                self.scale[i] = abs(v)
        self._once_done = self._moved = False
        try:
            self._iterate(t, h, u0, d0, states)
        except _Refused:                           # the target takes order 1 only: chords from now on
            self._chords_only()
            self._iterate(t, h, u0, [], states)
        self.statistics.steps += 1
        self.history.add(t, (u0, d0))

    def _iterate(self, t: float, h: float, u0, d0, states) -> int:
        z = self._predict(t, h, u0, d0)
        try:
            r = self._trial(t, h, u0, z, states)
        except SimulationError:                        # an FMU refused the extrapolated inputs: hold them
            z = list(u0) + [0.0] * len(d0)
            r = self._trial(t, h, u0, z, states)
        trials, fresh = 1, False
        while not self._converged(r, z, h):
            if trials >= MAX_TRIALS:
                raise NotConverged(f"implicit coupling: the inputs {', '.join(self.inputs)} did not agree "
                                   f"within {MAX_TRIALS} trials of the step from t = {t:.9g} s over "
                                   f"h = {h:.3g} s (residual {self._error(r, z, h):.2g} of their scale; tolerance "
                                   f"{self.tolerance:.2g}): take a shorter step")
            if self.jacobian is None or not 1 / JACOBIAN_RANGE <= h / self.jacobian_step <= JACOBIAN_RANGE:
                if not self._recall(h):
                    self._finite_differences(t, h, u0, z, r, states)
                    trials += len(z)
                    fresh = True
            dz = self._solve(r)
            error = self._error(r, z, h)
            for _ in range(BACKTRACK + 1):             # Newton's step, halved while it makes things worse
                z_new = [a + b for a, b in zip(z, dz)]
                trials += 1
                try:
                    r_new = self._trial(t, h, u0, z_new, states)
                    error_new = self._error(r_new, z_new, h)
                except SimulationError as exc:         # an FMU refused the trial (e.g. left its domain)
                    r_new, error_new, refused = None, math.inf, exc
                if error_new < error or trials >= MAX_TRIALS:
                    break
                dz = [0.5 * v for v in dz]
            if r_new is None:
                raise NotConverged(f"implicit coupling: the trials of the step from t = {t:.9g} s over h = {h:.3g} s "
                                   f"near the last one failed ({refused}): take a shorter step")
            if error_new < error:
                self._broyden([a - b for a, b in zip(z_new, z)], [a - b for a, b in zip(r_new, r)])
            if error_new > STALL * error and not fresh:
                self.kept.pop(self.jacobian_step, None)
                self.jacobian = None                   # renew it before the next trial
            fresh = False
            if error_new < error:
                z, r = z_new, r_new
        return trials

    def _chords_only(self) -> None:
        self.mode, self.derivative_slots, self.jacobian = "chord", [], None
        self.kept.clear()
        self.sets = [(Transfer(t.inst, [v for v, k in t.entries if k == 1], getter=False,
                               orders=[k for _, k in t.entries if k == 1]), idx)
                     for t, idx in self.sets]

    def _predict(self, t: float, h: float, u0: list[float], d0: list[float]) -> list[float]:
        """The end values (and derivatives) extrapolated from the points before: Hermite, the cubic
        through the values and derivatives at the point before and at t; chords, the parabola through
        the two points before and u0 (a line through one); u0 (and d0) held at the first step. A
        rolled-back step leaves no point behind."""
        history = self.history.before(t)
        if not history:
            return list(u0) + list(d0)
        t1, (u1, d1) = history[-1]
        k = h / (t - t1)
        if self.mode == "hermite":
            # the cubic, unless it moves an input more than twice as far as the line through the two
            # values (after a fast transient the derivatives extrapolate wildly): then the line
            z = self._hermite_extrapolation(t - t1, h, u1, d1, u0, d0)
            for i, (a, b) in enumerate(zip(u0, u1)):
                if abs(z[i] - a) > 2.0 * abs(a - b) * k:
                    z[i], z[self.n + i] = a + (a - b) * k, (a - b) / (t - t1)
            return z
        ds = [a + (a - b) * k for a, b in zip(d0, d1)]
        if len(history) < 2:
            return [a + (a - b) * k for a, b in zip(u0, u1)] + ds
        t2, (u2, _) = history[-2]
        s = t + h                                   # Lagrange weights of (t2, t1, t) at t + h
        w0 = (s - t1) * (s - t2) / ((t - t1) * (t - t2))
        w1 = (s - t) * (s - t2) / ((t1 - t) * (t1 - t2))
        w2 = (s - t) * (s - t1) / ((t2 - t) * (t2 - t1))
        return [w0 * a + w1 * b + w2 * c for a, b, c in zip(u0, u1, u2)] + ds

    @staticmethod
    def _hermite_extrapolation(H: float, h: float, u1, d1, u0, d0) -> list[float]:
        """Value and derivative at t + h of the cubic through (u1, d1) at t - H and (u0, d0) at t."""
        x = (H + h) / H
        b = (2 * x**3 - 3 * x**2 + 1, x**3 - 2 * x**2 + x, -2 * x**3 + 3 * x**2, x**3 - x**2)
        db = (6 * x**2 - 6 * x, 3 * x**2 - 4 * x + 1, -6 * x**2 + 6 * x, 3 * x**2 - 2 * x)
        values = [b[0] * a + b[1] * H * p + b[2] * c + b[3] * H * q for a, p, c, q in zip(u1, d1, u0, d0)]
        slopes = [(db[0] * a + db[1] * H * p + db[2] * c + db[3] * H * q) / H for a, p, c, q in zip(u1, d1, u0, d0)]
        return values + slopes

    def _trial(self, t: float, h: float, u0, z, states) -> list[float]:
        """Step from t with the polynomials ending at z; the residual G(z) - z at t + h. The FMUs
        with implicit inputs start from `states` (t), the others are stepped by the first trial only."""
        stepper, n = self.stepper, self.n
        if self._moved:                            # the FMUs are still at t before the first trial
            self.states.restore(states, t)
        self._moved = True
        self.statistics.trials += 1
        for setter, idx in self.sets:
            if self.mode == "hold":
                setter([z[i] for i in idx])
                continue
            values, m = setter.values, len(idx)
            for k, i in enumerate(idx):
                change = z[i] - u0[i]
                if self.mode == "hermite":
                    d = z[n + i]
                    values[k] = (2.0 * change - d * h) / h
                    values[m + k] = 2.0 * (d * h - change) / (h * h)
                else:
                    values[k] = change / h
            self._call(setter, t)
        stepper.step_some(t, h, self.rolled if self._once_done else self.rolled + self.once)
        self._once_done = True
        stepper.t = t + h
        stepper.resolve(with_derivatives=stepper.derivatives is not None)   # every FMU's, for the next step
        slots = stepper.slots
        r = [slots[s] - zi for s, zi in zip(self.slots, z)]
        if self.mode == "hermite":
            r += [d - zi for d, zi in zip(self.source_derivatives(), z[n:])]
        return r

    def transfers(self) -> list[Transfer]:
        """The input-derivative transfers (their `elapsed` is time inside the FMUs)."""
        return [t for t, _ in self.sets if isinstance(t, Transfer)]

    def source_derivatives(self) -> list[float]:
        """The sources' first derivatives (times the connections' factors) at the last resolve, for the
        Hermite polynomial (empty for chords and holds)."""
        if not self.derivative_slots:
            return []
        dv = self.stepper.derivatives.values
        return [dv[s] * f for s, f in self.derivative_slots]

    def _call(self, transfer: Transfer, t: float) -> None:
        try:
            transfer()
        except NonFinite as exc:
            raise SimulationError(f"implicit coupling: {exc.message(t)}") from None
        except FMICallException as exc:
            if self.mode == "hermite":
                raise _Refused() from None
            self.stepper.failed(transfer, exc)

    def _error(self, r: list[float], z: list[float], h: float) -> float:
        """The residual's effect on the inputs over the step, relative to their scale: |r_c| for an end
        value, |r_d| 4 h / 27 for an end derivative (its largest effect on the parabola)."""
        worst, n = 0.0, self.n
        for i in range(n):
            scale = max(self.scale[i], abs(z[i] + r[i]))
            e = abs(r[i]) + (4.0 * h / 27.0 * abs(r[n + i]) if self.mode == "hermite" else 0.0)
            worst = max(worst, e / scale if scale > 0 else e)
        return worst

    def _converged(self, r, z, h: float) -> bool:
        """The residual is below the iteration tolerance (never below ITERATION_FLOOR). A looser stop
        (e.g. at a fraction of the coupling's own error) lets the unconverged part of a stiff mode
        grow from step to step: the toy loop x' = -1000 x at h = 0.01 diverged with it."""
        return self._error(r, z, h) <= max(self.tolerance, ITERATION_FLOOR)

    def _finite_differences(self, t, h, u0, z, r, states) -> None:
        m = len(z)
        J = np.empty((m, m))
        for j in range(m):
            delta = PERTURBATION * max(self.scale[j], abs(z[j])) or PERTURBATION
            zj = list(z)
            zj[j] += delta
            rj = self._trial(t, h, u0, zj, states)
            J[:, j] = [(a - b) / delta for a, b in zip(rj, r)]
        self.jacobian, self.jacobian_step = J, h
        self._keep()
        self.statistics.jacobians += 1

    def _solve(self, r: list[float]) -> list[float]:
        try:
            return list(np.linalg.solve(self.jacobian, -np.asarray(r)))
        except np.linalg.LinAlgError:
            raise NotConverged("implicit coupling: the Jacobian of the input residual is singular") from None

    def _broyden(self, dz: list[float], dr: list[float]) -> None:
        """Broyden's update: J <- J + (dr - J dz) dz^T / (dz^T dz)."""
        J = self.jacobian
        if J is None:
            return
        dz_, dr_ = np.asarray(dz), np.asarray(dr)
        norm = float(dz_ @ dz_)
        if norm > 0 and math.isfinite(norm):
            self.jacobian = J + np.outer(dr_ - J @ dz_, dz_) / norm
            self._keep()

    def _keep(self) -> None:
        kept = self.kept
        kept.pop(self.jacobian_step, None)
        kept[self.jacobian_step] = self.jacobian
        while len(kept) > JACOBIANS_KEPT:
            del kept[next(iter(kept))]

    def _recall(self, h: float) -> bool:
        """Take the kept Jacobian of the step nearest h, if within JACOBIAN_RANGE. The Jacobian
        changes with the step in a way only the models know (measured on the maglev loop: its entries
        grow from 0.4 at 25 ms to 600 at 1.5 s, the open-loop plant being unstable), but at the same
        step it changes slowly along the run, and error-controlled steps return to sizes met before.
        A recalled Jacobian that does not halve the residual is renewed (STALL)."""
        best, distance = None, math.log(JACOBIAN_RANGE)
        for step in self.kept:
            d = abs(math.log(h / step))
            if d <= distance:
                best, distance = step, d
        if best is None:
            return False
        self.jacobian, self.jacobian_step = self.kept[best], best
        return True
