"""A device module of the kind fmus.build.build_device takes (a plant description's generated module will be
one): plain Python that defines a plant class and its components.device.Device, `DEVICE`, with no import
outside numpy, components and the standard library (the module is copied into the FMU bundle alone).

TwoAxis is tests/plants_for_tests.TwoAxisLevitator(damped=True) with its numbers as parameters: n_m =
n_e = 2, non-diagonal mass, skew J_e != 0, G_e != I, Psi(q) = diag(psi0_j - sum_k beta_kj q_k) linear in q,
so that grad_q H_e = -Gamma grad phi(x_e) with Gamma = beta / 2 and phi = sum_j x_j^3 / 3 (Assumptions 2
and 4, eq. assHe). Written again here, not imported, so that the tests compare two implementations.
Designs: Proposition 2 (eq. u2) and Theorem 3 (eq. tracker2), gains under the paper's names with matrix
entries q_d_1, R_e_bar_1_2, k_c_1_2, D_d_1_2 (issue 25's naming).
"""
from __future__ import annotations

from typing import Mapping

import numpy as np

from components.device import Design, Device, VariableSpec
from components.parameters import Parameter, resolve
from components.ph_plant import DomainError, EMPlant, Jet
from components.proposition2 import Proposition2
from components.theorem3 import Theorem3

PARAMETERS = {p.name: p for p in [
    Parameter("m_1", 2.0, "kg", "mass matrix entry M_11", "> 0"),
    Parameter("m_2", 1.0, "kg", "mass matrix entry M_22", "> 0"),
    Parameter("m_12", 0.3, "kg", "mass matrix entry M_12 = M_21", "any"),
    Parameter("k_1", 3.0, "N/m", "stiffness entry K_11 of V = q^T K q / 2 + b^T q", "any"),
    Parameter("k_2", 2.0, "N/m", "stiffness entry K_22", "any"),
    Parameter("k_12", -1.0, "N/m", "stiffness entry K_12 = K_21", "any"),
    Parameter("b_1", 1.0, "N", "constant force b_1 of V", "any"),
    Parameter("b_2", 0.5, "N", "constant force b_2 of V", "any"),
    Parameter("psi0_1", 5.0, "1/H", "Psi_11 at q = 0 (inverse inductance)", "> 0"),
    Parameter("psi0_2", 4.0, "1/H", "Psi_22 at q = 0", "> 0"),
    Parameter("R_m_1", 0.1, "N.s/m", "mechanical damping of axis 1", ">= 0"),
    Parameter("R_m_2", 0.05, "N.s/m", "mechanical damping of axis 2", ">= 0"),
    Parameter("R_e_1", 1.0, "Ohm", "resistance of coil 1", "> 0"),
    Parameter("R_e_2", 2.0, "Ohm", "resistance of coil 2", "> 0"),
]}
BETA = np.array([[1.0, 0.2], [0.3, 0.8]])        # dPsi_jj/dq_k = -beta_kj [1/(H m)]
J_E = np.array([[0.0, 0.5], [-0.5, 0.0]])
G_E = np.array([[1.0, 0.2], [0.0, 0.5]])


class TwoAxis(EMPlant):
    """Two positions, two coils (eq. open-loop elecmech with H_e = x_e^T Psi(q) x_e / 2)."""

    name = "two-axis levitator"
    n_m = 2
    n_e = 2
    constant_mass = True
    x_e_sign = 1.0

    def __init__(self, **params: float):
        v = self.params = resolve(PARAMETERS, params, self.name)
        self.M = np.array([[v["m_1"], v["m_12"]], [v["m_12"], v["m_2"]]])
        if not np.linalg.eigvalsh(self.M).min() > 0:
            raise ValueError(f"{self.name}: parameters m_1, m_2, m_12 = {v['m_1']}, {v['m_2']}, {v['m_12']} "
                             "violate M > 0 (positive definite)")
        self._M_inv = np.linalg.inv(self.M)
        self.K = np.array([[v["k_1"], v["k_12"]], [v["k_12"], v["k_2"]]])
        self.b = np.array([v["b_1"], v["b_2"]])
        self.psi0 = np.array([v["psi0_1"], v["psi0_2"]])
        self.beta = BETA
        self.R_m = np.diag([v["R_m_1"], v["R_m_2"]])
        self.J_e = J_E
        self.R_e = np.diag([v["R_e_1"], v["R_e_2"]])
        self.G_e = G_E

    Gamma = property(lambda self: self.beta / 2.0)          # Assumption 2: grad_q H_e = -Gamma grad phi

    def phi(self, x_e):
        return np.sum(x_e ** 3) / 3.0

    def grad_phi(self, x_e):
        return x_e ** 2

    def hess_phi(self, x_e):
        return np.diag(2.0 * x_e)

    def M_inv(self, q):
        return self._M_inv

    def V(self, q):
        return 0.5 * q @ self.K @ q + self.b @ q

    def grad_V(self, q):
        return self.K @ q + self.b

    def hess_V(self, q):
        return self.K

    def Psi(self, q):
        return np.diag(self.psi0 - q @ self.beta)

    def dPsi(self, q):
        return np.stack([np.diag(-self.beta[k]) for k in range(2)]) + 0.0 * q[0]

    def d2Psi(self, q):
        return np.zeros((2, 2, 2, 2))

    def domain_margin(self, eta):
        """min_j Psi_jj(q): positive while Psi(q) is positive definite."""
        return float(np.min(self.psi0 - np.real(np.asarray(eta)[:2]) @ self.beta))

    def check_state(self, eta):
        super().check_state(eta)
        if self.domain_margin(eta) <= 0:
            raise DomainError(f"{self.name}: Psi(q) must stay positive definite (psi0 - beta^T q > 0) at {eta}")

    def feasible_state(self, jet: Jet):
        """Definition 1 in closed form: Gamma grad phi(x_e*) = M q*'' + R_m q*' + grad V(q*), x_e* > 0."""
        F = self.M @ jet.qdd + self.R_m @ jet.qd + self.grad_V(jet.q)
        F_dot = self.M @ jet.qddd + self.R_m @ jet.qdd + self.K @ jet.qd
        x2 = np.linalg.solve(self.Gamma, F)
        if np.any(np.real(x2) <= 0):
            raise ValueError(f"{self.name}: infeasible reference at q* = {jet.q}: x_e*^2 = {x2} must be > 0")
        x = np.sqrt(x2)
        return np.concatenate([jet.q, self.M @ jet.qd, x]), np.linalg.solve(self.Gamma, F_dot) / (2 * x)


def _matrix_gains(name: str, values, unit: str, description: str, condition: str = "any") -> list[Parameter]:
    """The entries <name>_<i>_<j> of a 2 x 2 gain matrix."""
    return [Parameter(f"{name}_{i + 1}_{j + 1}", float(values[i][j]), unit, f"{description}, entry ({i + 1}, {j + 1})",
                      condition) for i in range(2) for j in range(2)]


def _matrix(g: Mapping[str, float], name: str) -> np.ndarray:
    return np.array([[g[f"{name}_{i + 1}_{j + 1}"] for j in range(2)] for i in range(2)])


K_C = [[3.0, 0.5], [0.5, 2.0]]
PROP2 = {p.name: p for p in [
    Parameter("q_d_1", 0.1, "m", "set-point position q_d_1"), Parameter("q_d_2", 0.2, "m", "set-point position q_d_2"),
    *_matrix_gains("R_e_bar", [[1.5, 0.0], [0.0, 2.5]], "Ohm", "desired electrical damping R_e_bar (eq. barRe)"),
    *_matrix_gains("k_c", K_C, "1", "weight K_c of Phi_2 = (z - L)^T K_c (z - L) / 2"),
    *_matrix_gains("D_d", [[0.03, 0.0], [0.01, 0.0]], "Wb/m", "coupled damping D_d of eq. (closedloop)"),
]}
THM3 = {p.name: p for p in [
    *_matrix_gains("R_e_bar", [[1.5, 0.2], [0.1, 2.5]], "Ohm", "desired electrical damping R_e_bar (eq. barRe)"),
    *_matrix_gains("k_c", K_C, "1", "weight K_c of Theta_2 = (z - L3)^T K_c (z - L3) / 2"),
    *_matrix_gains("D_d", [[0.03, 0.0], [0.01, 0.0]], "Wb/m", "coupled damping D_d of eq. (closedloop)"),
]}


def _variables(symbol: str, unit: str, what: str) -> tuple[VariableSpec, ...]:
    return tuple(VariableSpec(f"{symbol}_{i}", unit, f"{what} {i}") for i in (1, 2))


DEVICE = Device(
    "TwoAxis", "two-axis levitator (n_m = n_e = 2, tests)", PARAMETERS,
    q=_variables("q", "m", "position of axis"), p=_variables("p", "kg.m/s", "momentum of axis"),
    x_e=_variables("x_e", "Wb", "flux linkage of coil"), u=_variables("u", "V", "voltage of coil"),
    plant=TwoAxis,
    designs={
        "Proposition2": Design("Proposition2", PROP2, lambda P, g: Proposition2(
            P, [g["q_d_1"], g["q_d_2"]], _matrix(g, "R_e_bar"), k_c=_matrix(g, "k_c"), D_d=_matrix(g, "D_d"))),
        "Theorem3": Design("Theorem3", THM3, lambda P, g: Theorem3(
            P, _matrix(g, "R_e_bar"), k_c=_matrix(g, "k_c"), D_d=_matrix(g, "D_d"))),
    })
INITIAL_STATE = (0.05, 0.1, 0.0, 0.0, 1.0, 1.0)           # the plant FMU's q_0, p_0, x_e_0 (inside the domain)
EXPERIMENT = (0.0, 1.0, 1e-2)
