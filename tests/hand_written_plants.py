"""Independent truths for the described plants: the paper's MEMS switch and maglev as they were written
by hand before issue 25 (components/mems.py, components/maglev.py at 3df687d), and a 2 x 2 description
(a bar levitated by two electromagnets) with its hand-written model.

The generated plants (components/plants/*_model.py) must agree with these to 1e-12 relative.
"""
import math

import numpy as np

from components.parameters import Parameter, resolve
from components.ph_plant import DomainError, EMPlant, OneDOFPlant
from tests import hand_written_laws

MEMS_PARAMETERS = {p.name: p for p in [
    Parameter("c0", 15e-6, "m", "position offset of the capacitor: capacitance is c1 (q + c0)"),
    Parameter("c1", 35.6e-9, "F/m", "capacitance per unit displacement"),
    Parameter("m", 2.35e-9, "kg", "moving mass"),
    Parameter("a1", 0.46, "N/m", "linear spring constant, V = a1 q^2/2 + a2 q^4/4"),
    Parameter("a2", 0.0973, "N/m3", "cubic spring constant, V = a1 q^2/2 + a2 q^4/4", ">= 0"),
    Parameter("R_m", 5.5e-7, "N.s/m", "mechanical damping (the paper's b in x_e*)", ">= 0"),
    Parameter("r_e", 100.0, "Ohm", "series resistance of the electrical port"),
]}


class _HandOneDOF(OneDOFPlant):
    """Definition 1 in closed form, written by hand (tests/hand_written_laws.py)."""

    feasible_scalar = hand_written_laws.feasible_scalar


class HandMEMS(_HandOneDOF):
    """MEMS optical switch with the paper's Section 7 parameters as defaults."""

    name = "MEMS optical switch"

    def __init__(self, **params: float):
        self.params = resolve(MEMS_PARAMETERS, params, self.name)
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


MAGLEV_PARAMETERS = {p.name: p for p in [
    Parameter("k", 0.64042, "H.m", "inductance constant: inductance is k / (c - q)"),
    Parameter("R_e", 2.25, "Ohm", "coil resistance"),
    Parameter("c", 0.005, "m", "position of the magnet (q < c)"),
    Parameter("b", 0.8280, "N", "weight m g of the ball, V = b q"),
    Parameter("m", 0.0844, "kg", "mass of the ball"),
    Parameter("R_m", 0.0, "N.s/m", "mechanical damping (zero in the paper)", ">= 0"),
]}


class HandMaglev(_HandOneDOF):
    """Magnetic levitation system with the paper's Section 7.2 parameters as defaults."""

    name = "magnetic levitation system"

    def __init__(self, **params: float):
        self.params = resolve(MAGLEV_PARAMETERS, params, self.name)
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


# a bar of mass m and inertia J levitated by two electromagnets at lever arms +-l (q = (z, theta)):
# the gaps are c - z -+ l theta, the inverse inductances Psi_ii = gap_i / k
BAR_TOML = '''name = "Bar"
description = "bar levitated by two electromagnets"

[variables]
q   = [["z", "m", "height of the bar's centre"], ["theta", "rad", "tilt of the bar"]]
p   = [["p_z", "kg.m/s", "vertical momentum"], ["p_theta", "kg.m2/s", "angular momentum"]]
x_e = [["x_1", "Wb", "flux linkage of coil 1"], ["x_2", "Wb", "flux linkage of coil 2"]]
u   = [["u_1", "V", "voltage of coil 1"], ["u_2", "V", "voltage of coil 2"]]

[parameters]
k       = [0.5,   "H.m",    "inductance constant of each magnet", "> 0"]
c       = [0.01,  "m",      "height of the magnets", "> 0"]
l       = [0.1,   "m",      "lever arm of the magnets", "> 0"]
m       = [0.2,   "kg",     "mass of the bar", "> 0"]
J       = [0.002, "kg.m2",  "moment of inertia of the bar", "> 0"]
b       = [1.962, "N",      "weight of the bar", "> 0"]
R       = [2.0,   "Ohm",    "coil resistance", "> 0"]
d_z     = [0.05,  "N.s/m",  "vertical damping", ">= 0"]
d_theta = [0.001, "N.m.s/rad", "angular damping", ">= 0"]

[model]
M   = [["m", "0"], ["0", "J"]]
V   = "b*z"
Psi = [["(c - z - l*theta)/k", "0"], ["0", "(c - z + l*theta)/k"]]
R_m = [["d_z", "0"], ["0", "d_theta"]]
J_e = [["0", "0"], ["0", "0"]]
R_e = [["R", "0"], ["0", "R"]]
G_e = [["1", "0"], ["0", "1"]]
domain = ["z + l*theta < c", "z - l*theta < c"]

[controller]
q_d = [0.005, 0.01]
k_c = [[20.0, 0.0], [0.0, 20.0]]
'''


class HandBar(EMPlant):
    """The bar of BAR_TOML written by hand (defaults only)."""

    name = "bar"
    n_m = 2
    n_e = 2
    constant_mass = True

    def __init__(self, k=0.5, c=0.01, lever=0.1, m=0.2, J=0.002, b=1.962, R=2.0, d_z=0.05, d_theta=0.001):
        self.k, self.c, self.l, self.m, self.J, self.b = k, c, lever, m, J, b
        self.R_m = np.diag([d_z, d_theta])
        self.J_e = np.zeros((2, 2))
        self.R_e = np.diag([R, R])
        self.G_e = np.eye(2)
        self.Gamma = np.array([[1.0, 1.0], [lever, -lever]]) / (2 * k)       # grad_q H_e = -Gamma x_e^2

    def M_inv(self, q):
        return np.diag([1 / self.m, 1 / self.J])

    def V(self, q):
        return self.b * q[0]

    def grad_V(self, q):
        return np.array([self.b, 0.0]) + 0 * q

    def hess_V(self, q):
        return np.zeros((2, 2))

    def Psi(self, q):
        z, th = q
        return np.diag([(self.c - z - self.l * th) / self.k, (self.c - z + self.l * th) / self.k])

    def dPsi(self, q):
        return np.array([np.diag([-1.0, -1.0]), np.diag([-self.l, self.l])]) / self.k + 0 * q[0]

    def d2Psi(self, q):
        return np.zeros((2, 2, 2, 2))

    def phi(self, x_e):
        return np.sum(x_e ** 3) / 3

    def grad_phi(self, x_e):
        return x_e ** 2

    def hess_phi(self, x_e):
        return np.diag(2 * x_e)

    def feasible_state(self, jet):
        """Gamma x_e*^2 = M q*'' + R_m q*' + grad V(q*) (Definition 1), x_e* > 0."""
        M = np.diag([self.m, self.J])
        F = M @ jet.qdd + self.R_m @ jet.qd + self.grad_V(jet.q)
        F_dot = M @ jet.qddd + self.R_m @ jet.qdd
        x2 = np.linalg.solve(self.Gamma, F)
        x = np.sqrt(x2)
        return np.concatenate([jet.q, M @ jet.qd, x]), np.linalg.solve(self.Gamma, F_dot) / (2 * x)


__all__ = ["BAR_TOML", "HandBar", "HandMEMS", "HandMaglev", "MAGLEV_PARAMETERS", "MEMS_PARAMETERS", "math"]
