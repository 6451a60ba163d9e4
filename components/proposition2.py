"""Proposition 2: regulation of the partially / un-damped class (Assumption 2), control law eq. (u2).

Assumption 2: grad_q H_e(q, x_e) = -Gamma grad phi(x_e) with hess phi(x_e_d) > 0. With
    z = -G_e^T (J_e - R_e_bar)^-T (Gamma^T q + x_e)                                   (eq. z)
the law
    u = G_e^-1 { (R_e - J_e) Psi(q) x_e + (D_d - Gamma^T) M^-1(q) p
                 + (J_e - R_e_bar) grad phi(x_e) } - grad_z Phi_2(z)                   (eq. u2)
closes the loop into eq. (closedloop) with H_d = 1/2 p^T M^-1 p + V + Phi_2(z) + phi(x_e) + c_2
(eq. energyrug2). We use Phi_2(z) = 1/2 (z - L)^T K_c (z - L) with the set-point constant L chosen
from the equilibrium condition grad H_d(eta_d) = 0 (not the first row of eq. Phic21, see
docs/derivations.md):  L = z_d - K_c^-1 G_e^-1 (J_e - R_e_bar) grad phi(x_e_d).
"""
from __future__ import annotations

import numpy as np

from . import closed_loop
from .controller import Controller, as_matrix, check_positive_definite, hess_H_mech, quadratic
from .ph_plant import EMPlant


class ZShaped(Controller):
    """What Proposition 2 and Theorem 3 share: Gamma from the plant (Assumption 2/4), the weight K_c
    of the quadratic Phi_2 / Theta_2 in z, the map z(eta) of eq. (z), and hess H_d."""

    def __init__(self, plant: EMPlant, R_e_bar, k_c, D_d):
        super().__init__(plant, R_e_bar, D_d, plant.Gamma)
        self.K_c = as_matrix(k_c, (plant.n_e, plant.n_e), "k_c", self.name)
        check_positive_definite(self.K_c, "k_c", self.name)
        self.A = -plant.G_e.T @ np.linalg.inv(self.JR_bar).T                # z = A (Gamma^T q + x_e)

    def z(self, eta):
        """eq. (z)."""
        q, _, x_e = self.plant.split(eta)
        return self.A @ (self.Gamma.T @ q + x_e)

    def hess_H_d(self, eta, jet=None):
        """hess H_1 + hess phi (x_e block) + C^T K_c C with C = dz/deta = [A Gamma^T, 0, A]."""
        m = self.plant.n_m
        C = np.zeros((self.plant.n_e, self.plant.n))
        C[:, :m] = self.A @ self.Gamma.T
        C[:, 2 * m:] = self.A
        x_e = self.plant.split(eta)[2]
        return hess_H_mech(self.plant, eta) + self._embed_xe(self.plant.hess_phi(x_e)) + C.T @ self.K_c @ C


class Proposition2(ZShaped):
    """Set-point regulation for Assumption 2 plants (e.g. the maglev).

    The plant supplies Gamma and phi, grad_phi, hess_phi of Assumption 2.
    q_d      desired position
    R_e_bar  desired electrical damping R_e + K_e, with K_e >= 0
    k_c      weight of Phi_2 (scalar or n_e x n_e, > 0)
    D_d      coupled damping (general convention of eq. closedloop); must satisfy eq. (pHcondition)
    """

    name = "Proposition 2"

    def __init__(self, plant: EMPlant, q_d, R_e_bar, k_c=20.0, D_d=0.0):
        super().__init__(plant, R_e_bar, k_c, D_d)
        closed_loop.check_ph_condition(plant.R_m, self.R_e_bar, self.D_d, strict=False, owner=self.name)
        self.eta_d = plant.equilibrium(q_d)
        q_d, _, x_ed = plant.split(self.eta_d)
        z_d = self.z(self.eta_d)
        self.L = z_d - np.linalg.solve(self.K_c, self.G_inv @ self.JR_bar @ plant.grad_phi(x_ed))
        self.c2 = -(plant.V(q_d) + quadratic(z_d, self.L, self.K_c) + plant.phi(x_ed))
        self.bind_law("u2", self.K_c, self.eta_d)                         # eq. (u2), generated (n = 1)

    def u_matrix(self, eta, jet=None):
        return law_u2(self, eta, self.K_c @ (self.z(eta) - self.L))

    def H_d(self, eta, jet=None):
        q, p, x_e = self.plant.split(eta)                                   # eq. (energyrug2)
        return (self.plant.H_mech(q, p) + quadratic(self.z(eta), self.L, self.K_c)
                + self.plant.phi(x_e) + self.c2)

    def target(self, jet=None):
        return self.eta_d


def law_u2(controller: Controller, eta: np.ndarray, grad_z_Phi: np.ndarray) -> np.ndarray:
    """eq. (u2) (identical in form to eq. tracker2, with Theta_2 for Phi_2)."""
    plant = controller.plant
    q, p, x_e = plant.split(eta)
    return (controller.G_inv @ ((plant.R_e - plant.J_e) @ plant.Psi(q) @ x_e
                                + (controller.D_d - controller.Gamma.T) @ plant.M_inv(q) @ p
                                + controller.JR_bar @ plant.grad_phi(x_e))
            - grad_z_Phi)
