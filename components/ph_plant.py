"""Weakly coupled electromechanical (EM) systems as port-Hamiltonian systems, eq. (open-loop elecmech).

State eta = (q, p, x_e): generalised positions q (n_m), momenta p (n_m), electrical states x_e (n_e).
Hamiltonian (eq. open-loop elecmech, eq. elec energy):

    H(eta) = 1/2 p^T M(q)^-1 p + V(q) + 1/2 x_e^T Psi(q) x_e

Dynamics:  eta' = F grad H(eta) + g u,  F = [[0, I, 0], [-I, -R_m, 0], [0, 0, J_e - R_e]],
g = [0; 0; G_e]. Because F and g are constant, the Jacobian is df/deta = F hess H(eta).

A concrete plant subclasses `EMPlant` and supplies M^-1(q), V(q), Psi(q) and their derivatives.
Every function accepts complex arrays, so derivatives can be checked by the complex step.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np


class DomainError(ValueError):
    """A state outside the model's admissible domain (e.g. a closed MEMS gap)."""


@dataclass(frozen=True)
class Jet:
    """Reference jet (q*, q*', q*'', q*''') at one instant; each entry has shape (n_m,)."""

    q: np.ndarray
    qd: np.ndarray
    qdd: np.ndarray
    qddd: np.ndarray


class EMPlant:
    """General weakly coupled EM plant, eq. (open-loop elecmech).

    Subclasses set n_m, n_e and the constant matrices R_m (mechanical damping, n_m x n_m, >= 0),
    J_e (electrical interconnection, skew), R_e (electrical damping, >= 0) and G_e (input matrix,
    full rank), and implement the q-dependent functions below.
    """

    n_m: int
    n_e: int
    R_m: np.ndarray
    J_e: np.ndarray
    R_e: np.ndarray
    G_e: np.ndarray
    name: str = "EM plant"

    # ---- model functions a concrete plant provides -------------------------------------------
    def M_inv(self, q: np.ndarray) -> np.ndarray:
        """Inverse mass-inertia matrix M(q)^-1 (n_m x n_m)."""
        raise NotImplementedError

    constant_mass: bool = True
    """True when M does not depend on q (then dM_inv and d2M_inv are zero and are skipped)."""

    def dM_inv(self, q: np.ndarray) -> np.ndarray:
        """d M^-1 / d q_k stacked on axis 0 (n_m x n_m x n_m). Zero for a constant mass."""
        return np.zeros((self.n_m, self.n_m, self.n_m))

    def d2M_inv(self, q: np.ndarray) -> np.ndarray:
        """d^2 M^-1 / d q_k d q_l (n_m x n_m x n_m x n_m). Zero for a constant mass."""
        return np.zeros((self.n_m,) * 4)

    def V(self, q: np.ndarray):
        """Mechanical potential energy V(q) [J]."""
        raise NotImplementedError

    def grad_V(self, q: np.ndarray) -> np.ndarray:
        raise NotImplementedError

    def hess_V(self, q: np.ndarray) -> np.ndarray:
        raise NotImplementedError

    def Psi(self, q: np.ndarray) -> np.ndarray:
        """Inverse capacitance / inductance matrix Psi(q) (n_e x n_e), eq. (elec energy)."""
        raise NotImplementedError

    def dPsi(self, q: np.ndarray) -> np.ndarray:
        """d Psi / d q_k stacked on axis 0 (n_m x n_e x n_e)."""
        raise NotImplementedError

    def d2Psi(self, q: np.ndarray) -> np.ndarray:
        """d^2 Psi / d q_k d q_l (n_m x n_m x n_e x n_e)."""
        raise NotImplementedError

    def domain_margin(self, eta: np.ndarray) -> float:
        """Positive inside the admissible domain, zero on its boundary (default: no boundary)."""
        return np.inf

    def check_state(self, eta: np.ndarray) -> None:
        """Raise DomainError if eta is outside the admissible domain or not finite."""
        if not np.all(np.isfinite(eta)):
            raise DomainError(f"{self.name}: state {eta} is not finite")

    # ---- structure ---------------------------------------------------------------------------
    @property
    def n(self) -> int:
        return 2 * self.n_m + self.n_e

    def split(self, eta: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(q, p, x_e) views of eta."""
        eta = np.asarray(eta)
        m = self.n_m
        return eta[:m], eta[m:2 * m], eta[2 * m:]

    def F(self) -> np.ndarray:
        """Open-loop structure matrix J - R of eq. (open-loop elecmech)."""
        cached = self.__dict__.get("_F")
        if cached is not None:
            return cached
        m = self.n_m
        F = np.zeros((self.n, self.n))
        F[:m, m:2 * m] = np.eye(m)
        F[m:2 * m, :m] = -np.eye(m)
        F[m:2 * m, m:2 * m] = -self.R_m
        F[2 * m:, 2 * m:] = self.J_e - self.R_e
        self._F = F                        # plant matrices are fixed after construction
        return F

    def g(self) -> np.ndarray:
        """Input matrix [0; 0; G_e] of eq. (open-loop elecmech)."""
        g = np.zeros((self.n, self.n_e))
        g[2 * self.n_m:, :] = self.G_e
        return g

    # ---- energy ------------------------------------------------------------------------------
    def H_e(self, q: np.ndarray, x_e: np.ndarray):
        """Coupling (electrical) energy 1/2 x_e^T Psi(q) x_e, eq. (elec energy)."""
        return 0.5 * x_e @ self.Psi(q) @ x_e

    def H_mech(self, q: np.ndarray, p: np.ndarray):
        """Mechanical energy H_1(q, p) = 1/2 p^T M^-1 p + V(q) (eq. HdClass4)."""
        return 0.5 * p @ self.M_inv(q) @ p + self.V(q)

    def H(self, eta: np.ndarray):
        """Hamiltonian, eq. (open-loop elecmech)."""
        q, p, x_e = self.split(eta)
        return self.H_mech(q, p) + self.H_e(q, x_e)

    def grad_H(self, eta: np.ndarray) -> np.ndarray:
        """grad H = (grad_q H, M^-1 p, Psi x_e)."""
        q, p, x_e = self.split(eta)
        grad_q = self.grad_V(q) + 0.5 * np.einsum("i,kij,j->k", x_e, self.dPsi(q), x_e)
        if not self.constant_mass:
            grad_q = grad_q + 0.5 * np.einsum("i,kij,j->k", p, self.dM_inv(q), p)
        return np.concatenate([grad_q, self.M_inv(q) @ p, self.Psi(q) @ x_e])

    def hess_H(self, eta: np.ndarray) -> np.ndarray:
        """Hessian of H (n x n)."""
        q, p, x_e = self.split(eta)
        m = self.n_m
        Mi, dMi, d2Mi = self.M_inv(q), self.dM_inv(q), self.d2M_inv(q)
        Psi, dPsi, d2Psi = self.Psi(q), self.dPsi(q), self.d2Psi(q)
        Hqq = (self.hess_V(q)
               + 0.5 * np.einsum("i,klij,j->kl", p, d2Mi, p)
               + 0.5 * np.einsum("i,klij,j->kl", x_e, d2Psi, x_e))
        Hqp = np.einsum("kij,j->ki", dMi, p)        # d(grad_q H)_k / d p_i
        Hqx = np.einsum("kij,j->ki", dPsi, x_e)     # d(grad_q H)_k / d x_e_i
        Hs = np.zeros((self.n, self.n), dtype=np.result_type(eta, float))
        Hs[:m, :m] = Hqq
        Hs[:m, m:2 * m] = Hqp
        Hs[m:2 * m, :m] = Hqp.T
        Hs[:m, 2 * m:] = Hqx
        Hs[2 * m:, :m] = Hqx.T
        Hs[m:2 * m, m:2 * m] = Mi
        Hs[2 * m:, 2 * m:] = Psi
        return Hs

    # ---- dynamics ----------------------------------------------------------------------------
    def f(self, eta: np.ndarray, u: np.ndarray) -> np.ndarray:
        """eta' = F grad H(eta) + g u, eq. (open-loop elecmech)."""
        u = np.atleast_1d(u)
        dx = self.F() @ self.grad_H(eta)
        dx[2 * self.n_m:] = dx[2 * self.n_m:] + self.G_e @ u
        return dx

    def jacobian(self, eta: np.ndarray) -> np.ndarray:
        """df/deta = F hess H(eta) (F and g constant)."""
        return self.F() @ self.hess_H(eta)

    def time_derivatives(self, eta: np.ndarray, u, u_dot=0.0) -> tuple[np.ndarray, np.ndarray, float, float]:
        """(eta', eta'', H', H'') along the motion at state eta with input u and input rate u_dot:

            eta'  = f(eta, u) = F grad H + g u                      (eq. open-loop elecmech)
            eta'' = F hess H(eta) eta' + g u_dot                     (F, g constant)
            H'    = grad H . eta' = -grad H^T R grad H + y^T u,  y = g^T grad H   (power balance)
            H''   = eta'^T hess H eta' + grad H . eta''
        """
        u, u_dot = np.atleast_1d(u), np.atleast_1d(u_dot)
        gH, hH = self.grad_H(eta), self.hess_H(eta)
        d1 = self.f(eta, u)
        d2 = self.F() @ (hH @ d1) + self.g() @ u_dot
        return d1, d2, float(gH @ d1), float(d1 @ hH @ d1 + gH @ d2)

    # ---- feasible references (Definition 1) --------------------------------------------------
    def feasible_state(self, jet: Jet) -> tuple[np.ndarray, np.ndarray]:
        """(eta*, x_e*') of a reference jet, from the mechanical equations (Definition 1).

        The p-row of eq. (open-loop elecmech) fixes the electrical force -grad_q H_e(q*, x_e*) that
        the reference needs; which x_e* delivers it depends on the plant (OneDOFPlant.feasible_scalar
        for n_m = n_e = 1). Plants of other dimensions implement this method.
        """
        raise NotImplementedError(f"{self.name}: feasible_state is not implemented for this plant")

    x_e_sign: float = 1.0
    """Which root of the electrical equilibrium equation the reference uses (+1: positive charge / flux)."""

    def equilibrium(self, q_d: np.ndarray) -> np.ndarray:
        """Assignable equilibrium eta_d = (q_d, 0, x_e_d) of the set E (Section 3).

        At rest the p-row of eq. (open-loop elecmech) reads grad V(q_d) + grad_q H_e(q_d, x_e_d) = 0. Where the
        potential holds the position alone (grad V(q_d) = 0, e.g. a relaxed spring) x_e_d = 0 solves it (the
        electrical force is quadratic in x_e), whatever root `feasible_state` would look for."""
        q = np.atleast_1d(np.asarray(q_d, dtype=float))
        z = np.zeros(self.n_m)
        if q.shape == (self.n_m,) and np.all(np.isfinite(q)) and not np.any(self.grad_V(q)):
            eta = np.concatenate([q, z, np.zeros(self.n_e)])
            self.check_state(eta)
            return eta
        return self.feasible_state(Jet(q, z, z, z))[0]


class OneDOFPlant(EMPlant):
    """A plant with n_m = n_e = 1 and a constant mass m (both of the paper's Section 7 examples).

    A subclass writes its model once, as scalar functions of the position q (floats, or complex
    numbers for the complex-step tests): V_s, dV, d2V (the potential energy and its derivatives) and
    psi, dpsi, d2psi (Psi(q) of eq. (elec energy) and its derivatives); it sets m, R_m, J_e, R_e, G_e.
    EMPlant's matrix interface is built from these functions. The per-step code paths (controllers
    in FMUs, the plant integrator in doStep) call the scalar functions: numpy's cost per call on
    1 x 1 arrays would dominate there.
    """

    n_m = 1
    n_e = 1
    constant_mass = True
    m: float
    q_min: float = -math.inf
    q_max: float = math.inf
    """The model's admissible positions q_min < q < q_max (a subclass sets them from its parameters)."""

    def domain_margin(self, eta) -> float:
        """Distance of q to the nearer end of q_min < q < q_max (positive inside)."""
        q = eta[0].real
        return float(min(q - self.q_min, self.q_max - q))

    # ---- the model in scalars (a concrete plant implements these) --------------------------------
    def V_s(self, q):
        """Potential energy V(q) [J]."""
        raise NotImplementedError

    def dV(self, q):
        """V'(q) [N]."""
        raise NotImplementedError

    def d2V(self, q):
        """V''(q) [N/m]."""
        raise NotImplementedError

    def psi(self, q):
        """Psi(q), the inverse capacitance or inductance of eq. (elec energy)."""
        raise NotImplementedError

    def dpsi(self, q):
        """Psi'(q)."""
        raise NotImplementedError

    def d2psi(self, q):
        """Psi''(q)."""
        raise NotImplementedError

    # ---- EMPlant's matrix interface ----------------------------------------------------------------
    def M_inv(self, q):
        return np.array([[1.0 / self.m]])

    def V(self, q):
        return self.V_s(q[0])

    def grad_V(self, q):
        return np.array([self.dV(q[0])])

    def hess_V(self, q):
        return np.array([[self.d2V(q[0])]])

    def Psi(self, q):
        return np.array([[self.psi(q[0])]])

    def dPsi(self, q):
        return np.array([[[self.dpsi(q[0])]]])

    def d2Psi(self, q):
        return np.array([[[[self.d2psi(q[0])]]]])

    def H(self, eta):
        """Hamiltonian p^2/(2m) + V(q) + Psi(q) x_e^2 / 2, eq. (open-loop elecmech), in scalars."""
        q, p, x_e = eta[0], eta[1], eta[2]
        return 0.5 * p * p / self.m + self.V_s(q) + 0.5 * self.psi(q) * x_e * x_e

    # ---- feasible references (Definition 1) --------------------------------------------------------
    def feasible_state(self, jet: Jet) -> tuple[np.ndarray, np.ndarray]:
        q, p, x_e, x_e_dot = self.feasible_scalar(*(float(np.asarray(v).reshape(-1)[0])
                                                     for v in (jet.q, jet.qd, jet.qdd, jet.qddd)))
        return np.array([q, p, x_e]), np.array([x_e_dot])

    def feasible_scalar(self, q, qd, qdd, qddd) -> tuple:
        """(q*, p*, x_e*, x_e*') of the reference jet (q*, q*', q*'', q*'''), Definition 1: the p-row of
        eq. (open-loop elecmech) gives the electrical force the reference needs,
            -1/2 Psi'(q*) x_e*^2 = m q*'' + R_m q*' + V'(q*) =: F*,
        whose real root is x_e* = s sqrt(2 F* / g), g = -Psi'(q*), s = x_e_sign, when F* / g > 0, and
        x_e*' = (F*' g - F* g') / (x_e* g^2). Stated once, in components.laws.feasible_reference; a described
        plant's generated module prints it (components.codegen). Takes complex numbers (complex step)."""
        raise NotImplementedError(f"{self.name}: feasible_scalar is generated from a description (components.codegen)")

    def infeasible_reference(self, q) -> None:
        """Raise the ValueError of a reference jet at q* that no real x_e* holds (Definition 1)."""
        raise ValueError(
            f"{self.name}: infeasible reference at q* = {q.real:.6g}: no real x_e* solves -1/2 Psi'(q*) x_e*^2 = "
            "m q*'' + R_m q*' + V'(q*) =: F* (needs F* / (-Psi'(q*)) > 0)")
