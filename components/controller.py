"""What the four static controllers share: the design matrices and the target structure F_d.

Every controller maps a plant state eta (and, for tracking, a reference jet) to the input u, and
states the closed loop it enforces: eta' = F_d grad H_d(eta, t), eq. (closedloop).
"""
from __future__ import annotations

import math
from typing import Callable, Sequence

import numpy as np

from . import closed_loop
from .ph_plant import EMPlant, Jet, OneDOFPlant

# Complex step of `Controller.u_derivative`: the imaginary perturbation of each input is at most
# COMPLEX_STEP times its magnitude (or COMPLEX_STEP_FLOOR, for an input at zero), so the neglected
# O(h^2) terms are ~1e-40 relative; Im(u) = h (du/dx) v then stays far above the subnormal range.
COMPLEX_STEP = 1e-20
COMPLEX_STEP_FLOOR = 1e-150


def as_matrix(value, shape: tuple[int, int], name: str, owner: str) -> np.ndarray:
    """A scalar or array parameter as a float matrix of `shape`, or a ValueError naming it."""
    try:
        a = np.array(value, dtype=float)
    except (TypeError, ValueError):
        raise ValueError(f"{owner}: parameter {name} = {value!r} is not a number or matrix") from None
    if a.ndim == 0:
        a = a * np.eye(shape[0], shape[1]) if shape[0] == shape[1] else np.full(shape, float(a))
    if a.shape != shape:
        raise ValueError(f"{owner}: parameter {name} has shape {a.shape}, expected {shape}")
    if not np.all(np.isfinite(a)):
        raise ValueError(f"{owner}: parameter {name} = {a.tolist()} must be finite")
    return a


def check_positive_definite(W: np.ndarray, name: str, owner: str) -> None:
    """Weights of the quadratic Phi/Theta must be symmetric positive definite (k_c > 0 in the paper)."""
    if not np.allclose(W, W.T) or not np.min(np.linalg.eigvalsh(W)) > 0:
        raise ValueError(f"{owner}: parameter {name} = {W.tolist()} violates {name} > 0 "
                         "(symmetric positive definite)")


def quadratic(x: np.ndarray, center: np.ndarray, W: np.ndarray):
    """1/2 (x - center)^T W (x - center): the quadratic Phi/Theta of the paper's examples."""
    d = x - center
    return 0.5 * d @ W @ d


class Controller:
    """Base of the four controllers.

    plant    the EM plant (eq. open-loop elecmech)
    R_e_bar  desired electrical damping R_e + K_e > 0 (eq. barRe), n_e x n_e
    D_d      coupled damping, n_e x n_m (eq. closedloop)
    Gamma    coupling matrix of the target structure, n_m x n_e (zero for Prop. 1 and Thm. 2)
    """

    name = "controller"
    tracking = False

    def __init__(self, plant: EMPlant, R_e_bar, D_d, Gamma):
        self.plant = plant
        m, e = plant.n_m, plant.n_e
        self.R_e_bar = as_matrix(R_e_bar, (e, e), "R_e_bar", self.name)
        self.D_d = as_matrix(D_d, (e, m), "D_d", self.name)
        self.Gamma = as_matrix(Gamma, (m, e), "Gamma", self.name)
        closed_loop.check_R_e_bar(self.R_e_bar, plant.J_e, self.name)
        self.K_e = self.R_e_bar - plant.R_e                       # eq. (barRe)
        self.JR_bar = plant.J_e - self.R_e_bar                    # J_e - R_e_bar, invertible
        self.G_inv = np.linalg.inv(plant.G_e)
        self.scalars: Callable | None = None
        """The law in scalars for a described one-degree-of-freedom plant: the function its generated module
        prints from components.laws (components.codegen; no numpy on the per-step path), u = scalars(q, p, x_e)
        for regulation and u = scalars(q, p, x_e, q*, dq*/dt, d2q*/dt2, d3q*/dt3) for tracking; None for any
        other plant."""
        self.vector_law: Callable | None = None
        """The law of a described plant of any n (components.laws, printed by components.codegen): u(eta) for
        regulation, u(eta, eta*, x_e*') for tracking (eta*, x_e*' of Definition 1, EMPlant.feasible_state);
        None for plants written as Python classes (u_matrix)."""

    def bind_law(self, family: str, gain, reference: np.ndarray | None = None) -> None:
        """Set `scalars` (a described one-DOF plant) or `vector_law` (a described plant of any other n) from the
        plant's generated law of `family` ("c1" or "u2", components.laws) with the gains R_e_bar, D_d and `gain`
        (W or K_c), at the constant reference eta_d = `reference` (regulation: p* = 0, x_e*' = 0) or along the
        reference (tracking). A plant written as a Python class has no generated laws: it keeps u_matrix."""
        if not isinstance(self.plant, OneDOFPlant):
            factory = getattr(self.plant, f"law_{family}_{'ref' if self.tracking else 'at'}", None)
            if factory is not None:                          # a described plant of any n
                self.vector_law = (factory(self.R_e_bar, self.D_d, gain) if self.tracking else
                                   factory(self.R_e_bar, self.D_d, gain, reference, np.zeros(self.plant.n_e)))
            return
        factory = getattr(self.plant, f"law_{family}_{'tracking' if self.tracking else 'at'}", None)
        if factory is None:
            return
        gains = (float(self.R_e_bar[0, 0]), float(self.D_d[0, 0]), float(np.asarray(gain)[0, 0]))
        if self.tracking:
            self.scalars = factory(*gains)
        else:
            q_d, _, x_ed = (float(v) for v in np.asarray(reference))
            self.scalars = factory(*gains, q_d, 0.0, x_ed, 0.0)

    def F_d(self) -> np.ndarray:
        """Target structure matrix F_d = J_d - R_d, eqs. (closedloop), (Eq:R-J)."""
        p = self.plant
        return closed_loop.F_d(p.R_m, p.J_e, self.R_e_bar, self.Gamma, self.D_d)

    def u(self, eta: np.ndarray, jet: Jet | None = None) -> np.ndarray:
        """The control law at state eta (and reference jet, if tracking): u, shape (n_e,)."""
        if self.scalars is not None:
            jet_values = tuple(v[0] for v in (jet.q, jet.qd, jet.qdd, jet.qddd)) if self.tracking else ()
            return np.array([self.scalars(eta[0], eta[1], eta[2], *jet_values)])
        if self.vector_law is not None:
            if self.tracking:
                eta_s, x_e_s_dot = self.plant.feasible_state(jet)
                return self.vector_law(eta, eta_s, x_e_s_dot)
            return self.vector_law(eta)
        return self.u_matrix(eta, jet)

    def u_matrix(self, eta: np.ndarray, jet: Jet | None = None) -> np.ndarray:
        """The control law in the paper's general matrix form."""
        raise NotImplementedError

    def u_scalar(self, q, p, x_e, jet: tuple | None = None):
        """u for a described one-DOF plant from the numbers q, p, x_e and, tracking, the jet (q*, dq*/dt,
        d2q*/dt2, d3q*/dt3): `scalars`, generated. Accepts complex numbers (complex-step derivatives)."""
        if self.scalars is None:
            raise ValueError(f"{self.name}: no law in scalars for the plant {self.plant.name} (u_matrix)")
        return self.scalars(q, p, x_e, *jet) if self.tracking else self.scalars(q, p, x_e)

    def u_derivative(self, inputs: Sequence[float], directions: Sequence[float]):
        """sum_j du/dx_j v_j: the exact derivative of u along a direction v of the controller's inputs
        x = (q, p, x_e) or, tracking, (q, p, x_e, q*, q*', q*'', q*''') (each a number for a one-DOF
        plant, else q, p, x_e and the jet entries concatenated), by one complex-step evaluation of the
        law (docs/derivations.md, "Controller Jacobians"). With v = dx/dt it is du/dt; with v = e_j,
        the Jacobian's column j. A number for a one-DOF plant, else an array of shape (n_e,)."""
        x, v = inputs, directions
        if len(x) != len(v):
            raise ValueError(f"{self.name}: {len(x)} inputs but {len(v)} directions")
        if not all(math.isfinite(a) for a in (*x, *v)):          # each: a sum of finite values may overflow
            raise ValueError(f"{self.name}: inputs {list(x)} or directions {list(v)} are not finite")
        ratio = 0.0
        for xi, vi in zip(x, v):
            r = abs(vi) / max(abs(xi), COMPLEX_STEP_FLOOR)
            if r > ratio:
                ratio = r
        if ratio == 0.0:
            return 0.0 if self.scalars is not None else np.zeros(self.plant.n_e)
        h = COMPLEX_STEP / ratio                    # |h v_j| <= 1e-20 max(|x_j|, floor) for every input j
        z = [complex(xi, h * vi) for xi, vi in zip(x, v)]
        n = self.plant.n
        if self.scalars is not None:
            return self.scalars(*z).imag / h
        m = self.plant.n_m
        jet = Jet(*np.reshape(np.array(z[n:]), (4, m))) if self.tracking else None
        return np.imag(self.u(np.array(z[:n]), jet)) / h

    def H_d(self, eta: np.ndarray, jet: Jet | None = None):
        """Desired Hamiltonian; written independently of u, so grad H_d can check the matching."""
        raise NotImplementedError

    def hess_H_d(self, eta: np.ndarray, jet: Jet | None = None) -> np.ndarray:
        """Hessian of H_d (analytic; the closed-loop Jacobian is F_d hess H_d)."""
        raise NotImplementedError

    def target(self, jet: Jet | None = None) -> np.ndarray:
        """The state the closed loop should be at: eta_d (regulation) or eta*(t) (tracking)."""
        raise NotImplementedError

    def _embed_xe(self, block: np.ndarray) -> np.ndarray:
        """An n_e x n_e block placed at the x_e-x_e position of an n x n matrix."""
        out = np.zeros((self.plant.n, self.plant.n))
        out[2 * self.plant.n_m:, 2 * self.plant.n_m:] = block
        return out


def hess_H_mech(plant: EMPlant, eta: np.ndarray) -> np.ndarray:
    """Hessian of H_1(q, p) = 1/2 p^T M^-1 p + V(q) as an n x n matrix (zero x_e rows and columns)."""
    q, p, _ = plant.split(eta)
    h = plant.hess_H(np.concatenate([q, p, np.zeros(plant.n_e)]))
    h[2 * plant.n_m:, :] = 0.0
    h[:, 2 * plant.n_m:] = 0.0
    return h
