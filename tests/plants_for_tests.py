"""A two-axis electromagnetic plant (n_m = n_e = 2) used only by the tests, to exercise the general
matrix forms of the controllers: non-diagonal constant mass, skew J_e != 0, non-identity G_e,
partial mechanical damping. Psi(q) = diag(psi0_j - sum_k beta_kj q_k) is linear in q, so
grad_q H_e = -Gamma grad phi(x_e) with Gamma = beta / 2 and phi(x_e) = sum_j x_j^3 / 3 (Assumption 2/4).
"""
import numpy as np

from components.ph_plant import DomainError, EMPlant, Jet


class TwoAxisLevitator(EMPlant):
    name = "two-axis test plant"
    n_m = 2
    n_e = 2
    x_e_sign = 1.0

    def __init__(self, variable_mass: bool = False, damped: bool = False):
        self.M = np.array([[2.0, 0.3], [0.3, 1.0]])
        self.K = np.array([[3.0, -1.0], [-1.0, 2.0]])
        self.b = np.array([1.0, 0.5])
        self.psi0 = np.array([5.0, 4.0])
        self.beta = np.array([[1.0, 0.2], [0.3, 0.8]])
        self.R_m = np.diag([0.1, 0.05 if damped else 0.0])     # damped: Assumption 1 (R_m > 0)
        self.J_e = np.array([[0.0, 0.5], [-0.5, 0.0]])
        self.R_e = np.diag([1.0, 2.0])
        self.G_e = np.array([[1.0, 0.2], [0.0, 0.5]])
        self.variable_mass = variable_mass
        self.constant_mass = not variable_mass
        self.mu = 0.4

    Gamma = property(lambda self: self.beta / 2.0)

    def phi(self, x_e):
        return np.sum(x_e ** 3) / 3.0

    def grad_phi(self, x_e):
        return x_e ** 2

    def hess_phi(self, x_e):
        return np.diag(2.0 * x_e)

    # mass: constant, or M(q) = M + mu q_2^2 I (for derivative checks only)
    def _M(self, q):
        return self.M + (self.mu * q[1] ** 2 * np.eye(2) if self.variable_mass else 0.0)

    def M_inv(self, q):
        return np.linalg.inv(self._M(q)) if not np.iscomplexobj(q) else _inv2(self._M(q))

    def dM_inv(self, q):
        if not self.variable_mass:
            return np.zeros((2, 2, 2))
        Mi = self.M_inv(q)
        dM1 = 2 * self.mu * q[1] * np.eye(2)
        return np.stack([np.zeros((2, 2)), -Mi @ dM1 @ Mi])

    def d2M_inv(self, q):
        if not self.variable_mass:
            return np.zeros((2, 2, 2, 2))
        Mi = self.M_inv(q)
        dM = 2 * self.mu * q[1] * np.eye(2)
        d2M = 2 * self.mu * np.eye(2)
        d2 = 2 * Mi @ dM @ Mi @ dM @ Mi - Mi @ d2M @ Mi
        out = np.zeros((2, 2, 2, 2), dtype=d2.dtype)
        out[1, 1] = d2
        return out

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
        return float(np.min(self.psi0 - np.real(eta[:2]) @ self.beta))

    def check_state(self, eta):
        super().check_state(eta)
        if self.domain_margin(eta) <= 0:
            raise DomainError("Psi(q) must stay positive definite")

    def feasible_state(self, jet: Jet):
        """Closed form: Gamma grad phi(x_e*) = M q*'' + R_m q*' + grad V(q*) =: F, x_e* > 0."""
        F = self.M @ jet.qdd + self.R_m @ jet.qd + self.grad_V(jet.q)
        F_dot = self.M @ jet.qddd + self.R_m @ jet.qdd + self.K @ jet.qd
        x2 = np.linalg.solve(self.Gamma, F)
        if np.any(x2 <= 0):
            raise ValueError("infeasible reference")
        x = np.sqrt(x2)
        x_dot = np.linalg.solve(self.Gamma, F_dot) / (2 * x)
        return np.concatenate([jet.q, self.M @ jet.qd, x]), x_dot


def _inv2(A):
    det = A[0, 0] * A[1, 1] - A[0, 1] * A[1, 0]
    return np.array([[A[1, 1], -A[0, 1]], [-A[1, 0], A[0, 0]]]) / det


class VectorSinusoid:
    """q*(t) = offset + amplitude * sin(omega t + phase), componentwise (a test reference for n_m = 2)."""

    def __init__(self, offset, amplitude, omega, phase):
        self.o, self.a, self.w, self.ph = (np.asarray(v, dtype=float) for v in (offset, amplitude, omega, phase))

    def jet(self, t):
        th = self.w * t + self.ph
        s, c = np.sin(th), np.cos(th)
        return Jet(self.o + self.a * s, self.a * self.w * c, -self.a * self.w ** 2 * s, -self.a * self.w ** 3 * c)


class LinearPlant(EMPlant):
    """n_m = n_e = 1 with quadratic H: V = k q^2 / 2, constant Psi = psi, constant mass m. The closed loop
    of Theorem 2 at q_d = 0 is linear, eta' = J eta with J = F_d diag(k, 1/m, psi + 1)."""

    name = "linear test plant"
    n_m = 1
    n_e = 1

    def __init__(self, m=2.0, k=3.0, R_m=0.4, psi=5.0, R_e=1.0):
        self.m, self.k, self.psi = m, k, psi
        self.R_m = np.array([[R_m]])
        self.J_e = np.zeros((1, 1))
        self.R_e = np.array([[R_e]])
        self.G_e = np.eye(1)

    def M_inv(self, q):
        return np.array([[1.0 / self.m]])

    def V(self, q):
        return 0.5 * self.k * q[0] ** 2

    def grad_V(self, q):
        return np.array([self.k * q[0]])

    def hess_V(self, q):
        return np.array([[self.k]])

    def Psi(self, q):
        return np.array([[self.psi + 0.0 * q[0]]])

    def dPsi(self, q):
        return np.zeros((1, 1, 1))

    def d2Psi(self, q):
        return np.zeros((1, 1, 1, 1))

    def feasible_state(self, jet):
        """Only q* = 0 at rest is feasible (no electromechanical force); x_e* = 0."""
        return np.array([jet.q[0], self.m * jet.qd[0], 0.0]), np.zeros(1)
