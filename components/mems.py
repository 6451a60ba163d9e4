"""MEMS optical switch (Section 7.1): an electrostatic comb/parallel-plate actuator.

n_m = n_e = 1, constant mass m, J_e = 0, R_e = 1/r_e, G_e = 1/r_e, and
    V(q) = 1/2 a1 q^2 + 1/4 a2 q^4,   Psi(q) = 1 / (c1 (q + c0)),
so H_e = x_e^2 / (2 c1 (q + c0)) is the energy of a capacitor with capacitance c1 (q + c0).
q is the displacement [m], p the momentum [kg m/s], x_e the charge [C], u the voltage [V].
Admissible domain: q + c0 > 0 (the gap has not closed).
"""
from __future__ import annotations

import numpy as np

from .parameters import Parameter, resolve
from .ph_plant import DomainError, OneDOFPlant

PARAMETERS = {p.name: p for p in [
    Parameter("c0", 15e-6, "m", "position offset of the capacitor: capacitance is c1 (q + c0)"),
    Parameter("c1", 35.6e-9, "F/m", "capacitance per unit displacement"),
    Parameter("m", 2.35e-9, "kg", "moving mass"),
    Parameter("a1", 0.46, "N/m", "linear spring constant, V = a1 q^2/2 + a2 q^4/4"),
    Parameter("a2", 0.0973, "N/m3", "cubic spring constant, V = a1 q^2/2 + a2 q^4/4", ">= 0"),
    Parameter("R_m", 5.5e-7, "N.s/m", "mechanical damping (the paper's b in x_e*)", ">= 0"),
    Parameter("r_e", 100.0, "Ohm", "series resistance of the electrical port"),
]}

STATES = {
    "q": ("m", "displacement of the movable electrode"),
    "p": ("kg.m/s", "momentum of the movable electrode"),
    "x_e": ("C", "charge of the actuator capacitor"),
}
INPUT = ("u", "V", "voltage applied to the actuator")


class MEMS(OneDOFPlant):
    """MEMS optical switch with the paper's Section 7 parameters as defaults."""

    name = "MEMS optical switch"

    def __init__(self, **params: float):
        self.params = resolve(PARAMETERS, params, self.name)
        for k, v in self.params.items():
            setattr(self, k, v)
        self.R_m = np.array([[self.params["R_m"]]])
        self.J_e = np.zeros((1, 1))
        self.R_e = np.array([[1.0 / self.r_e]])        # Section 7.1: R_e = 1/r_e
        self.G_e = np.array([[1.0 / self.r_e]])        # Section 7.1: G_e = 1/r_e
        self.q_min = -self.c0                           # admissible domain: q + c0 > 0

    def V_s(self, q):
        return 0.5 * self.a1 * q ** 2 + 0.25 * self.a2 * q ** 4    # Section 7.1: V = a1 q^2/2 + a2 q^4/4

    def dV(self, q):
        return self.a1 * q + self.a2 * q ** 3

    def d2V(self, q):
        return self.a1 + 3.0 * self.a2 * q ** 2

    def psi(self, q):
        return 1.0 / (self.c1 * (q + self.c0))                     # Section 7.1: Psi = 1/(c1 (q + c0))

    def dpsi(self, q):
        return -1.0 / (self.c1 * (q + self.c0) ** 2)

    def d2psi(self, q):
        return 2.0 / (self.c1 * (q + self.c0) ** 3)

    def check_state(self, eta):
        super().check_state(eta)
        if not np.real(eta[0]) > self.q_min:
            raise DomainError(f"{self.name}: q = {np.real(eta[0]):.6g} m violates q + c0 > 0 "
                              f"(c0 = {self.c0:g} m): the capacitor gap has closed")


def R_e_bar_from_rbar_e(rbar_e: float) -> np.ndarray:
    """Desired electrical damping of the MEMS examples: K_e = 1/rbar_e - 1/r_e, so
    R_e_bar = R_e + K_e = 1/rbar_e (eq. closedPrameterreg, eq. barRe)."""
    if not (np.isfinite(rbar_e) and rbar_e > 0):
        raise ValueError(f"parameter rbar_e = {rbar_e} violates rbar_e > 0 (desired series resistance)")
    return np.array([[1.0 / rbar_e]])
