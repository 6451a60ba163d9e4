"""Theorem 2: contraction-based tracking for the mechanically damped class (Assumption 3).

The control law eq. (u1-track) has the form of eq. (c1) with a time-varying Theta_1(x_e, t):
    u = G_e^-1 { D_d M^-1(q) p - K_e Psi(q) x_e + (J_e - R_e_bar) grad Theta_1(x_e, t) }
and closes the loop into eq. (closedloop) with Gamma = 0, H_d = H + Theta_1 (eq. HdClass3).
With Theta_1 = 1/2 (x_e - x_e* + L_2)^T W (x_e - x_e* + L_2), the feasibility condition (feasibleT2)
    x_e*' = D_d M^-1 p* + (J_e - R_e_bar) (Psi(q*) x_e* + W L_2)
gives L_2 = W^-1 [ (J_e - R_e_bar)^-1 (x_e*' - D_d M^-1 p*) - Psi(q*) x_e* ]; for the MEMS with
W = 1 this is the paper's L_2 = -rbar_e x_e*' - x_e*/(c1 (q* + c0)) + rbar_e D_d p*/m.
D_d need not satisfy eq. (pHcondition) (Remark after Theorem 2).
"""
from __future__ import annotations

import numpy as np

from .controller import Controller, as_matrix, check_positive_definite, quadratic
from .ph_plant import EMPlant, Jet
from .proposition1 import law_c1


class Theorem2(Controller):
    """Tracking (and, with a constant jet, regulation) for Assumption 3 plants such as the MEMS."""

    name = "Theorem 2"
    tracking = True

    def __init__(self, plant: EMPlant, R_e_bar, D_d=0.0, W=None):
        super().__init__(plant, R_e_bar, D_d, np.zeros((plant.n_m, plant.n_e)))
        self.W = as_matrix(np.eye(plant.n_e) if W is None else W, (plant.n_e, plant.n_e), "W", self.name)
        check_positive_definite(self.W, "W", self.name)
        self.bind_law("c1", self.W)                                    # eq. (u1-track), generated (n = 1)

    def L2(self, jet: Jet) -> np.ndarray:
        """Offset L_2(t) from the feasibility condition (feasibleT2)."""
        return self._offsets(jet)[1]

    def _offsets(self, jet: Jet) -> tuple[np.ndarray, np.ndarray]:
        """(center, L_2): Theta_1 = 1/2 (x_e - center)^T W (x_e - center), center = x_e* - L_2."""
        plant = self.plant
        eta_s, xe_dot_s = plant.feasible_state(jet)
        q_s, p_s, x_s = plant.split(eta_s)
        inner = np.linalg.solve(self.JR_bar, xe_dot_s - self.D_d @ plant.M_inv(q_s) @ p_s)
        L2 = np.linalg.solve(self.W, inner - plant.Psi(q_s) @ x_s)          # eq. (feasibleT2)
        return x_s - L2, L2

    def u_matrix(self, eta, jet):
        x_e = self.plant.split(eta)[2]
        return law_c1(self, eta, self.W @ (x_e - self._offsets(jet)[0]))     # eq. (u1-track)

    def H_d(self, eta, jet):
        x_e = self.plant.split(eta)[2]
        return self.plant.H(eta) + quadratic(x_e, self._offsets(jet)[0], self.W)   # eq. (HdClass3)

    def hess_H_d(self, eta, jet):
        return self.plant.hess_H(eta) + self._embed_xe(self.W)

    def target(self, jet):
        return self.plant.feasible_state(jet)[0]
