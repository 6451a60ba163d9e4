"""Monolithic closed-loop reference: plant + static controller as one ODE, eta' = f(eta, u(eta, t)).

Integrated with scipy's Radau (implicit, order 5, L-stable) with the exact Jacobian
df/deta + g du/deta (plant: analytic, controller: complex step). The MEMS closed loop is stiff
(electrical time constant ~1e-10 s against ~1e-4 s for the mechanics) and its states differ by
ten orders of magnitude, so the integration runs on scaled states xi_i = eta_i / s_i, and the
tolerance is per state: |error_i| <= rtol |eta_i| + atol s_i. By default s_i = max_t |eta_i(t)|
from a first pass at rtol = 1e-6 (see docs/derivations.md, "Monolithic reference").

The integration stops cleanly (results so far kept, `message` says why) when the state leaves the
plant's domain, when the reference becomes infeasible, or when the solver fails.

`simulate` samples the states, u and the target system eta* on an equidistant grid (reports, tests).
`record` is the benchmark's fair path: the same integration (any of scipy's LSODA, BDF, Radau, each
with the exact Jacobian) recording only what a co-simulation run records, the plant states and u at
given communication points; `diagnose` adds eta* afterwards, outside any timing.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.integrate import BDF, LSODA, Radau

from . import differentiation
from .controller import Controller
from .ph_plant import EMPlant
from .references import Reference


@dataclass
class Result:
    """Samples of a closed-loop run. eta_star is the controller's target (eta_d or eta*(t))."""

    t: np.ndarray
    eta: np.ndarray
    u: np.ndarray
    eta_star: np.ndarray
    success: bool
    message: str
    n_steps: int
    scale: np.ndarray

    @property
    def q(self) -> np.ndarray:
        return self.eta[:, 0]

    @property
    def error(self) -> np.ndarray:
        return self.eta - self.eta_star


@dataclass
class Recording:
    """What a co-simulation run records at its communication points t: the plant's states eta (its
    outputs q, p, x_e) and the controller's u. No target system: `diagnose` adds it."""

    t: np.ndarray
    eta: np.ndarray
    u: np.ndarray
    success: bool
    message: str
    n_steps: int
    nfev: int                       # right-hand sides f(eta, u(eta, t)) the solver evaluated
    njev: int                       # exact Jacobians it evaluated (LSODA: its LU factorisations)
    scale: np.ndarray
    method: str

    @property
    def q(self) -> np.ndarray:
        return self.eta[:, 0]


METHODS = {"Radau": Radau, "BDF": BDF, "LSODA": LSODA}     # scipy's solvers that take an exact Jacobian


class ClosedLoop:
    """eta' = f(eta, u(eta, jet(t))) of a plant and a controller (and its reference, if tracking)."""

    def __init__(self, controller: Controller, reference: Reference | None = None):
        if controller.tracking and reference is None:
            raise ValueError(f"{controller.name} is a tracking controller: give a reference")
        self.controller = controller
        self.plant = controller.plant
        self.reference = reference
        self.g = self.plant.g()

    def jet(self, t: float):
        return None if self.reference is None else self.reference.jet(t)

    def u(self, eta: np.ndarray, t: float) -> np.ndarray:
        return self.controller.u(eta, self.jet(t))

    def target(self, t: float) -> np.ndarray:
        return self.controller.target(self.jet(t))

    def controls(self, t: np.ndarray, eta: np.ndarray) -> np.ndarray:
        """u at every sample (t_k, eta_k): what the co-simulated controller outputs."""
        return np.array([self.u(e, tt) for e, tt in zip(eta, t)])

    def targets(self, t: np.ndarray) -> np.ndarray:
        """The target system eta*(t_k) at every sample: a diagnostic no co-simulation run computes."""
        return np.array([self.target(tt) for tt in t])

    def rhs(self, t: float, eta: np.ndarray) -> np.ndarray:
        return self.plant.f(eta, self.u(eta, t))

    def jacobian(self, t: float, eta: np.ndarray) -> np.ndarray:
        jet = self.jet(t)
        du = differentiation.jacobian(lambda e: self.controller.u(e, jet), eta, scale=np.abs(eta) + 1e-300)
        return self.plant.jacobian(eta) + self.g @ du


def simulate(controller: Controller, eta0, t_end: float, reference: Reference | None = None,
             n_samples: int = 2001, rtol: float = 1e-10, scale=None, max_step: float = np.inf) -> Result:
    """Integrate the closed loop from eta0 over [0, t_end]; sample on n_samples equidistant times."""
    loop = ClosedLoop(controller, reference)
    eta0 = np.asarray(eta0, dtype=float)
    controller.plant.check_state(eta0)
    if not (np.isfinite(t_end) and t_end > 0):
        raise ValueError(f"t_end = {t_end} must be finite and > 0")
    scale = _default_scale(loop, eta0, t_end, max_step) if scale is None else np.asarray(scale, dtype=float)
    return _integrate(loop, eta0, t_end, n_samples, rtol, scale, max_step)


def record(controller: Controller, eta0, t_grid, reference: Reference | None = None, rtol: float = 1e-10,
           scale=None, method: str = "Radau", max_step: float = np.inf) -> Recording:
    """Integrate the closed loop eta' = f(eta, u(eta, t)) (eq. (open-loop elecmech) with the controller's
    law, ClosedLoop.rhs) from eta0 at t_grid[0] to t_grid[-1] with scipy's `method` (a key of METHODS)
    and record eta and u at every time of t_grid (increasing), and nothing else."""
    loop = ClosedLoop(controller, reference)
    eta0 = np.asarray(eta0, dtype=float)
    controller.plant.check_state(eta0)
    t_grid = np.asarray(t_grid, dtype=float)
    if t_grid.ndim != 1 or len(t_grid) < 2 or not np.all(np.isfinite(t_grid)) or np.any(np.diff(t_grid) <= 0):
        raise ValueError("t_grid must be finite, increasing and hold at least two times")
    if method not in METHODS:
        raise ValueError(f"method {method!r}: one of {', '.join(METHODS)}")
    if scale is None and t_grid[0] != 0:
        raise ValueError("the default scale is simulate's, from t = 0: give a scale for a grid from t0 != 0")
    scale = _default_scale(loop, eta0, t_grid[-1], max_step) if scale is None else np.asarray(scale, dtype=float)
    run = _march(loop, eta0, t_grid, rtol, scale, max_step, METHODS[method])
    return Recording(run.t, run.eta, loop.controls(run.t, run.eta), run.success, run.message, run.steps,
                     run.solver.nfev, run.solver.njev, scale, method)


def diagnose(recording: Recording, controller: Controller, reference: Reference | None = None) -> Result:
    """The recording with the target system eta*(t) of its controller (eq. (desired trajectory) when
    tracking, the set-point otherwise): the diagnostics a benchmark computes outside its timing."""
    loop = ClosedLoop(controller, reference)
    r = recording
    return Result(r.t, r.eta, r.u, loop.targets(r.t), r.success, r.message, r.n_steps, r.scale)


def _default_scale(loop: ClosedLoop, eta0: np.ndarray, t_end: float, max_step: float) -> np.ndarray:
    """s_i = max_t |eta_i|, |eta*_i| of a first pass at rtol = 1e-6 (module doc)."""
    first = _integrate(loop, eta0, t_end, 201, 1e-6, _first_scale(loop, eta0, t_end), max_step)
    scale = np.max(np.abs(np.vstack([first.eta, first.eta_star])), axis=0)
    return np.where(scale > 0, scale, 1.0)


def _first_scale(loop: ClosedLoop, eta0: np.ndarray, t_end: float) -> np.ndarray:
    """Rough state scales for the first pass: |eta0|, |eta*| at a few times, and for the momentum
    m |q_scale| / (a hundredth of the horizon)."""
    samples = [np.abs(eta0)] + [np.abs(loop.target(t)) for t in np.linspace(0, t_end, 11)]
    s = np.max(samples, axis=0)
    m_idx = slice(loop.plant.n_m, 2 * loop.plant.n_m)
    q_idx = slice(0, loop.plant.n_m)
    M = np.linalg.inv(loop.plant.M_inv(eta0[q_idx]))
    s[m_idx] = np.maximum(s[m_idx], np.abs(M @ s[q_idx]) / (0.01 * t_end))
    return np.where(s > 0, s, 1.0)


def _integrate(loop: ClosedLoop, eta0, t_end, n_samples, rtol, scale, max_step) -> Result:
    run = _march(loop, eta0, np.linspace(0.0, t_end, n_samples), rtol, scale, max_step, Radau)
    u, eta_star = loop.controls(run.t, run.eta), loop.targets(run.t)
    return Result(run.t, run.eta, u, eta_star, run.success, run.message, run.steps, scale)


@dataclass
class _Run:
    t: np.ndarray
    eta: np.ndarray
    success: bool
    message: str
    steps: int
    solver: object


def _march(loop: ClosedLoop, eta0, t_grid, rtol, scale, max_step, method) -> _Run:
    """Step `method` on the scaled states xi = eta / scale from t_grid[0], with the exact Jacobian, and
    sample eta at t_grid by the solver's dense output; stop cleanly at a domain exit or a failure."""
    fun = lambda t, xi: loop.rhs(t, xi * scale) / scale                      # noqa: E731
    jac = lambda t, xi: loop.jacobian(t, xi * scale) * scale[None, :] / scale[:, None]  # noqa: E731
    solver = method(fun, t_grid[0], eta0 / scale, t_grid[-1], rtol=rtol, atol=rtol, jac=jac, max_step=max_step)
    out = [eta0]
    k = 1                                                       # next grid index to fill
    message, success, steps = "reached t_end", True, 0
    while solver.status == "running":
        try:
            err = solver.step()
            steps += 1
            if err is not None:
                raise RuntimeError(err)
            if loop.plant.domain_margin(solver.y * scale) <= 0:
                loop.plant.check_state(solver.y * scale)           # raises DomainError with the reason
        except (ValueError, ArithmeticError, RuntimeError, np.linalg.LinAlgError) as exc:
            message, success = f"stopped at t = {solver.t:.6g} s: {exc}", False
            break
        if k < len(t_grid) and t_grid[k] <= solver.t:
            dense = solver.dense_output()
            while k < len(t_grid) and t_grid[k] <= solver.t:
                out.append(dense(t_grid[k]) * scale)
                k += 1
    return _Run(t_grid[:len(out)], np.array(out), success, message, steps, solver)


def open_loop_exit(plant: EMPlant, eta0, u, t_end: float, rtol: float = 1e-8) -> float | None:
    """The time at which the open loop eta' = f(eta, u) (eq. open-loop elecmech, u held) from eta0 leaves the
    plant's admissible domain, or None if it stays inside over [0, t_end] (scipy's Radau with the exact
    Jacobian F hess H; an event on the domain margin)."""
    from scipy.integrate import solve_ivp

    from .plant_step import nominal_scale

    u = np.atleast_1d(np.asarray(u, dtype=float))

    def margin(t, eta):
        return plant.domain_margin(eta)
    margin.terminal = True                                   # type: ignore[attr-defined]
    margin.direction = -1                                    # type: ignore[attr-defined]
    scale = np.maximum(np.abs(np.asarray(eta0, dtype=float)), nominal_scale(plant))
    sol = solve_ivp(lambda t, eta: plant.f(eta, u), (0.0, t_end), np.asarray(eta0, dtype=float), method="Radau",
                    rtol=rtol, atol=rtol * scale, jac=lambda t, eta: plant.jacobian(eta), events=margin)
    if sol.status == 1 and len(sol.t_events[0]):
        return float(sol.t_events[0][0])
    if not sol.success:
        return float(sol.t[-1])
    return None
