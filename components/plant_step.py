"""The open-loop plant over one communication step with a polynomial input: what a plant FMU's doStep computes.

Between two communication points t_k and t_k + h a co-simulation master either holds the input
constant or, through fmi2SetRealInputDerivatives, hands a polynomial
    u(t_k + tau) = u + u' tau + u'' tau^2 / 2 + sum_{k >= 3} u^(k) tau^k / k!,      0 <= tau <= h,
and the plant integrates eq. (open-loop elecmech), eta' = f(eta, u(t)), over the step from its
current state. (The held input is the polynomial with u' = u'' = 0.) FMI 2.0 lets a master send any
order; the quadratic (the orders a master usually sends) has a path of its own, any higher degree
(`advance`'s `higher`) goes through `input_value`.

The MEMS switch is extremely stiff: its electrical time constant 1/alpha = r_e c1 (q + c0) is ~1e-10 s
near the rest position and ~2e-7 s at the tracking scenario's q ~ 0.06 m; its mechanics ~1e-4 s.
Two things make a communication step both cheap and accurate:

1. The electrical layer. The electrical equation is linear in x_e for fixed q,
       x_e' = A(q) x_e + G_e u(t),   A(q) = (J_e - R_e) Psi(q)    (n_e = 1: A = -alpha, alpha > 0),
   so x_e = x_s + delta splits exactly into a part x_s that starts on the slow manifold
       x_s(0) = (G_e / alpha) (u - u'/alpha + u''/alpha^2 - u^(3)/alpha^3 + ...) + G_e u alpha' / alpha^3
   (alpha' = d alpha/dt along the motion) and a layer delta' = -alpha(q(t)) delta that decays from
   delta_0 = x_e - x_s(0) as delta_0 exp(-alpha tau - alpha' tau^2 / 2). The layer acts on the
   mechanics only through the extra force -1/2 Psi'(q) (2 x_s delta + delta^2) of the p-row, whose
   integral over the step is the momentum kick
       dp = F_pq (Psi'(q) delta_0 / alpha) (x_s (1 - E) + delta_0 (1 - E^2) / 4),  E = exp(-alpha h - ...).
   So the step integrates the smooth part from (q, p + dp, x_s(0)) and adds delta_0 E to x_e at the
   end. The layer is applied when it is stiff for the step (alpha h >= LAYER_MIN_DECAY) and well
   separated from the mechanics (alpha T_m >= LAYER_SEPARATION), and when the terms it neglects (of
   relative size 1/(alpha T_m): the motion of q, p during the layer) are below LAYER_TOL times the
   step's error tolerance. Derivation: docs/derivations.md, "Plant step".
2. The smooth remainder is integrated by RODAS4 (Hairer & Wanner, Solving ODEs II, Sec. IV.7: a
   stiffly accurate, L-stable Rosenbrock method of order 4 with an embedded order-3 estimate) using the
   analytic Jacobian F hess H (eq. open-loop elecmech) and, for the time-varying input, the stage
   times alpha_i and the coefficients gamma_i of the f_t = g u'(t) term; error control on states scaled
   by `nominal_scale`: a substep is accepted when the RMS of err_i / (rtol (1 + |xi_i|)) is <= 1.
   The proposed substep size carries over to the next communication step (`PlantStepper.h_next`).

Without (1) the layer would be resolved by the error control: correct, but ~10-30 substeps per step
(each input jump of a held input starts a new layer).

The fast path (`_ScalarModel`) evaluates eq. (open-loop elecmech) with scalar arithmetic for a
OneDOFPlant (n_m = n_e = 1, constant mass), from the plant's own scalar V', V'', Psi, Psi', Psi'' and
its constant F and g: the same equations as `EMPlant.f` and `EMPlant.jacobian`, which the tests pin
it to. Any other plant with three states uses `EMPlant.f` and `EMPlant.jacobian` directly (slower).

`simulate_polynomial` (and `simulate_zoh`) is the tight-tolerance reference for the same problem
(scipy's Radau, step by step).
"""
from __future__ import annotations

import math
from typing import Mapping, Sequence

import numpy as np

from .ph_plant import DomainError, EMPlant, OneDOFPlant

DEFAULT_RTOL = 1e-8
RTOL_RANGE = (1e-14, 1e-2)  # the relative tolerances PlantStepper accepts
LAYER_MIN_DECAY = 1.0       # alpha h from which the layer is taken in closed form (below, RODAS4 resolves it)
LAYER_SEPARATION = 100.0    # alpha T_m from which the layer counts as fast for the mechanics
LAYER_TOL = 0.1             # the terms the layer neglects must stay below this fraction of the error tolerance
LAYER_GONE = 50.0           # alpha h above which exp(-alpha h) < 2e-22: nothing of the layer is left
MAX_SUBSTEPS = 100_000
# halvings of _boundary_distance at the most: a boundary below 1e-12 ~ 2^-40 is approached from [0, 1e-12] by
# halving, 1034 halvings down to the least subnormal 2^-1074, then 10 more resolve 1e-3 relative (2^-10); the
# halving also ends where no double lies strictly between the bounds (issue 40: a boundary below the least
# subnormal looped forever). emc_plant.c's EMC_BISECTIONS.
BISECTIONS = 1100


def step_factor(e: float) -> tuple[float, float]:
    """(e, factor): the scaled error norm of a substep (inf if not finite) and the factor its successor's
    size gets (RODAS4's embedded order-3 estimate: 0.9 e^(-1/4), limited to [0.2, 5])."""
    if not math.isfinite(e):
        return math.inf, 0.2
    return e, (min(5.0, max(0.2, 0.9 * e ** (-1.0 / _ERROR_ORDER))) if e > 0 else 5.0)


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
# Non-autonomous right-hand side (rodas.f, C2..C4 and D1..D4): stage i evaluates f at t + alpha_i h and
# adds gamma_i h f_t(t, y) to its right-hand side. alpha_i = sum_j alpha_ij and gamma_i = sum_j gamma_ij
# of the untransformed method, i.e. the row sums of a Gamma and Gamma with Gamma = (I/gamma - c)^-1
# (tests/test_plant_step.py derives them so from _A and _C); stages 5 and 6 sit at t + h with gamma_i = 0.
_STAGE_TIME = (0.0, 0.386, 0.21, 0.63, 1.0, 1.0)
_STAGE_GAMMA = (0.25, -0.1043, 0.1035, -0.0362, 0.0, 0.0)


def nominal_scale(plant: EMPlant) -> np.ndarray:
    """Typical magnitudes (q, p, x_e) of a one-degree-of-freedom plant, from its parameters alone.

    Length L: the distance from q = 0 to the domain boundary (MEMS c0, maglev c), else 1.
    Force F: |V'(L)|. Mechanical time T = sqrt(m L / F); momentum m L / T. Electrical state: the x_e
    whose force 1/2 |Psi'(0)| x_e^2 equals F. These only set the absolute tolerance of the integration.
    Plants with n_m > 1 or n_e > 1: `_nominal_scale_general`, the same construction per axis.
    """
    if plant.n_m != 1 or plant.n_e != 1:
        return _nominal_scale_general(plant)
    zero = np.zeros(plant.n)
    L = plant.domain_margin(zero)
    L = L if math.isfinite(L) and L > 0 else 1.0
    force = abs(float(plant.grad_V(np.array([L]))[0])) or 1.0
    m = 1.0 / float(plant.M_inv(np.zeros(1))[0, 0])
    T = math.sqrt(m * L / force)
    dPsi = abs(float(plant.dPsi(np.zeros(1))[0, 0, 0]))
    x_e = math.sqrt(2.0 * force / dPsi) if dPsi > 0 else 1.0
    return np.array([L, m * L / T, x_e])


def _boundary_distance(plant: EMPlant, direction: np.ndarray) -> float:
    """The distance t > 0 from eta = 0 along `direction` (a unit vector in q) to the boundary of the
    admissible domain (domain_margin <= 0 or not finite), to 1e-3 relative; inf if none up to 1e6; nan if
    eta = 0 is itself outside. At most 19 decades and BISECTIONS halvings; 0 for a boundary nearer than the
    least subnormal."""
    eta = np.zeros(plant.n)

    def inside(t: float) -> bool:
        eta[:plant.n_m] = t * direction
        margin = plant.domain_margin(eta)
        return bool(np.isfinite(margin) and margin > 0) or margin == np.inf

    if not inside(0.0):
        return math.nan
    low, high = 0.0, 1e-12
    while inside(high):
        if high >= 1e6:
            return math.inf
        low, high = high, high * 10.0
    for _ in range(BISECTIONS):
        if not high - low > 1e-3 * high:
            break
        mid = 0.5 * (low + high)
        if not low < mid < high:                 # no double between the bounds: resolved to one ulp
            break
        low, high = (mid, high) if inside(mid) else (low, mid)
    return low


def _nominal_scale_general(plant: EMPlant) -> np.ndarray:
    """`nominal_scale` for any n_m, n_e: the one-degree-of-freedom construction per axis.

    Position q_i: L_i, the distance from q = 0 along +-e_i to the domain's boundary (the nearer one), else 1
    (no boundary within 1e6, or q = 0 outside the domain). Force F_i = |dV/dq_i (L_i e_i)|, else 1.
    Momentum p_i: m_i L_i / T_i with m_i = 1 / (M^-1(0))_ii and T_i = sqrt(m_i L_i / F_i). Electrical
    state x_e_j: the x whose force 1/2 |dPsi_jj/dq_k(0)| x^2 equals F_k on the axis k where Psi_jj varies
    most, else 1. A scale that comes out zero or not finite is 1. They only set the absolute tolerance.
    """
    m, e = plant.n_m, plant.n_e
    L, force, mass = np.ones(m), np.ones(m), np.ones(m)
    M_inv = np.real(np.asarray(plant.M_inv(np.zeros(m)), dtype=float))
    for i in range(m):
        unit = np.zeros(m)
        unit[i] = 1.0
        d = min(_boundary_distance(plant, unit), _boundary_distance(plant, -unit))
        if math.isfinite(d) and d > 0:
            L[i] = d
        F_i = abs(float(np.real(plant.grad_V(L[i] * unit)[i])))
        force[i] = F_i if math.isfinite(F_i) and F_i > 0 else 1.0
        mass[i] = 1.0 / M_inv[i, i] if M_inv[i, i] > 0 else 1.0
    T = np.sqrt(mass * L / force)
    x_e = np.ones(e)
    dPsi = np.abs(np.real(np.asarray(plant.dPsi(np.zeros(m)), dtype=float)))      # (n_m, n_e, n_e)
    for j in range(e):
        k = int(np.argmax(dPsi[:, j, j]))
        if dPsi[k, j, j] > 0:
            x_e[j] = math.sqrt(2.0 * force[k] / dPsi[k, j, j])
    s = np.concatenate([L, mass * L / T, x_e])
    return np.where(np.isfinite(s) & (s > 0), s, 1.0)


def mechanical_time(plant: EMPlant) -> float:
    """T = sqrt(m L / F) of `nominal_scale`: the time scale the electrical layer is compared with."""
    s = nominal_scale(plant)
    m = 1.0 / float(plant.M_inv(np.zeros(1))[0, 0])
    return m * s[0] / s[1]


def _moments(beta: float, h: float) -> tuple[float, float, float, float]:
    """int_0^h tau^k exp(-beta tau) d tau for k = 0..3 (beta h >= 1: no cancellation)."""
    bh = beta * h
    E = math.exp(-bh) if bh < LAYER_GONE else 0.0
    ib = 1.0 / beta
    return ((1.0 - E) * ib, (1.0 - E * (1.0 + bh)) * ib ** 2, (2.0 - E * (2.0 + bh * (2.0 + bh))) * ib ** 3,
            (6.0 - E * (6.0 + bh * (6.0 + bh * (3.0 + bh)))) * ib ** 4)


def _power_over_factorial(tau: float, m: int) -> float:
    """tau^m / m! for tau >= 0 and an integer m >= 0 (inf where it overflows; m may be large: the
    factorial is never formed beyond 20!)."""
    if m == 0:
        return 1.0
    if tau == 0.0:
        return 0.0
    try:
        if m <= 20:
            return tau ** m / math.factorial(m)
        return math.exp(m * math.log(tau) - math.lgamma(m + 1.0))
    except OverflowError:
        return math.inf


def input_value(terms: Sequence[tuple[int, float]], tau: float, shift: int = 0) -> float:
    """d^shift/dtau^shift of the input polynomial u(tau) = sum_k c_k tau^k / k! at tau >= 0, from its
    terms (k, c_k) (orders without a term are 0)."""
    total = 0.0
    for k, c in terms:
        if k >= shift and c != 0.0:
            total += c * _power_over_factorial(tau, k - shift)
    return total


def input_terms(u: float, du: float, d2u: float, higher: Mapping[int, float] | None) -> tuple[tuple[int, float], ...]:
    """The terms (k, u^(k)) of the input polynomial: orders 0, 1, 2 and those of `higher` (orders >= 3);
    ValueError naming an order that is not an integer >= 3 or whose value is not finite."""
    terms = [(0, u), (1, du), (2, d2u)]
    for k, c in sorted((higher or {}).items()):
        if isinstance(k, bool) or not isinstance(k, int) or k < 3:
            raise ValueError(f"input derivative order {k!r} is not an integer >= 3 (orders 1 and 2 are du, d2u)")
        if not math.isfinite(c):
            raise ValueError(f"input derivative d^{k}u/dt^{k} = {c} is not finite")
        terms.append((k, float(c)))
    return tuple(terms)


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

    def time_derivatives(self, q: float, p: float, x: float, u: float, u_dot: float):
        """`EMPlant.time_derivatives` in scalars: ((q', p', x_e'), (q'', p'', x_e''), H', H'').

        With grad H = (V' + 1/2 x_e^2 Psi', p/m, Psi x_e) and w = hess H eta':
        eta' = F grad H + g u, eta'' = F w + g u_dot, H' = grad H . eta', H'' = eta' . w + grad H . eta''."""
        Psi, dPsi = self.Psi(q), self.dPsi(q)
        gq, gp, gx = self.dV(q) + 0.5 * x * x * dPsi, self.m_inv * p, Psi * x
        f0, f1, f2 = self.F_qp * gp, self.F_pq * gq + self.F_pp * gp, self.F_xx * gx + self.g_x * u
        h_qx = x * dPsi
        w0 = (self.d2V(q) + 0.5 * x * x * self.d2Psi(q)) * f0 + h_qx * f2
        w1, w2 = self.m_inv * f1, h_qx * f0 + Psi * f2
        e0, e1, e2 = self.F_qp * w1, self.F_pq * w0 + self.F_pp * w1, self.F_xx * w2 + self.g_x * u_dot
        return ((f0, f1, f2), (e0, e1, e2), gq * f0 + gp * f1 + gx * f2,
                f0 * w0 + f1 * w1 + f2 * w2 + gq * e0 + gp * e1 + gx * e2)


class _ArrayModel(_ScalarModel):
    """Any three-state plant: `EMPlant.f` and `EMPlant.jacobian` (dense) behind the scalar interface."""

    def __init__(self, plant: EMPlant):
        super().__init__(plant)
        self.plant = plant

    def psi(self, q):
        qa = np.array([q])
        return float(self.plant.Psi(qa)[0, 0]), float(self.plant.dPsi(qa)[0, 0, 0])

    def d2Psi(self, q):
        return float(self.plant.d2Psi(np.array([q]))[0, 0, 0, 0])

    def dV(self, q):
        return float(self.plant.grad_V(np.array([q]))[0])

    def d2V(self, q):
        return float(self.plant.hess_V(np.array([q]))[0, 0])

    def f(self, q, p, x, u):
        return tuple(float(v) for v in self.plant.f(np.array([q, p, x]), np.array([u])))

    def f_jac(self, q, p, x, u):
        eta = np.array([q, p, x])
        return self.f(q, p, x, u), np.asarray(self.plant.jacobian(eta), dtype=float)

    def time_derivatives(self, q, p, x, u, u_dot):
        d1, d2, H1, H2 = self.plant.time_derivatives(np.array([q, p, x]), u, u_dot)
        return tuple(float(v) for v in d1), tuple(float(v) for v in d2), H1, H2


class PlantStepper:
    """Advances a plant's state over communication steps with a held input.

    rtol      relative tolerance of the integration (absolute tolerance rtol * nominal_scale)
    h_next    integrator state: the substep size proposed for the next step (0: none yet); an FMU must
              save and restore it with its state for rolled-back steps to reproduce exactly.
    """

    def __init__(self, plant: EMPlant, rtol: float = DEFAULT_RTOL, max_substeps: int = MAX_SUBSTEPS):
        if plant.n_m != 1 or plant.n_e != 1:
            raise NotImplementedError(f"{plant.name}: PlantStepper handles n_m = n_e = 1")
        if not (math.isfinite(rtol) and RTOL_RANGE[0] <= rtol <= RTOL_RANGE[1]):
            low, high = (f"{v:.0e}".replace("e-0", "e-") for v in RTOL_RANGE)      # 1e-14, 1e-2
            raise ValueError(f"parameter rtol = {rtol} violates {low} <= rtol <= {high} "
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

    # ---- output derivatives ----------------------------------------------------------------------
    def time_derivatives(self, q: float, p: float, x: float, u: float, u_dot: float = 0.0):
        """((q', p', x_e'), (q'', p'', x_e''), H', H'') at state (q, p, x_e) with input u and input rate
        u_dot: the exact derivatives of eq. (open-loop elecmech) (`EMPlant.time_derivatives`)."""
        return self.model.time_derivatives(q, p, x, u, u_dot)

    # ---- the electrical layer ------------------------------------------------------------------
    def layer(self, q: float, p: float, x: float, u: float, h: float, du: float = 0.0,
              d2u: float = 0.0, higher: Sequence[tuple[int, float]] = ()) -> tuple[float, float, float, float, bool]:
        """(q_0, p_0, x_s(0), delta(h), applied): the electrical layer of a step of size h taken in closed
        form (module doc; docs/derivations.md, "Plant step"), or (q, p, x, 0, False) when it does not apply.
        `higher`: the terms (k, u^(k)) of the input polynomial of orders k >= 3.

        The smooth part of the step starts from (q_0, p_0, x_s(0)); delta(h) is what is left of the layer
        at the end of the step, to be added to x_e there."""
        model = self.model
        Psi, dPsi = model.psi(q)
        alpha = -model.F_xx * Psi                               # n_e = 1: A(q) = (J_e - R_e) Psi(q) = -alpha
        ah = alpha * h
        if not (ah >= LAYER_MIN_DECAY and alpha * self.t_mech >= LAYER_SEPARATION):
            return q, p, x, 0.0, False
        F_pq, F_xx, g, ia = model.F_pq, model.F_xx, model.g_x, 1.0 / alpha
        d2Psi, J_qp, J_pp = model.d2Psi(q), model.F_qp * model.m_inv, model.F_pp * model.m_inv
        # the slow manifold x_s of the electrical row and its rate, to first order in 1/alpha
        v = J_qp * p                                            # q'
        alpha1 = -F_xx * dPsi * v                               # alpha' along the motion
        if higher:
            # the slow manifold's series for a polynomial input, w - w'/alpha + w''/alpha^2 - ... with
            # w = G_e u / alpha (exact for a frozen alpha): the orders k >= 3 enter through the u'' slot,
            # d2u + sum_k (-1/alpha)^(k-2) u^(k)
            try:
                d2u = d2u + sum(c * (-ia) ** (k - 2) for k, c in higher)
            except OverflowError:
                return q, p, x, 0.0, False
            if not math.isfinite(d2u):
                return q, p, x, 0.0, False
        x_s = g * ia * (u - ia * (du - ia * d2u) + u * alpha1 * ia * ia)
        x_s1 = g * ia * (du - ia * d2u - u * alpha1 * ia)
        d0 = x - x_s
        tol, (sq, sp, sx) = LAYER_TOL * self.rtol, self.scale
        # relative rates over the layer: r1 (first derivatives of alpha, Psi', x_s along the motion) and
        # sigma (the mechanics: J_s with x_e on its manifold, k_s = J_pq - J_px J_xq / J_xx)
        xx = x_s * x_s
        k_s = F_pq * (model.d2V(q) + 0.5 * xx * d2Psi - xx * dPsi * dPsi / Psi)
        size = abs(x_s) + abs(d0) or 1.0
        r1 = (abs(alpha1) * ia + (abs(d2Psi * v / dPsi) if dPsi else 0.0) + abs(x_s1) / size) * ia
        sigma = max(math.sqrt(abs(k_s * J_qp)), abs(J_pp), 1.0 / self.t_mech) * ia
        kick = abs(d0) * (abs(dPsi * x_s) + abs(d0 * dPsi) * 0.25) * ia   # size of the zeroth-order kick
        if ah >= LAYER_GONE and kick * (r1 + sigma) <= tol * (sp + abs(p)) and \
                abs(J_qp) * kick * ia <= tol * (sq + abs(q)):
            # the layer ends inside the step and what the first-order terms and the delay add is below a
            # tenth of the tolerance: the zeroth-order kick suffices (the common case: large alpha h)
            return q, p + F_pq * dPsi * d0 * (x_s + 0.25 * d0) * ia, x_s, 0.0, True
        # the layer's extra force on the p-row, G = F_pq Psi'(q) (x_s delta + delta^2 / 2) with
        # delta = d0 exp(-alpha tau - alpha' tau^2 / 2), to first order along the motion; its moments
        # M_k = int_0^h tau^k / k! G d tau
        Phi0, Phi1 = F_pq * dPsi * x_s, F_pq * (d2Psi * v * x_s + dPsi * x_s1)
        B0, B1 = 0.5 * F_pq * dPsi, 0.5 * F_pq * d2Psi * v
        J0, J1, J2, J3 = _moments(alpha, h)                     # int_0^h tau^k exp(-alpha tau) d tau
        L0, L1, L2, L3 = _moments(2.0 * alpha, h)
        d00 = d0 * d0
        M0 = d0 * (Phi0 * J0 + Phi1 * J1 - 0.5 * alpha1 * Phi0 * J2) + d00 * (B0 * L0 + B1 * L1 - alpha1 * B0 * L2)
        M1 = d0 * (Phi0 * J1 + Phi1 * J2 - 0.5 * alpha1 * Phi0 * J3) + d00 * (B0 * L1 + B1 * L2 - alpha1 * B0 * L3)
        M2 = 0.5 * (d0 * Phi0 * J2 + d00 * B0 * L2)
        # The smooth part feels the force G as if it all came at tau = 0, so it starts from
        # (q, p) + sum_k (-J_s)^k e_p M_k (J_s: J_qp, J_pp, k_s): the kick M_0 and the corrections for its delay.
        dq = -J_qp * M1 + J_qp * J_pp * M2
        dp = M0 - J_pp * M1 + (k_s * J_qp + J_pp * J_pp) * M2
        E = math.exp(-ah - 0.5 * alpha1 * h * h) if ah < LAYER_GONE else 0.0
        # What this neglects, relative to the kick: second order in the rates of the motion over the layer
        # (r1 squared; r2: second derivatives), a cross term and third order in the mechanical rates
        # (sigma); for delta(h), the next term alpha'' h^3 / 6 of its exponent.
        a_q = J_qp * (F_pq * (model.dV(q) + 0.5 * xx * dPsi) + J_pp * p)      # q''
        alpha2 = -F_xx * (d2Psi * v * v + dPsi * a_q)
        r2 = (abs(alpha2) * ia + (abs(d2Psi * a_q / dPsi) if dPsi else 0.0) + abs(g * d2u) * ia / size) * ia * ia
        if kick * (r1 * r1 + r2 + r1 * sigma + sigma ** 3) > tol * (sp + abs(p)) or \
                abs(J_qp * kick) * ia * (r1 * r1 + r2 + sigma * sigma) > tol * (sq + abs(q)) or \
                abs(d0) * E * abs(alpha2) * h * h * h / 6.0 > tol * (sx + abs(x_s)):
            return q, p, x, 0.0, False
        return q + dq, p + dp, x_s, d0 * E, True

    # ---- one communication step ------------------------------------------------------------------
    def step(self, eta: Sequence[float], u, h: float, du: float = 0.0, d2u: float = 0.0,
             higher: Mapping[int, float] | None = None) -> np.ndarray:
        """The state after h seconds from state eta with the input u(t + tau) = u + du tau + d2u tau^2 / 2
        (du = d2u = 0: the input held), plus sum_k higher[k] tau^k / k! for the orders k >= 3 in `higher`.

        Raises ValueError for a non-finite or non-positive h, a non-finite u, du, d2u or eta; DomainError
        (with the plant's reason) if the state leaves the domain; StepFailure if the integration fails.
        The stepper's h_next changes only when the step succeeds.
        """
        u = float(np.asarray(u, dtype=float).reshape(-1)[0])
        q, p, x = (float(v) for v in eta)
        return np.array(self.advance(q, p, x, u, float(h), float(du), float(d2u), higher))

    def advance(self, q: float, p: float, x: float, u: float, h: float, du: float = 0.0,
                d2u: float = 0.0, higher: Mapping[int, float] | None = None) -> tuple[float, float, float]:
        """`step` on floats: (q, p, x_e) after h seconds with the input u + du tau + d2u tau^2 / 2
        (+ the orders k >= 3 of `higher`: {k: d^k u/dt^k}). (Python floats: numpy scalars work but make
        the arithmetic about twice as slow.)"""
        if not (math.isfinite(h) and h > 0):
            raise ValueError(f"communication step size h = {h} must be finite and > 0")
        if not (math.isfinite(u) and math.isfinite(du) and math.isfinite(d2u)):
            bad = next(f"{n} = {v}" for n, v in (("input u", u), ("input derivative du/dt", du),
                                                   ("input derivative d2u/dt2", d2u)) if not math.isfinite(v))
            raise ValueError(f"{bad} is not finite")
        terms = self._higher_terms(u, du, d2u, higher, h) if higher else None
        self._check(q, p, x)
        q, p, x, x_left, self.layer_applied = self.layer(q, p, x, u, h, du, d2u, terms[3:] if terms else ())
        y, h_next, n_ok, n_rej = self._integrate(q, p, x, u, du, d2u, h, terms)
        self.h_next, self.n_substeps, self.n_rejected = h_next, n_ok, n_rej
        if x_left:
            y = (y[0], y[1], y[2] + x_left)
        return y

    @staticmethod
    def _higher_terms(u: float, du: float, d2u: float, higher: Mapping[int, float],
                      h: float) -> tuple[tuple[int, float], ...] | None:
        """The polynomial's terms (`input_terms`), or None when every order >= 3 is 0 (the quadratic path);
        ValueError if the polynomial overflows over the step."""
        terms = input_terms(u, du, d2u, higher)
        if all(c == 0.0 for _, c in terms[3:]):
            return None
        bound = sum(abs(c) * _power_over_factorial(h, k) for k, c in terms)
        if not math.isfinite(bound):
            raise ValueError(f"the input polynomial of orders up to {terms[-1][0]} overflows over the step "
                             f"h = {h:g} s (sum |u^(k)| h^k / k! is not finite)")
        return terms

    def _integrate(self, q, p, x, u, du, d2u, h, terms=None):
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
                if terms is None:                     # the quadratic re-expanded at the substep's start t
                    y_new, err = rodas4(model, y, u + t * (du + 0.5 * t * d2u), du + t * d2u, d2u, hh,
                                        iq, ip, ix, sq, sp, sx)
                else:                                 # any degree: its values at the stage times
                    stages = tuple(input_value(terms, t + a * hh) for a in _STAGE_POINTS)
                    y_new, err = rodas4(model, y, input_value(terms, t), input_value(terms, t, 1), 0.0, hh,
                                        iq, ip, ix, sq, sp, sx, stages)
                e0, e1, e2 = err
                n0 = rtol * (1.0 + max(abs(y[0]), abs(y_new[0])))
                n1 = rtol * (1.0 + max(abs(y[1]), abs(y_new[1])))
                n2 = rtol * (1.0 + max(abs(y[2]), abs(y_new[2])))
                e = math.sqrt(((e0 / n0) ** 2 + (e1 / n1) ** 2 + (e2 / n2) ** 2) / 3.0)
            except (ArithmeticError, ValueError):
                e = math.inf
            e, factor = step_factor(e)
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

    def _rodas4_dense(self, model, y, u, du, d2u, h, iq, ip, ix, sq, sp, sx, stages=None):
        """One RODAS4 step in scaled variables, dense Jacobian, input u + du tau + d2u tau^2 / 2 (or, given
        `stages`, the input's values at the stage times _STAGE_POINTS h; du its rate at the start):
        (y_new, error estimate)."""
        f0, jac = model.f_jac(y[0] * sq, y[1] * sp, y[2] * sx, u)
        gi = 1.0 / (h * _GAMMA)
        lu = _lu3(gi * np.eye(3) - jac * np.outer([iq, ip, ix], [sq, sp, sx]))
        ft = h * model.g_x * du * ix                             # h f_t, scaled: only the x_e-row depends on t
        Ks = []
        y0, y1, y2 = y
        r = (f0[0] * iq, f0[1] * ip, f0[2] * ix + _STAGE_GAMMA[0] * ft)
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
                tau = _STAGE_TIME[i] * h
                ui = u + tau * (du + 0.5 * tau * d2u) if stages is None else stages[min(i, 4) - 1]
                fi = model.f(Y0 * sq, Y1 * sp, Y2 * sx, ui)
                r = (fi[0] * iq + hi * c0, fi[1] * ip + hi * c1, fi[2] * ix + hi * c2 + _STAGE_GAMMA[i] * ft)
            Ks.append(_solve_dense(lu, r))
        K6 = Ks[5]
        return (Y0 + K6[0], Y1 + K6[1], Y2 + K6[2]), K6


# RODAS4's coefficients by name, for the written-out stages of `_rodas4_structured`
(_a21,), (_a31, _a32), (_a41, _a42, _a43), (_a51, _a52, _a53, _a54), (_a61, _a62, _a63, _a64, _a65) = _A[1:]
(_c21,), (_c31, _c32), (_c41, _c42, _c43), (_c51, _c52, _c53, _c54), (_c61, _c62, _c63, _c64, _c65) = _C[1:]
_, _t2, _t3, _t4, _, _ = _STAGE_TIME
_STAGE_POINTS = (_t2, _t3, _t4, 1.0)        # the stage times after 0 (stages 5 and 6 share t + h)
_d1, _d2, _d3, _d4, _, _ = _STAGE_GAMMA


def _rodas4_structured(model, y, u, du, d2u, h, iq, ip, ix, sq, sp, sx, stages=None):
    """One RODAS4 step in scaled variables for J = [[0, a, 0], [b, c, d], [e, 0, k]] (a OneDOFPlant),
    input u + du tau + d2u tau^2 / 2 (or, given `stages`, the input's values at the stage times
    _STAGE_POINTS h; du its rate at the start): (y_new, error estimate). The same method as
    `PlantStepper._rodas4_dense`, with the six stages written out (a loop over the coefficient table
    would cost more than the arithmetic) and the linear solves done by elimination."""
    f0, (J_qp, J_pq, J_pp, J_px, J_xq, J_xx) = model.f_jac(y[0] * sq, y[1] * sp, y[2] * sx, u)
    g = 1.0 / (h * _GAMMA)
    # G = I/(h gamma) - J (scaled): eliminate K_q and K_x into the K_p equation
    a, b, c = J_qp * sp * iq, J_pq * sq * ip, J_pp
    d, e, gk = J_px * sx * ip, J_xq * sq * ix, g - J_xx
    lu = (g, a, b, c, d, e, gk, 1.0 / ((g - c) - a * b / g - a * d * e / (g * gk)))

    f = model.f
    hi = 1.0 / h
    ft = h * model.g_x * du * ix                                 # h f_t, scaled: only the x_e-row depends on t
    y0, y1, y2 = y
    # stage 1
    p0, p1, p2 = _solve_structured(lu, (f0[0] * iq, f0[1] * ip, f0[2] * ix + _d1 * ft))
    if stages is None:
        t2, t3, t4 = _t2 * h, _t3 * h, _t4 * h
        stages = (u + t2 * (du + 0.5 * t2 * d2u), u + t3 * (du + 0.5 * t3 * d2u), u + t4 * (du + 0.5 * t4 * d2u),
                  u + h * (du + 0.5 * h * d2u))
    u2, u3, u4, u1 = stages
    # stage 2
    fi = f((y0 + _a21 * p0) * sq, (y1 + _a21 * p1) * sp, (y2 + _a21 * p2) * sx, u2)
    q0, q1, q2 = _solve_structured(lu, (fi[0] * iq + hi * _c21 * p0, fi[1] * ip + hi * _c21 * p1,
                                        fi[2] * ix + hi * _c21 * p2 + _d2 * ft))
    # stage 3
    fi = f((y0 + _a31 * p0 + _a32 * q0) * sq, (y1 + _a31 * p1 + _a32 * q1) * sp,
           (y2 + _a31 * p2 + _a32 * q2) * sx, u3)
    r0, r1, r2 = _solve_structured(lu, (fi[0] * iq + hi * (_c31 * p0 + _c32 * q0),
                                        fi[1] * ip + hi * (_c31 * p1 + _c32 * q1),
                                        fi[2] * ix + hi * (_c31 * p2 + _c32 * q2) + _d3 * ft))
    # stage 4
    fi = f((y0 + _a41 * p0 + _a42 * q0 + _a43 * r0) * sq, (y1 + _a41 * p1 + _a42 * q1 + _a43 * r1) * sp,
           (y2 + _a41 * p2 + _a42 * q2 + _a43 * r2) * sx, u4)
    s0, s1, s2 = _solve_structured(lu, (fi[0] * iq + hi * (_c41 * p0 + _c42 * q0 + _c43 * r0),
                                        fi[1] * ip + hi * (_c41 * p1 + _c42 * q1 + _c43 * r1),
                                        fi[2] * ix + hi * (_c41 * p2 + _c42 * q2 + _c43 * r2) + _d4 * ft))
    # stage 5 (at t + h, gamma_5 = 0)
    fi = f((y0 + _a51 * p0 + _a52 * q0 + _a53 * r0 + _a54 * s0) * sq,
           (y1 + _a51 * p1 + _a52 * q1 + _a53 * r1 + _a54 * s1) * sp,
           (y2 + _a51 * p2 + _a52 * q2 + _a53 * r2 + _a54 * s2) * sx, u1)
    t0, t1, t2 = _solve_structured(lu, (fi[0] * iq + hi * (_c51 * p0 + _c52 * q0 + _c53 * r0 + _c54 * s0),
                                        fi[1] * ip + hi * (_c51 * p1 + _c52 * q1 + _c53 * r1 + _c54 * s1),
                                        fi[2] * ix + hi * (_c51 * p2 + _c52 * q2 + _c53 * r2 + _c54 * s2)))
    # stage 6 (at t + h, gamma_6 = 0): Y_6 = y + sum_j a_6j K_j; y_new = Y_6 + K_6 (stiffly accurate),
    # K_6 is the error estimate
    Y0 = y0 + _a61 * p0 + _a62 * q0 + _a63 * r0 + _a64 * s0 + _a65 * t0
    Y1 = y1 + _a61 * p1 + _a62 * q1 + _a63 * r1 + _a64 * s1 + _a65 * t1
    Y2 = y2 + _a61 * p2 + _a62 * q2 + _a63 * r2 + _a64 * s2 + _a65 * t2
    fi = f(Y0 * sq, Y1 * sp, Y2 * sx, u1)
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


def vector_terms(u, derivatives: Mapping[int, Sequence[float]] | None, n_e: int) -> tuple[tuple[int, np.ndarray], ...]:
    """The terms (k, u^(k)) of an input polynomial u(tau) = sum_k u^(k) tau^k / k! with vector coefficients
    (shape (n_e,)): order 0 is u, the others come from `derivatives` ({k: d^k u/dt^k}, k >= 1, missing orders
    and entries 0). ValueError naming the order for a wrong shape, an order that is not an integer >= 1, or a
    value that is not finite."""
    terms = []
    for k, c in [(0, u), *sorted((derivatives or {}).items())]:
        if isinstance(k, bool) or not isinstance(k, int) or k < 0 or (k == 0 and terms):
            raise ValueError(f"input derivative order {k!r} is not an integer >= 1")
        a = np.array(c, dtype=float).reshape(-1)
        if a.shape != (n_e,):
            raise ValueError(f"input derivative of order {k} has {a.size} entries, expected n_e = {n_e}")
        if not np.all(np.isfinite(a)):
            raise ValueError(f"input {'u' if k == 0 else f'derivative d^{k}u/dt^{k}'} = {a.tolist()} is not finite")
        if k == 0 or np.any(a != 0.0):
            terms.append((k, a))
    return tuple(terms)


def vector_input(terms: Sequence[tuple[int, np.ndarray]], tau: float, shift: int = 0) -> np.ndarray:
    """d^shift/dtau^shift of the vector input polynomial of `vector_terms` at tau >= 0."""
    total = np.zeros_like(terms[0][1])
    for k, c in terms:
        if k >= shift:
            total = total + c * _power_over_factorial(tau, k - shift)
    return total


class GeneralStepper:
    """`PlantStepper` for any n_m, n_e (a plant that is not a OneDOFPlant with three states): the state
    eta = (q, p, x_e) and the input u (n_e entries) as numpy arrays.

    Over a communication step of size h the input is held or, per input, the polynomial
    u(t + tau) = sum_k u^(k) tau^k / k! (the derivatives the master set, any orders), and eq. (open-loop
    elecmech), eta' = F grad H(eta) + g u(t), is integrated by the same RODAS4 as PlantStepper's: the
    analytic Jacobian F hess H (EMPlant.jacobian), the stage times and the f_t = g u'(t) terms of the
    time-varying input, states scaled by `nominal_scale`, a substep accepted when the RMS over the n states
    of err_i / (rtol (1 + |xi_i|)) is <= 1, the proposed substep carried over (`h_next`). There is no
    closed-form electrical layer here (PlantStepper's shortcut for the stiff n_e = 1 layer): a stiff
    electrical layer is resolved by the error control (correct, more substeps).

    rtol      relative tolerance (absolute tolerance rtol * nominal_scale)
    h_next    integrator state: the substep proposed for the next step (0: none yet); an FMU saves and
              restores it with its state
    """

    def __init__(self, plant: EMPlant, rtol: float = DEFAULT_RTOL, max_substeps: int = MAX_SUBSTEPS):
        if not (math.isfinite(rtol) and RTOL_RANGE[0] <= rtol <= RTOL_RANGE[1]):
            low, high = (f"{v:.0e}".replace("e-0", "e-") for v in RTOL_RANGE)
            raise ValueError(f"parameter rtol = {rtol} violates {low} <= rtol <= {high} "
                             "(relative tolerance of the plant integration)")
        self.plant = plant
        self.rtol = float(rtol)
        self.max_substeps = int(max_substeps)
        self.scale = np.asarray(nominal_scale(plant), dtype=float)
        self.g = plant.g()
        self.h_next = 0.0
        self.n_substeps = 0
        self.n_rejected = 0

    def check(self, eta: np.ndarray) -> None:
        """Raise the plant's DomainError if eta is not finite or outside the domain."""
        if not (np.all(np.isfinite(eta)) and self.plant.domain_margin(eta) > 0):
            self.plant.check_state(eta)
            raise DomainError(f"{self.plant.name}: state {eta} is outside the domain")

    def time_derivatives(self, eta, u, u_dot=0.0) -> tuple[np.ndarray, np.ndarray, float, float]:
        """(eta', eta'', H', H'') of eq. (open-loop elecmech) at eta with input u and rate u_dot (n_e each)."""
        return self.plant.time_derivatives(np.asarray(eta, dtype=float), u, u_dot)

    def step(self, eta, u, h: float, derivatives: Mapping[int, Sequence[float]] | None = None) -> np.ndarray:
        """The state after h seconds from eta with the input polynomial of u and `derivatives` ({k: d^k u/dt^k}
        per input; None or {}: u held). ValueError for a bad h, u, derivative or eta; DomainError if the state
        leaves the domain; StepFailure on step size underflow or too many substeps. h_next changes only when
        the step succeeds."""
        h = float(h)
        if not (math.isfinite(h) and h > 0):
            raise ValueError(f"communication step size h = {h} must be finite and > 0")
        plant = self.plant
        terms = vector_terms(u, derivatives, plant.n_e)
        eta = np.array(eta, dtype=float).reshape(-1)
        if eta.shape != (plant.n,):
            raise ValueError(f"{plant.name}: state has {eta.size} entries, expected {plant.n}")
        self.check(eta)
        if not math.isfinite(sum(float(np.max(np.abs(c))) * _power_over_factorial(h, k) for k, c in terms)):
            raise ValueError(f"the input polynomial overflows over the step h = {h:g} s")
        s, rtol = self.scale, self.rtol
        y = eta / s
        t, hs = 0.0, min(self.h_next or h, h)
        n_ok = n_rej = 0
        h_min = 1e-13 * h
        while True:
            remaining = h - t
            last = hs >= remaining * (1.0 - 1e-9)
            hh = remaining if last else hs
            try:
                y_new, err = self._rodas4(y, terms, t, hh)
                e = float(np.sqrt(np.mean((err / (rtol * (1.0 + np.maximum(np.abs(y), np.abs(y_new))))) ** 2)))
            except (ArithmeticError, ValueError, np.linalg.LinAlgError):
                e = math.inf
            e, factor = step_factor(e)
            if e <= 1.0:
                n_ok += 1
                y = y_new
                self.check(y * s)
                proposal = hh * factor
                if last:
                    self.h_next = max(proposal, hs) if hh < hs else proposal
                    self.n_substeps, self.n_rejected = n_ok, n_rej
                    return y * s
                t += hh
                hs = proposal
            else:
                n_rej += 1
                hs = hh * factor
                if hs < h_min:
                    raise StepFailure(f"{plant.name}: step size underflow ({hs:.3g} s) at t + {t:.6g} s in a step "
                                      f"of {h:.6g} s from state {y * s} with u = {terms[0][1]}")
            if n_ok + n_rej >= self.max_substeps:
                raise StepFailure(f"{plant.name}: more than {self.max_substeps} substeps in a step of {h:.6g} s "
                                  f"(reached t + {t:.6g} s)")

    def _rodas4(self, y: np.ndarray, terms, t: float, h: float) -> tuple[np.ndarray, np.ndarray]:
        """One RODAS4 step of size h from the scaled state y at t (the step's time): (y_new, error estimate),
        as PlantStepper._rodas4_dense: (I/(h gamma) - J) K_i = f(Y_i, u(t + alpha_i h)) + sum_j c_ij K_j / h
        + gamma_i h f_t, with f_t = g u'(t) (Hairer & Wanner, rodas.f)."""
        import scipy.linalg

        plant, s = self.plant, self.scale
        eta = y * s
        jac = plant.jacobian(eta) * s[None, :] / s[:, None]            # J = F hess H, eq. (open-loop elecmech)
        lu = scipy.linalg.lu_factor(np.eye(plant.n) / (h * _GAMMA) - jac, check_finite=False)
        held = len(terms) == 1                                         # u constant: no f_t term, one input value
        ft = None if held else h * (self.g @ vector_input(terms, t, 1)) / s    # h f_t, scaled
        K = np.zeros((6, plant.n))
        hi = 1.0 / h
        Y = y
        u0 = terms[0][1]
        for i in range(6):
            Y = y + _A_ROWS[i] @ K
            r = plant.f(Y * s, u0 if held else vector_input(terms, t + _STAGE_TIME[i] * h)) / s + hi * (_C_ROWS[i] @ K)
            if ft is not None:
                r = r + _STAGE_GAMMA[i] * ft
            K[i] = scipy.linalg.lu_solve(lu, r, check_finite=False)
        return Y + K[5], K[5]


# RODAS4's a_ij and c_ij as rows of a 6 x 6 strictly lower triangular matrix (GeneralStepper._rodas4)
_A_ROWS = np.array([list(row) + [0.0] * (6 - len(row)) for row in _A])
_C_ROWS = np.array([list(row) + [0.0] * (6 - len(row)) for row in _C])


def make_stepper(plant: EMPlant, rtol: float = DEFAULT_RTOL) -> PlantStepper | GeneralStepper:
    """PlantStepper (scalars, the electrical layer in closed form) for a plant with n_m = n_e = 1, else
    GeneralStepper (arrays). Why two: GeneralStepper on the paper's plants costs 9-14 times PlantStepper's
    step at the same accuracy (MEMS 190-370 us against 21-25 us, maglev 190-230 us against 16-17 us), and
    120 times on the MEMS's start, where only PlantStepper's closed-form electrical layer keeps the stiff layer
    out of the error control (benchmarks/bench_plant.py --general)."""
    if plant.n_m == 1 and plant.n_e == 1:
        return PlantStepper(plant, rtol)
    return GeneralStepper(plant, rtol)


def simulate_polynomial(plant: EMPlant, eta0, h: float, inputs, rtol: float = 1e-11) -> np.ndarray:
    """Reference solution: the states at t = k h (k = 0..len(inputs)) for the input
    u(k h + tau) = u_k + u'_k tau + u''_k tau^2 / 2 + ... on [k h, (k+1) h], where inputs[k] is u_k or a
    tuple (u_k[, u'_k[, u''_k[, ...]]]) of the polynomial's derivatives at k h, of any length; each step
    integrated by scipy's Radau with the exact Jacobian on states scaled by `nominal_scale`, to relative
    and absolute (scaled) tolerance rtol. Raises DomainError on leaving the domain."""
    from scipy.integrate import solve_ivp

    s = nominal_scale(plant)
    eta = np.asarray(eta0, dtype=float)
    plant.check_state(eta)
    out = [eta]
    for k, row in enumerate(inputs):
        row = tuple(float(v) for v in np.atleast_1d(row))
        u0, u1, u2 = (row + (0.0, 0.0))[:3]
        terms = tuple(enumerate(row))

        def u_of(t: float) -> float:
            return u0 + t * (u1 + 0.5 * t * u2) if len(terms) <= 3 else input_value(terms, t)

        sol = solve_ivp(lambda t, xi: plant.f(xi * s, np.array([u_of(t)])) / s, (0.0, h),
                        eta / s, method="Radau", rtol=rtol, atol=rtol,
                        jac=lambda t, xi: plant.jacobian(xi * s) * s[None, :] / s[:, None])
        if not sol.success:
            raise StepFailure(f"reference integration failed in step {k}: {sol.message}")
        eta = sol.y[:, -1] * s
        plant.check_state(eta)
        out.append(eta)
    return np.array(out)


def simulate_zoh(plant: EMPlant, eta0, h: float, inputs: Sequence[float], rtol: float = 1e-11) -> np.ndarray:
    """`simulate_polynomial` with each input inputs[k] held on [k h, (k+1) h]."""
    return simulate_polynomial(plant, eta0, h, [float(u) for u in inputs], rtol)
