"""Monolithic closed-loop reference: plant + static controller as one ODE, eta' = f(eta, u(eta, t)).

Integrated with scipy's Radau (implicit, order 5, L-stable) with the exact Jacobian
df/deta + g du/deta (plant: analytic, controller: complex step). The MEMS closed loop is stiff
(electrical time constant ~1e-10 s against ~1e-4 s for the mechanics) and its states differ by
ten orders of magnitude, so the integration runs on scaled states xi_i = eta_i / s_i, and the
tolerance is per state: |error_i| <= rtol |eta_i| + atol s_i. By default s_i = max_t |eta_i(t)|
from a first pass at rtol = 1e-6 (see docs/derivations.md, "Monolithic reference").

The integration stops cleanly (results so far kept, `message` says why) when the state leaves the
plant's domain, when the reference becomes infeasible, or when the solver fails.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.integrate import Radau

from . import differentiation
from .controller import Controller
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
    if scale is None:
        first = _integrate(loop, eta0, t_end, 201, 1e-6, _first_scale(loop, eta0, t_end), max_step)
        scale = np.max(np.abs(np.vstack([first.eta, first.eta_star])), axis=0)
        scale = np.where(scale > 0, scale, 1.0)
    return _integrate(loop, eta0, t_end, n_samples, rtol, np.asarray(scale, dtype=float), max_step)


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
    t_grid = np.linspace(0.0, t_end, n_samples)
    fun = lambda t, xi: loop.rhs(t, xi * scale) / scale                      # noqa: E731
    jac = lambda t, xi: loop.jacobian(t, xi * scale) * scale[None, :] / scale[:, None]  # noqa: E731
    solver = Radau(fun, 0.0, eta0 / scale, t_end, rtol=rtol, atol=rtol, jac=jac, max_step=max_step)
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
        if k < n_samples and t_grid[k] <= solver.t:
            dense = solver.dense_output()
            while k < n_samples and t_grid[k] <= solver.t:
                out.append(dense(t_grid[k]) * scale)
                k += 1
    t = t_grid[:len(out)]
    eta = np.array(out)
    u = np.array([loop.u(e, tt) for e, tt in zip(eta, t)])
    eta_star = np.array([loop.target(tt) for tt in t])
    return Result(t, eta, u, eta_star, success, message, steps, scale)
