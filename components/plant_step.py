"""The open-loop plant over one communication step with a held input: what a plant FMU's doStep computes.

Between two communication points t_k and t_k + h a co-simulation master holds the input constant, so the
plant integrates eq. (open-loop elecmech), eta' = f(eta, u_k), over [t_k, t_k + h] from its current state.

The MEMS switch is extremely stiff: its electrical time constant 1/alpha = r_e c1 (q + c0) is ~1e-10 s,
its mechanics ~1e-4 s. Two things make a communication step both cheap and accurate:

1. The electrical layer. The electrical equation is linear in x_e for fixed q,
       x_e' = A(q) x_e + G_e u,   A(q) = (J_e - R_e) Psi(q)    (n_e = 1: A = -alpha, alpha > 0),
   so after an input jump x_e relaxes to the quasi-static charge x_ss = G_e u / alpha within a few
   1/alpha, while q and p hardly move. When the layer is over long before the step ends
   (alpha h >= LAYER_DECAY) and far faster than the mechanics (alpha T_m >= LAYER_SEPARATION), it is
   applied in closed form at the start of the step: delta = x_e - x_ss decays as delta0 exp(-alpha t),
   and the extra force -1/2 Psi'(q) (x_e^2 - x_ss^2) of the p-row gives the momentum kick
       dp = F_pq (Psi'(q) / alpha) (x_ss delta0 + delta0^2 / 4),
   after which x_e = x_ss. Neglected: the motion of q, p during the layer (relative size 1/(alpha T_m)).
2. The smooth remainder is integrated by RODAS4 (Hairer & Wanner, Solving ODEs II, Sec. IV.7: a
   stiffly accurate, L-stable Rosenbrock method of order 4 with an embedded order-3 estimate) using the
   analytic Jacobian F hess H (eq. open-loop elecmech), with error control on states scaled by
   `nominal_scale`: a substep is accepted when the RMS of err_i / (rtol (1 + |xi_i|)) is <= 1.
   The proposed substep size carries over to the next communication step (`PlantStepper.h_next`).

Without (1) the layer would be resolved by the error control: correct, but ~10-30 substeps per step.

The fast path (`_ScalarModel`) evaluates eq. (open-loop elecmech) with scalar arithmetic for a
OneDOFPlant (n_m = n_e = 1, constant mass), from the plant's own scalar V', V'', Psi, Psi', Psi'' and
its constant F and g: the same equations as `EMPlant.f` and `EMPlant.jacobian`, which the tests pin
it to. Any other plant with three states uses `EMPlant.f` and `EMPlant.jacobian` directly (slower).

`simulate_zoh` is the tight-tolerance reference for the same problem (scipy's Radau, step by step).
"""
from __future__ import annotations

import math
from typing import Sequence

import numpy as np

from .ph_plant import DomainError, EMPlant, OneDOFPlant

DEFAULT_RTOL = 1e-8
LAYER_DECAY = 40.0          # alpha h above which exp(-alpha h) < 5e-18: the layer ends inside the step
LAYER_SEPARATION = 1e3      # alpha T_m above which the layer is instantaneous for the mechanics
MAX_SUBSTEPS = 100_000


class StepFailure(RuntimeError):
    """The integration of a communication step failed (step size underflow, too many substeps)."""


def _lower(values: Sequence[float], s: int) -> tuple[tuple[float, ...], ...]:
    rows, k = [], 0
    for i in range(s):
        rows.append(tuple(values[k:k + i]))
        k += i
    return tuple(rows)


# RODAS4 in the form  (I/(h gamma) - J) K_i = f(y + sum_j a_ij K_j) + sum_j (c_ij / h) K_j,
# y_new = y + sum_i m_i K_i, error estimate K_6 (Hairer & Wanner, rodas.f, METH = 1).
_GAMMA = 0.25
_A = _lower([1.544, 0.9466785280815826, 0.2557011698983284, 3.314825187068521, 2.896124015972201,
             0.9986419139977817, 1.221224509226641, 6.019134481288629, 12.53708332932087,
             -0.6878860361058950, 1.221224509226641, 6.019134481288629, 12.53708332932087,
             -0.6878860361058950, 1.0], 6)
_C = _lower([-5.6688, -2.430093356833875, -0.2063599157091915, -0.1073529058151375, -9.594562251023355,
             -20.47028614809616, 7.496443313967647, -10.24680431464352, -33.99990352819905,
             11.70890893206160, 8.083246795921522, -7.981132988064893, -31.52159432874371,
             16.31930543123136, -6.058818238834054], 6)
# The method is stiffly accurate: y_new = Y_6 + K_6 with Y_6 = y + sum_j a_6j K_j.
_ERROR_ORDER = 4.0          # the embedded estimate is O(h^4)


def nominal_scale(plant: EMPlant) -> np.ndarray:
    """Typical magnitudes (q, p, x_e) of a one-degree-of-freedom plant, from its parameters alone.

    Length L: the distance from q = 0 to the domain boundary (MEMS c0, maglev c), else 1.
    Force F: |V'(L)|. Mechanical time T = sqrt(m L / F); momentum m L / T. Electrical state: the x_e
    whose force 1/2 |Psi'(0)| x_e^2 equals F. These only set the absolute tolerance of the integration.
    """
    if plant.n_m != 1 or plant.n_e != 1:
        raise NotImplementedError(f"{plant.name}: nominal_scale needs n_m = n_e = 1")
    zero = np.zeros(plant.n)
    L = plant.domain_margin(zero)
    L = L if math.isfinite(L) and L > 0 else 1.0
    force = abs(float(plant.grad_V(np.array([L]))[0])) or 1.0
    m = 1.0 / float(plant.M_inv(np.zeros(1))[0, 0])
    T = math.sqrt(m * L / force)
    dPsi = abs(float(plant.dPsi(np.zeros(1))[0, 0, 0]))
    x_e = math.sqrt(2.0 * force / dPsi) if dPsi > 0 else 1.0
    return np.array([L, m * L / T, x_e])


def mechanical_time(plant: EMPlant) -> float:
    """T = sqrt(m L / F) of `nominal_scale`: the time scale the electrical layer is compared with."""
    s = nominal_scale(plant)
    m = 1.0 / float(plant.M_inv(np.zeros(1))[0, 0])
    return m * s[0] / s[1]


class _ScalarModel:
    """eq. (open-loop elecmech) for a OneDOFPlant, in scalar arithmetic with the plant's own
    V', V'', Psi, Psi', Psi'' (OneDOFPlant's scalar functions) and its constant F and g:

    grad H = (V' + 1/2 x_e^2 Psi', p/m, Psi x_e); hess H = [[V'' + 1/2 x_e^2 Psi'', 0, x_e Psi'],
    [0, 1/m, 0], [x_e Psi', 0, Psi]]; f = F grad H + g u and J = F hess H with
    F = [[0, 1, 0], [-1, -R_m, 0], [0, 0, J_e - R_e]] and g = [0, 0, G_e]. The tests pin this to
    EMPlant.f and EMPlant.jacobian.
    """

    def __init__(self, plant: EMPlant):
        F, g = plant.F(), plant.g()
        pattern = np.array([[0, 1, 0], [1, 1, 0], [0, 0, 1]], dtype=bool)
        if np.any(F[~pattern] != 0) or g[0, 0] != 0 or g[1, 0] != 0:
            raise ValueError(f"{plant.name}: F, g do not have the structure of eq. (open-loop elecmech)")
        self.F_qp, self.F_pq, self.F_pp, self.F_xx = (float(F[0, 1]), float(F[1, 0]), float(F[1, 1]),
                                                     float(F[2, 2]))
        self.g_x = float(g[2, 0])
        self.m_inv = float(plant.M_inv(np.zeros(1))[0, 0])
        if isinstance(plant, OneDOFPlant):
            self.dV, self.d2V = plant.dV, plant.d2V
            self.Psi, self.dPsi, self.d2Psi = plant.psi, plant.dpsi, plant.d2psi

    def psi(self, q: float) -> tuple[float, float]:
        """(Psi(q), Psi'(q))."""
        return self.Psi(q), self.dPsi(q)

    def f(self, q: float, p: float, x: float, u: float) -> tuple[float, float, float]:
        gp = self.m_inv * p
        return (self.F_qp * gp,
                self.F_pq * (self.dV(q) + 0.5 * x * x * self.dPsi(q)) + self.F_pp * gp,
                self.F_xx * self.Psi(q) * x + self.g_x * u)

    def f_jac(self, q: float, p: float, x: float, u: float):
        """f and the nonzero entries (J_qp, J_pq, J_pp, J_px, J_xq, J_xx) of J = F hess H."""
        Psi, dPsi = self.Psi(q), self.dPsi(q)
        gp = self.m_inv * p
        f = (self.F_qp * gp,
             self.F_pq * (self.dV(q) + 0.5 * x * x * dPsi) + self.F_pp * gp,
             self.F_xx * Psi * x + self.g_x * u)
        h_qx = x * dPsi
        jac = (self.F_qp * self.m_inv, self.F_pq * (self.d2V(q) + 0.5 * x * x * self.d2Psi(q)),
               self.F_pp * self.m_inv, self.F_pq * h_qx, self.F_xx * h_qx, self.F_xx * Psi)
        return f, jac


class _ArrayModel(_ScalarModel):
    """Any three-state plant: `EMPlant.f` and `EMPlant.jacobian` (dense) behind the scalar interface."""

    def __init__(self, plant: EMPlant):
        super().__init__(plant)
        self.plant = plant

    def psi(self, q):
        qa = np.array([q])
        return float(self.plant.Psi(qa)[0, 0]), float(self.plant.dPsi(qa)[0, 0, 0])

    def f(self, q, p, x, u):
        return tuple(float(v) for v in self.plant.f(np.array([q, p, x]), np.array([u])))

    def f_jac(self, q, p, x, u):
        eta = np.array([q, p, x])
        return self.f(q, p, x, u), np.asarray(self.plant.jacobian(eta), dtype=float)


class PlantStepper:
    """Advances a plant's state over communication steps with a held input.

    rtol      relative tolerance of the integration (absolute tolerance rtol * nominal_scale)
    h_next    integrator state: the substep size proposed for the next step (0: none yet); an FMU must
              save and restore it with its state for rolled-back steps to reproduce exactly.
    """

    def __init__(self, plant: EMPlant, rtol: float = DEFAULT_RTOL, max_substeps: int = MAX_SUBSTEPS):
        if plant.n_m != 1 or plant.n_e != 1:
            raise NotImplementedError(f"{plant.name}: PlantStepper handles n_m = n_e = 1")
        if not (math.isfinite(rtol) and 1e-14 <= rtol <= 1e-2):
            raise ValueError(f"parameter rtol = {rtol} violates 1e-14 <= rtol <= 1e-2 "
                             "(relative tolerance of the plant integration)")
        self.plant = plant
        self.rtol = float(rtol)
        self.max_substeps = int(max_substeps)
        one_dof = isinstance(plant, OneDOFPlant)
        self.model = _ScalarModel(plant) if one_dof else _ArrayModel(plant)
        self.dense = not one_dof
        self.scale = tuple(float(s) for s in nominal_scale(plant))
        self.t_mech = mechanical_time(plant)
        self.h_next = 0.0
        self.n_substeps = 0          # statistics of the last step
        self.n_rejected = 0
        self.layer_applied = False

    def _check(self, q: float, p: float, x: float) -> None:
        """Raise the plant's DomainError if (q, p, x_e) is not finite or outside the domain."""
        if not (math.isfinite(q) and math.isfinite(p) and math.isfinite(x)) or \
                not self.plant.domain_margin((q, p, x)) > 0:
            eta = np.array([q, p, x])
            self.plant.check_state(eta)
            raise DomainError(f"{self.plant.name}: state {eta} is outside the domain")

    # ---- the electrical layer ------------------------------------------------------------------
    def layer(self, q: float, p: float, x: float, u: float, h: float) -> tuple[float, float, bool]:
        """(p, x_e) after the electrical layer, if it is applicable for a step of size h (see module doc)."""
        model = self.model
        Psi, dPsi = model.psi(q)
        alpha = -model.F_xx * Psi
        if not (alpha * h >= LAYER_DECAY and alpha * self.t_mech >= LAYER_SEPARATION):
            return p, x, False
        x_ss = model.g_x * u / alpha
        d0 = x - x_ss
        return p + model.F_pq * (dPsi / alpha) * (x_ss * d0 + 0.25 * d0 * d0), x_ss, True

    # ---- one communication step ------------------------------------------------------------------
    def step(self, eta: Sequence[float], u, h: float) -> np.ndarray:
        """The state after holding input u for h seconds from state eta.

        Raises ValueError for a non-finite or non-positive h, a non-finite u or eta; DomainError
        (with the plant's reason) if the state leaves the domain; StepFailure if the integration fails.
        The stepper's h_next changes only when the step succeeds.
        """
        u = float(np.asarray(u, dtype=float).reshape(-1)[0])
        q, p, x = (float(v) for v in eta)
        return np.array(self.advance(q, p, x, u, float(h)))

    def advance(self, q: float, p: float, x: float, u: float, h: float) -> tuple[float, float, float]:
        """`step` on floats: (q, p, x_e) after holding u for h seconds."""
        if not (math.isfinite(h) and h > 0):
            raise ValueError(f"communication step size h = {h} must be finite and > 0")
        if not math.isfinite(u):
            raise ValueError(f"input u = {u} is not finite")
        self._check(q, p, x)
        p, x, self.layer_applied = self.layer(q, p, x, u, h)
        y, h_next, n_ok, n_rej = self._integrate(q, p, x, u, h)
        self.h_next, self.n_substeps, self.n_rejected = h_next, n_ok, n_rej
        return y

    def _integrate(self, q, p, x, u, h):
        sq, sp, sx = self.scale
        iq, ip, ix = 1.0 / sq, 1.0 / sp, 1.0 / sx
        rtol = self.rtol
        model, plant = self.model, self.plant
        rodas4 = self._rodas4_dense if self.dense else _rodas4_structured
        # scaled state xi = eta / s; scaled f_i = f_i / s_i; scaled J_ij = J_ij s_j / s_i
        y = (q * iq, p * ip, x * ix)
        t = 0.0
        hs = min(self.h_next or h, h)
        n_ok = n_rej = 0
        h_min = 1e-13 * h
        while True:
            remaining = h - t
            last = hs >= remaining * (1.0 - 1e-9)
            hh = remaining if last else hs
            try:
                y_new, err = rodas4(model, y, u, hh, iq, ip, ix, sq, sp, sx)
                e0, e1, e2 = err
                n0 = rtol * (1.0 + max(abs(y[0]), abs(y_new[0])))
                n1 = rtol * (1.0 + max(abs(y[1]), abs(y_new[1])))
                n2 = rtol * (1.0 + max(abs(y[2]), abs(y_new[2])))
                e = math.sqrt(((e0 / n0) ** 2 + (e1 / n1) ** 2 + (e2 / n2) ** 2) / 3.0)
            except (ArithmeticError, ValueError):
                e = math.inf
            if not math.isfinite(e):
                e, factor = math.inf, 0.2
            else:
                factor = min(5.0, max(0.2, 0.9 * e ** (-1.0 / _ERROR_ORDER))) if e > 0 else 5.0
            if e <= 1.0:
                n_ok += 1
                y = y_new
                self._check(y[0] * sq, y[1] * sp, y[2] * sx)
                proposal = hh * factor
                if last:
                    h_next = max(proposal, hs) if hh < hs else proposal
                    return (y[0] * sq, y[1] * sp, y[2] * sx), h_next, n_ok, n_rej
                t += hh
                hs = proposal
            else:
                n_rej += 1
                hs = hh * factor
                if hs < h_min:
                    raise StepFailure(
                        f"{plant.name}: step size underflow ({hs:.3g} s) at t + {t:.6g} s in a step of {h:.6g} s "
                        f"from state {np.array([y[0] * sq, y[1] * sp, y[2] * sx])} with u = {u:g}")
            if n_ok + n_rej >= self.max_substeps:
                raise StepFailure(f"{plant.name}: more than {self.max_substeps} substeps in a step of {h:.6g} s "
                                  f"(reached t + {t:.6g} s)")

    def _rodas4_dense(self, model, y, u, h, iq, ip, ix, sq, sp, sx):
        """One RODAS4 step in scaled variables, dense Jacobian: (y_new, error estimate)."""
        f0, jac = model.f_jac(y[0] * sq, y[1] * sp, y[2] * sx, u)
        gi = 1.0 / (h * _GAMMA)
        lu = _lu3(gi * np.eye(3) - jac * np.outer([iq, ip, ix], [sq, sp, sx]))
        Ks = []
        y0, y1, y2 = y
        r = (f0[0] * iq, f0[1] * ip, f0[2] * ix)
        hi = 1.0 / h
        for i in range(6):
            if i:
                Y0, Y1, Y2, c0, c1, c2 = y0, y1, y2, 0.0, 0.0, 0.0
                for a_, c_, (k0, k1, k2) in zip(_A[i], _C[i], Ks):
                    Y0 += a_ * k0
                    Y1 += a_ * k1
                    Y2 += a_ * k2
                    c0 += c_ * k0
                    c1 += c_ * k1
                    c2 += c_ * k2
                fi = model.f(Y0 * sq, Y1 * sp, Y2 * sx, u)
                r = (fi[0] * iq + hi * c0, fi[1] * ip + hi * c1, fi[2] * ix + hi * c2)
            Ks.append(_solve_dense(lu, r))
        K6 = Ks[5]
        return (Y0 + K6[0], Y1 + K6[1], Y2 + K6[2]), K6


# RODAS4's coefficients by name, for the written-out stages of `_rodas4_structured`
(_a21,), (_a31, _a32), (_a41, _a42, _a43), (_a51, _a52, _a53, _a54), (_a61, _a62, _a63, _a64, _a65) = _A[1:]
(_c21,), (_c31, _c32), (_c41, _c42, _c43), (_c51, _c52, _c53, _c54), (_c61, _c62, _c63, _c64, _c65) = _C[1:]


def _rodas4_structured(model, y, u, h, iq, ip, ix, sq, sp, sx):
    """One RODAS4 step in scaled variables for J = [[0, a, 0], [b, c, d], [e, 0, k]] (a OneDOFPlant):
    (y_new, error estimate). The same method as `PlantStepper._rodas4_dense`, with the six stages
    written out (a loop over the coefficient table would cost more than the arithmetic) and the
    linear solves done by elimination."""
    f0, (J_qp, J_pq, J_pp, J_px, J_xq, J_xx) = model.f_jac(y[0] * sq, y[1] * sp, y[2] * sx, u)
    g = 1.0 / (h * _GAMMA)
    # G = I/(h gamma) - J (scaled): eliminate K_q and K_x into the K_p equation
    a, b, c = J_qp * sp * iq, J_pq * sq * ip, J_pp
    d, e, gk = J_px * sx * ip, J_xq * sq * ix, g - J_xx
    lu = (g, a, b, c, d, e, gk, 1.0 / ((g - c) - a * b / g - a * d * e / (g * gk)))

    f = model.f
    hi = 1.0 / h
    y0, y1, y2 = y
    # stage 1
    p0, p1, p2 = _solve_structured(lu, (f0[0] * iq, f0[1] * ip, f0[2] * ix))
    # stage 2
    fi = f((y0 + _a21 * p0) * sq, (y1 + _a21 * p1) * sp, (y2 + _a21 * p2) * sx, u)
    q0, q1, q2 = _solve_structured(lu, (fi[0] * iq + hi * _c21 * p0, fi[1] * ip + hi * _c21 * p1,
                                        fi[2] * ix + hi * _c21 * p2))
    # stage 3
    fi = f((y0 + _a31 * p0 + _a32 * q0) * sq, (y1 + _a31 * p1 + _a32 * q1) * sp,
           (y2 + _a31 * p2 + _a32 * q2) * sx, u)
    r0, r1, r2 = _solve_structured(lu, (fi[0] * iq + hi * (_c31 * p0 + _c32 * q0),
                                        fi[1] * ip + hi * (_c31 * p1 + _c32 * q1),
                                        fi[2] * ix + hi * (_c31 * p2 + _c32 * q2)))
    # stage 4
    fi = f((y0 + _a41 * p0 + _a42 * q0 + _a43 * r0) * sq, (y1 + _a41 * p1 + _a42 * q1 + _a43 * r1) * sp,
           (y2 + _a41 * p2 + _a42 * q2 + _a43 * r2) * sx, u)
    s0, s1, s2 = _solve_structured(lu, (fi[0] * iq + hi * (_c41 * p0 + _c42 * q0 + _c43 * r0),
                                        fi[1] * ip + hi * (_c41 * p1 + _c42 * q1 + _c43 * r1),
                                        fi[2] * ix + hi * (_c41 * p2 + _c42 * q2 + _c43 * r2)))
    # stage 5
    fi = f((y0 + _a51 * p0 + _a52 * q0 + _a53 * r0 + _a54 * s0) * sq,
           (y1 + _a51 * p1 + _a52 * q1 + _a53 * r1 + _a54 * s1) * sp,
           (y2 + _a51 * p2 + _a52 * q2 + _a53 * r2 + _a54 * s2) * sx, u)
    t0, t1, t2 = _solve_structured(lu, (fi[0] * iq + hi * (_c51 * p0 + _c52 * q0 + _c53 * r0 + _c54 * s0),
                                        fi[1] * ip + hi * (_c51 * p1 + _c52 * q1 + _c53 * r1 + _c54 * s1),
                                        fi[2] * ix + hi * (_c51 * p2 + _c52 * q2 + _c53 * r2 + _c54 * s2)))
    # stage 6: Y_6 = y + sum_j a_6j K_j; y_new = Y_6 + K_6 (stiffly accurate), K_6 is the error estimate
    Y0 = y0 + _a61 * p0 + _a62 * q0 + _a63 * r0 + _a64 * s0 + _a65 * t0
    Y1 = y1 + _a61 * p1 + _a62 * q1 + _a63 * r1 + _a64 * s1 + _a65 * t1
    Y2 = y2 + _a61 * p2 + _a62 * q2 + _a63 * r2 + _a64 * s2 + _a65 * t2
    fi = f(Y0 * sq, Y1 * sp, Y2 * sx, u)
    K6 = _solve_structured(lu, (fi[0] * iq + hi * (_c61 * p0 + _c62 * q0 + _c63 * r0 + _c64 * s0 + _c65 * t0),
                                  fi[1] * ip + hi * (_c61 * p1 + _c62 * q1 + _c63 * r1 + _c64 * s1 + _c65 * t1),
                                  fi[2] * ix + hi * (_c61 * p2 + _c62 * q2 + _c63 * r2 + _c64 * s2 + _c65 * t2)))
    return (Y0 + K6[0], Y1 + K6[1], Y2 + K6[2]), K6


def _solve_structured(lu, r):
    """Solve (g I - J) K = r for J = [[0, a, 0], [b, c, d], [e, 0, k]], gk = g - k, D = 1/Schur complement."""
    g, a, b, c, d, e, gk, D = lu
    r0, r1, r2 = r
    K1 = (r1 + b * r0 / g + d * (r2 + e * r0 / g) / gk) * D
    K0 = (r0 + a * K1) / g
    return K0, K1, (r2 + e * K0) / gk


def _lu3(G: np.ndarray):
    import scipy.linalg
    return scipy.linalg.lu_factor(G)


def _solve_dense(lu, r):
    import scipy.linalg
    return tuple(scipy.linalg.lu_solve(lu, np.asarray(r, dtype=float)))


def simulate_zoh(plant: EMPlant, eta0, h: float, inputs: Sequence[float], rtol: float = 1e-11) -> np.ndarray:
    """Reference solution: the states at t = k h (k = 0..len(inputs)) for input inputs[k] held on
    [k h, (k+1) h], each step integrated by scipy's Radau with the exact Jacobian on states scaled by
    `nominal_scale`, to relative and absolute (scaled) tolerance rtol. Raises DomainError on leaving
    the domain."""
    from scipy.integrate import solve_ivp

    s = nominal_scale(plant)
    eta = np.asarray(eta0, dtype=float)
    plant.check_state(eta)
    out = [eta]
    for k, u in enumerate(inputs):
        ua = np.array([float(u)])
        sol = solve_ivp(lambda t, xi: plant.f(xi * s, ua) / s, (0.0, h), eta / s, method="Radau",
                        rtol=rtol, atol=rtol, jac=lambda t, xi: plant.jacobian(xi * s) * s[None, :] / s[:, None])
        if not sol.success:
            raise StepFailure(f"reference integration failed in step {k}: {sol.message}")
        eta = sol.y[:, -1] * s
        plant.check_state(eta)
        out.append(eta)
    return np.array(out)
