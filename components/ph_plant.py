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

    # ---- feasible references (Definition 1) --------------------------------------------------
    def feasible_state(self, jet: Jet) -> tuple[np.ndarray, np.ndarray]:
        """(eta*, x_e*') of a reference jet, from the mechanical equations (Definition 1).

        The p-row of eq. (open-loop elecmech) gives the electrical force the reference needs,
        -grad_q H_e(q*, x_e*) = p*' + grad_q H_1(q*, p*) + R_m q*'  =: F*,
        which determines x_e*. This generic form covers n_m = n_e = 1 with constant M, where
        -1/2 Psi'(q) x_e^2 = F* has the real root x_e* = s sqrt(2 F* / (-Psi'(q*))), s = self.x_e_sign,
        when F*/(-Psi'(q*)) > 0. Plants of other dimensions override this method.
        """
        if self.n_m != 1 or self.n_e != 1 or not self.constant_mass:
            raise NotImplementedError(f"{self.name}: feasible_state needs n_m = n_e = 1 and constant M; "
                                      "override it for this plant")
        q, qd, qdd, qddd = (np.atleast_1d(np.asarray(v, dtype=float)) for v in (jet.q, jet.qd, jet.qdd, jet.qddd))
        self.check_state(np.concatenate([q, np.zeros(self.n_m + self.n_e)]))
        m = 1.0 / self.M_inv(q)[0, 0]
        Rm = self.R_m[0, 0]
        force = m * qdd + Rm * qd + self.grad_V(q)                           # F* (p-row)
        force_dot = m * qddd + Rm * qdd + self.hess_V(q)[0, 0] * qd          # dF*/dt
        g = -self.dPsi(q)[0, 0, 0]                                          # -Psi'(q*)
        g_dot = -self.d2Psi(q)[0, 0, 0, 0] * qd[0]
        ratio = 2.0 * force[0] / g
        if not ratio > 0:
            raise ValueError(
                f"{self.name}: infeasible reference at q* = {q[0]:.6g}: no real x_e* solves "
                f"-1/2 Psi'(q*) x_e*^2 = m q*'' + R_m q*' + V'(q*) = {force[0]:.6g} "
                f"(needs (m q*'' + R_m q*' + V'(q*)) / (-Psi'(q*)) > 0)")
        x_e = self.x_e_sign * np.sqrt(ratio)
        # d/dt (x_e^2) = 2 (F' g - F g') / g^2  =>  x_e' = (F' g - F g') / (x_e g^2)
        x_e_dot = (force_dot[0] * g - force[0] * g_dot) / (x_e * g * g)
        p = m * qd
        return np.concatenate([q, p, [x_e]]), np.array([x_e_dot])

    x_e_sign: float = 1.0
    """Which root of the electrical equilibrium equation the reference uses (+1: positive charge / flux)."""

    def equilibrium(self, q_d: np.ndarray) -> np.ndarray:
        """Assignable equilibrium eta_d = (q_d, 0, x_e_d) of the set E (Section 3)."""
        z = np.zeros(self.n_m)
        return self.feasible_state(Jet(np.atleast_1d(np.asarray(q_d, dtype=float)), z, z, z))[0]
