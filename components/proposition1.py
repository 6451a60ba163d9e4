"""Proposition 1: regulation of the mechanically damped class (Assumption 1), control law eq. (c1).

    u = G_e^-1 { (J_e - R_e_bar) grad Phi_1(x_e) - K_e Psi(q) x_e + D_d M^-1(q) p }     (eq. c1)

closes the loop into eq. (closedloop) with Gamma = 0 and H_d = H + Phi_1 + c_1. With the quadratic
Phi_1(x_e) = 1/2 (x_e - x_e_d + L_1)^T W (x_e - x_e_d + L_1), condition (phi11) gives
L_1 = -W^-1 Psi(q_d) x_e_d (eq. RegL for W = 1). D_d must satisfy eq. (pHcondition) strictly.
"""
from __future__ import annotations

import numpy as np

from . import closed_loop
from .controller import Controller, as_matrix, check_positive_definite, quadratic
from .ph_plant import EMPlant


def law_c1(controller: Controller, eta: np.ndarray, grad_Phi: np.ndarray) -> np.ndarray:
    """eq. (c1) (identical in form to eq. u1-track, with Theta_1 for Phi_1)."""
    plant = controller.plant
    q, p, x_e = plant.split(eta)
    return controller.G_inv @ (controller.JR_bar @ grad_Phi
                               - controller.K_e @ plant.Psi(q) @ x_e
                               + controller.D_d @ plant.M_inv(q) @ p)


class Proposition1(Controller):
    """Set-point regulation for Assumption 1 plants (e.g. the MEMS switch).

    q_d      desired position (n_m)
    R_e_bar  desired electrical damping (MEMS: 1/rbar_e)
    D_d      coupled damping; must satisfy eq. (pHcondition) strictly
    W        weight of the quadratic Phi_1 (default identity, as in the paper)
    """

    name = "Proposition 1"

    def __init__(self, plant: EMPlant, q_d, R_e_bar, D_d=0.0, W=None):
        super().__init__(plant, R_e_bar, D_d, np.zeros((plant.n_m, plant.n_e)))
        closed_loop.check_ph_condition(plant.R_m, self.R_e_bar, self.D_d, strict=True, owner=self.name)
        self.W = as_matrix(np.eye(plant.n_e) if W is None else W, (plant.n_e, plant.n_e), "W", self.name)
        check_positive_definite(self.W, "W", self.name)
        self.eta_d = plant.equilibrium(q_d)
        q_d, _, x_ed = plant.split(self.eta_d)
        self.L1 = -np.linalg.solve(self.W, plant.Psi(q_d) @ x_ed)          # eq. (RegL), from (phi11)
        self.center = x_ed - self.L1                                       # Phi_1 minimiser
        self.c1 = -plant.H(self.eta_d) - quadratic(x_ed, self.center, self.W)   # c_1, H_d(eta_d) = 0
        self.bind_law("c1", self.W, self.eta_d)                           # eq. (c1), generated (n = 1)

    def grad_Phi1(self, x_e):
        return self.W @ (x_e - self.center)

    def u_matrix(self, eta, jet=None):
        return law_c1(self, eta, self.grad_Phi1(self.plant.split(eta)[2]))

    def H_d(self, eta, jet=None):
        x_e = self.plant.split(eta)[2]
        return self.plant.H(eta) + quadratic(x_e, self.center, self.W) + self.c1

    def hess_H_d(self, eta, jet=None):
        return self.plant.hess_H(eta) + self._embed_xe(self.W)

    def target(self, jet=None):
        return self.eta_d
