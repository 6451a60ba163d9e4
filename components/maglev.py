"""Magnetic levitation system (Section 7.2): a ball below an electromagnet.

n_m = n_e = 1, constant mass m, J_e = 0, G_e = 1, and
    H_e = (c - q) x_e^2 / (2 k),  V(q) = b q,
so Psi(q) = (c - q)/k is the inverse inductance. q is the ball position [m] (the magnet is at q = c),
p the momentum [kg m/s], x_e the flux linkage [Wb], u the coil voltage [V].
Admissible domain: q < c (the ball has not reached the magnet).
"""
from __future__ import annotations

import numpy as np

from .parameters import Parameter, resolve
from .ph_plant import DomainError, OneDOFPlant

PARAMETERS = {p.name: p for p in [
    Parameter("k", 0.64042, "H.m", "inductance constant: inductance is k / (c - q)"),
    Parameter("R_e", 2.25, "Ohm", "coil resistance"),
    Parameter("c", 0.005, "m", "position of the magnet (q < c)"),
    Parameter("b", 0.8280, "N", "weight m g of the ball, V = b q"),
    Parameter("m", 0.0844, "kg", "mass of the ball"),
    Parameter("R_m", 0.0, "N.s/m", "mechanical damping (zero in the paper)", ">= 0"),
]}

STATES = {
    "q": ("m", "position of the ball (magnet at q = c)"),
    "p": ("kg.m/s", "momentum of the ball"),
    "x_e": ("Wb", "flux linkage of the coil"),
}
INPUT = ("u", "V", "coil voltage")


class Maglev(OneDOFPlant):
    """Magnetic levitation system with the paper's Section 7.2 parameters as defaults."""

    name = "magnetic levitation system"

    def __init__(self, **params: float):
        self.params = resolve(PARAMETERS, params, self.name)
        for k, v in self.params.items():
            setattr(self, k, v)
        self.R_m = np.array([[self.params["R_m"]]])
        self.J_e = np.zeros((1, 1))
        self.R_e = np.array([[self.params["R_e"]]])
        self.G_e = np.eye(1)
        self.q_max = self.c                             # admissible domain: q < c (below the magnet)

    @property
    def Gamma(self) -> np.ndarray:
        """Gamma = 1/(2k) of Assumption 4: grad_q H_e = -Gamma grad phi_2(x_e), grad phi_2 = x_e^2."""
        return np.array([[1.0 / (2.0 * self.k)]])

    # phi_2 of Assumption 2 / 4, eq. (assHe): Section 7.2 gives grad phi_2 = x_e^2, so phi_2 = x_e^3 / 3
    def phi_s(self, x_e):
        return x_e ** 3 / 3.0

    def dphi(self, x_e):
        return x_e ** 2

    def d2phi(self, x_e):
        return 2.0 * x_e

    def phi(self, x_e):
        return self.phi_s(x_e[0])

    def grad_phi(self, x_e):
        return np.array([self.dphi(x_e[0])])

    def hess_phi(self, x_e):
        return np.array([[self.d2phi(x_e[0])]])

    def V_s(self, q):
        return self.b * q                                          # Section 7.2: V = b q

    def dV(self, q):
        return self.b + 0.0 * q

    def d2V(self, q):
        return 0.0 * q

    def psi(self, q):
        return (self.c - q) / self.k                               # Section 7.2: H_e = (c - q) x_e^2 / (2k)

    def dpsi(self, q):
        return -1.0 / self.k + 0.0 * q

    def d2psi(self, q):
        return 0.0 * q

    def check_state(self, eta):
        super().check_state(eta)
        if not np.real(eta[0]) < self.q_max:
            raise DomainError(f"{self.name}: q = {np.real(eta[0]):.6g} m violates q < c "
                              f"(c = {self.c:g} m): the ball has reached the magnet")


def D_d_from_paper(D_d_paper: float, k: float = PARAMETERS["k"].default) -> float:
    """Convert the paper's maglev coupled damping (Section 7.2, eq. controlmaglv) to the general D_d.

    eq. (controlmaglv) prints the momentum coefficient (-1 + D_d)/(2 k m), while eq. (tracker2) gives
    (D_d - Gamma)/m with Gamma = 1/(2k): the paper's maglev D_d is 2 k times the general one.
    """
    return D_d_paper / (2.0 * k)
