"""Certificates of a controller design: the assumptions, the pH condition, Theorem 1's conditions and
contraction rates (Sections 2, 4, 5, 6 of the paper).

Everything is evaluated over a stated neighbourhood of the target: a tube around eta*(t) (or the box
around eta_d) with half-widths `radius` per state, covered by samples (times x box vertices, centre and
random points). Bounds over the neighbourhood are therefore *sampled*, not rigorous between samples;
the report says so.

Rates: a contraction metric Omega > 0 with Omega J + J^T Omega <= -2 lam Omega at every sample,
J = F_d hess H_d(eta, t) the closed-loop Jacobian, makes distances in the metric decay like
exp(-lam t) (Lemma 1, eq. crate, with sigma = 2 lam). The best constant metric is a semidefinite
program (optimal_metric: bisection on lam with LMI feasibility, cvxpy + Clarabel, in scaled modal
coordinates); every reported rate is the value verified by exact generalised eigenvalues at every
sample, and where no metric exists a dual certificate says so (docs/certificates.md).

Public functions a report can call: certify (everything), theorem1_conditions, contraction_rate,
admissible_D_d, design_checks (what a controller FMU checks at initialization).
"""
from __future__ import annotations

import json
import math
import warnings
from dataclasses import asdict, dataclass, field
from itertools import product

import numpy as np
from scipy import linalg

from . import closed_loop
from .controller import Controller
from .references import Reference, Sinusoid

HOLDS, FAILS, NOT_APPLICABLE, INCONCLUSIVE = "holds", "fails", "not applicable", "inconclusive"


@dataclass
class Check:
    """One condition: a verdict and the numbers behind it."""

    name: str
    verdict: str
    numbers: dict
    note: str = ""


@dataclass
class Certificate:
    controller: str
    neighbourhood: dict
    checks: list[Check] = field(default_factory=list)
    rate: float | None = None            # best certified distance-decay rate [1/s]
    metric: list | None = None           # its Omega
    rate_upper: float | None = None      # no constant metric contracts faster over the samples [1/s]

    def check(self, name: str) -> Check:
        return next(c for c in self.checks if c.name == name)

    def to_json(self) -> str:
        return json.dumps(asdict(self), indent=2, default=_jsonable)

    def report(self) -> str:
        lines = [f"Certificate for {self.controller}",
                 f"  neighbourhood: {self.neighbourhood['description']}"]
        for c in self.checks:
            lines.append(f"  [{c.verdict:>14}] {c.name}")
            for k, v in c.numbers.items():
                lines.append(f"                   {k} = {_fmt(v)}")
            if c.note:
                lines.append(f"                   note: {c.note}")
        if self.rate is not None:
            lines.append(f"  certified rate: {self.rate:.6g} 1/s (no constant metric is faster over the samples "
                         f"than {self.rate_upper:.6g} 1/s)")
        elif self.rate_upper is not None and self.rate_upper <= 0:
            lines.append("  certified rate: none: no constant metric exists over these samples (Lemma 1 above)")
        else:
            lines.append("  certified rate: none found (inconclusive)")
        return "\n".join(lines)


def _jsonable(x):
    if isinstance(x, np.ndarray):
        return x.tolist()
    if isinstance(x, (np.floating, np.integer, np.bool_)):
        return x.item()
    if isinstance(x, complex):
        return [x.real, x.imag]
    raise TypeError(type(x))


def _fmt(v) -> str:
    """Numbers with 6 significant digits; matrices on one line, rows separated by ';'."""
    if isinstance(v, (float, np.floating)):
        return f"{v:.6g}"
    if isinstance(v, (list, tuple, np.ndarray)):
        a = np.asarray(v)
        if np.iscomplexobj(a):
            return "[" + ", ".join(f"{z.real:.6g}{z.imag:+.6g}j" for z in a.ravel()) + "]"
        if a.dtype.kind not in "fiu":
            return str(v)
        rows = np.atleast_2d(a)
        return "[" + "; ".join(" ".join(f"{x:.6g}" for x in row) for row in rows) + "]"
    return str(v)


# ---- the neighbourhood -------------------------------------------------------------------------

@dataclass
class Neighbourhood:
    """Samples (eta, jet) of the tube {eta*(t) + d : |d_i| <= radius_i, t in times} (see `neighbourhood`)."""

    samples: list
    times: np.ndarray
    radius: np.ndarray
    scale: np.ndarray
    description: str


def state_scale(controller: Controller, targets: np.ndarray) -> np.ndarray:
    """Per-state size of the target: max |eta*_i|; for a momentum at rest, sqrt(m x 1 N/m) |q*|."""
    plant = controller.plant
    m = plant.n_m
    s = np.max(np.abs(targets), axis=0)
    q_size = np.max(s[:m])
    p_floor = np.sqrt(1.0 / np.diag(plant.M_inv(targets[0, :m]))) * q_size
    s[m:2 * m] = np.maximum(s[m:2 * m], p_floor)
    return np.where(s > 0, s, 1.0)


def reference_period(reference: Reference | None) -> float | None:
    """The period 2 pi / omega of a sinusoidal reference (None for any other reference)."""
    if isinstance(reference, Sinusoid) and reference.omega > 0 and reference.amplitude != 0:
        return 2.0 * np.pi / reference.omega
    return None


def check_radius(radius: float) -> float:
    """The neighbourhood's relative half-width must be a finite number > 0."""
    try:
        r = float(radius)
    except (TypeError, ValueError):
        raise ValueError(f"radius = {radius!r} is not a number (relative half-width of the neighbourhood)") from None
    if not (np.isfinite(r) and r > 0):
        raise ValueError(f"radius = {radius!r} must be finite and > 0 (relative half-width of the neighbourhood)")
    return r


def neighbourhood(controller: Controller, reference: Reference | None = None, horizon: float = 0.0,
                  radius: float = 0.1, eta0=None, n_times: int = 21, n_random: int = 8,
                  seed: int = 0) -> Neighbourhood:
    """The tube of relative half-width `radius` (times each state's scale) around the target; if eta0
    is given the half-widths grow to contain it, so the certificate covers the start of the run.

    Times: one full period [0, T) for a periodic reference (the target and the closed-loop Jacobian
    repeat, so the tube covers every t >= 0, whatever the horizon), [0, horizon] for another
    time-varying reference, t = 0 for a set-point."""
    radius = check_radius(radius)
    period = reference_period(reference)
    if period is not None:
        times = np.linspace(0.0, period, n_times, endpoint=False)
        what = (f"reference eta*(t) over one period, t in [0, {period:.6g}) s ({n_times} times; "
                "the target is periodic, so this covers every t >= 0)")
    elif reference is not None and horizon > 0:
        times = np.linspace(0.0, horizon, n_times)
        what = f"reference eta*(t), t in [0, {horizon:g}] s ({n_times} times)"
    else:
        times = np.array([0.0])
        what = "set-point eta_d"
    jets = [None if reference is None else reference.jet(t) for t in times]
    targets = np.array([controller.target(j) for j in jets])
    scale = state_scale(controller, targets)
    half = radius * scale
    if eta0 is not None:
        half = np.maximum(half, 1.01 * np.abs(np.asarray(eta0, dtype=float) - targets[0]))
    rng = np.random.default_rng(seed)
    n = controller.plant.n
    corners = np.array(list(product([-1.0, 1.0], repeat=n)))
    samples = []
    for jet, target in zip(jets, targets):
        offsets = np.vstack([np.zeros(n), corners, rng.uniform(-1, 1, (n_random, n))]) * half
        for d in offsets:
            eta = target + d
            if controller.plant.domain_margin(eta) > 0:
                samples.append((eta, jet))
    desc = (f"box around the {what} with half-widths {np.array2string(half, precision=3)} "
            f"(state scales {np.array2string(scale, precision=3)}); {len(samples)} samples "
            f"(centre, {2 ** n} vertices, {n_random} random points per time; outside-domain points dropped); "
            "bounds are sampled, not rigorous between samples")
    return Neighbourhood(samples, times, half, scale, desc)


# ---- assumptions -------------------------------------------------------------------------------

def min_eig(A: np.ndarray) -> float:
    """The smallest eigenvalue of the symmetric part of A (A > 0 iff it is > 0)."""
    return float(np.min(np.linalg.eigvalsh(0.5 * (A + A.T))))


def max_eig(A: np.ndarray) -> float:
    """The largest eigenvalue of the symmetric part of A."""
    return float(np.max(np.linalg.eigvalsh(0.5 * (A + A.T))))


def _verdict(ok: bool) -> str:
    return HOLDS if ok else FAILS


def definiteness(A: np.ndarray) -> tuple[str, float, str]:
    """A > 0 decided in the matrix's own scale: (verdict, min eig of D^-1/2 A D^-1/2 with D = diag(A), note).

    The entries of a Hessian in SI numbers can span 40 orders of magnitude (a charge device's hess H_d with the
    paper's Gamma: 8e46 next to 1e9), so the smallest eigenvalue of A itself is rounding (0 for a matrix whose
    determinant is positive). The diagonal scaling is a congruence (Sylvester's law of inertia: same
    definiteness) that makes the matrix unitless with a unit diagonal; its smallest eigenvalue is decided when
    it exceeds the rounding of the entries (each is known to ~eps of its diagonal), else the verdict is
    inconclusive. A non-positive diagonal entry proves A is not positive definite."""
    S = 0.5 * (np.asarray(A, dtype=float) + np.asarray(A, dtype=float).T)
    d = np.diag(S)
    if not np.all(np.isfinite(S)):
        return INCONCLUSIVE, math.nan, "the matrix has entries that are not finite"
    if np.any(d <= 0):
        return FAILS, float(np.min(d)), "a diagonal entry is <= 0"
    r = 1.0 / np.sqrt(d)
    B = S * np.outer(r, r)
    lam = float(np.min(np.linalg.eigvalsh(B)))
    rounding = 8.0 * len(d) * np.finfo(float).eps * max(1.0, float(np.max(np.abs(B))))
    if lam > rounding:
        return HOLDS, lam, ""
    if lam < -rounding:
        return FAILS, lam, ""
    return INCONCLUSIVE, lam, (f"its smallest eigenvalue is below the rounding of its entries ({rounding:.2g}): "
                               "ill-conditioned in SI numbers (a factorization Gamma, phi out of the device's "
                               "scale, docs/plant-description.md)")


def assumption_1(controller: Controller) -> Check:
    """hess_q H(eta_d) > 0 and R_m > 0."""
    plant, eta_d = controller.plant, controller.target()
    m = plant.n_m
    h = min_eig(plant.hess_H(eta_d)[:m, :m])
    r = min_eig(plant.R_m)
    return Check("Assumption 1", _verdict(h > 0 and r > 0),
                 {"min eig hess_q H(eta_d)": h, "min eig R_m": r}, "at the set-point")


def _gamma_phi_residual(controller: Controller, nb: Neighbourhood) -> float:
    """max over samples of |grad_q H_e + Gamma grad phi| / |grad_q H_e| (eq. assHereg / assHe)."""
    plant = controller.plant
    worst = 0.0
    for eta, _ in nb.samples:
        q, _, x_e = plant.split(eta)
        g = 0.5 * np.einsum("i,kij,j->k", x_e, plant.dPsi(q), x_e)
        res = g + controller.Gamma @ plant.grad_phi(x_e)
        worst = max(worst, float(np.linalg.norm(res) / max(np.linalg.norm(g), 1e-300)))
    return worst


def assumption_2(controller: Controller, nb: Neighbourhood) -> Check:
    """grad_q H_e = -Gamma grad phi on the neighbourhood and hess phi(x_e_d) > 0."""
    plant = controller.plant
    res = _gamma_phi_residual(controller, nb)
    h = min_eig(plant.hess_phi(plant.split(controller.target())[2]))
    return Check("Assumption 2", _verdict(res < 1e-10 and h > 0),
                 {"max rel. residual grad_q H_e + Gamma grad phi": res, "min eig hess phi(x_e_d)": h})


def assumption_3(controller: Controller, nb: Neighbourhood) -> Check:
    """R_m > 0 and alpha I < [[hess_q H, d_q grad_p H], [., M^-1]] < beta I on the neighbourhood (eq. cond1T2)."""
    plant = controller.plant
    m = plant.n_m
    lo, hi = np.inf, -np.inf
    for eta, _ in nb.samples:
        block = plant.hess_H(eta)[:2 * m, :2 * m]
        lo, hi = min(lo, min_eig(block)), max(hi, max_eig(block))
    r = min_eig(plant.R_m)
    return Check("Assumption 3", _verdict(r > 0 and lo > 0),
                 {"min eig R_m": r, "alpha (sampled min eig)": lo, "beta (sampled max eig)": hi})


def assumption_4(controller: Controller, nb: Neighbourhood) -> Check:
    """grad_q H_e = -Gamma grad phi and hess phi(x_e*(t)) > 0 along the reference (eq. assHe)."""
    plant = controller.plant
    res = _gamma_phi_residual(controller, nb)
    jets = {id(j): j for _, j in nb.samples}.values()
    h = min(min_eig(plant.hess_phi(plant.split(controller.target(j))[2])) for j in jets)
    return Check("Assumption 4", _verdict(res < 1e-10 and h > 0),
                 {"max rel. residual grad_q H_e + Gamma grad phi": res, "min eig hess phi(x_e*(t))": h})


# ---- pH condition and Theorem 1 ----------------------------------------------------------------

def ph_condition(controller: Controller) -> Check:
    """eq. (pHcondition); required by Propositions 1 (strictly) and 2, not by Theorems 2 and 3."""
    plant = controller.plant
    margin = closed_loop.ph_margin(plant.R_m, controller.R_e_bar, controller.D_d)
    numbers = {"min eig R_m - D_d^T R_e_bar^-1 D_d / 4": margin}
    bounds = admissible_D_d(controller)
    if bounds is not None:
        numbers["admissible D_d range"] = list(bounds)
        numbers["D_d"] = float(controller.D_d[0, 0])
    required = controller.name in ("Proposition 1", "Proposition 2")
    note = "required" if required else f"not required by {controller.name}: the closed loop need not be pH"
    return Check("pH condition (eq. pHcondition)", _verdict(margin >= 0), numbers, note)


def closed_loop_jacobians(controller: Controller, nb: Neighbourhood) -> list[np.ndarray]:
    F_d = controller.F_d()
    return [F_d @ controller.hess_H_d(eta, jet) for eta, jet in nb.samples]


def theorem1(controller: Controller, nb: Neighbourhood) -> tuple[list[Check], float | None, np.ndarray | None]:
    """Conditions (i)-(iii) of Theorem 1 and, where (iii) holds, the Riccati metric (eq. riccati) and rate."""
    F = controller.F_d()
    eig_F = np.linalg.eigvals(F)
    c1 = Check("Theorem 1 (i): F_d Hurwitz", _verdict(np.max(eig_F.real) < 0),
               {"eigenvalues of F_d": eig_F, "max real part": float(np.max(eig_F.real))})
    hess = [controller.hess_H_d(eta, jet) for eta, jet in nb.samples]
    g1 = min(min_eig(h) for h in hess)
    g2 = max(max_eig(h) for h in hess)
    c2 = Check("Theorem 1 (ii): gamma1 I < hess H_d < gamma2 I", _verdict(g1 > 0),
               {"gamma1 (sampled)": g1, "gamma2 (sampled)": g2, "gamma1/gamma2": g1 / g2}, "sampled bound")
    if not (c1.verdict == HOLDS and g1 > 0):
        return [c1, c2, Check("Theorem 1 (iii): Q of eq. (Eq:N) off the imaginary axis", NOT_APPLICABLE, {},
                              "needs (i) and (ii)")], None, None
    gamma = 1.0 - g1 / g2
    n = F.shape[0]
    best = None
    for eps in np.logspace(-8, 3, 45):
        Q = np.block([[F, gamma * F @ F.T], [-(gamma + eps) * np.eye(n), -F.T]])
        lam, vec = np.linalg.eig(Q)
        if np.min(np.abs(lam.real)) <= 1e-9 * np.linalg.norm(Q, 2):
            continue
        X = vec[:, lam.real < 0]
        Omega = np.real(X[n:] @ np.linalg.inv(X[:n]))
        Omega = 0.5 * (Omega + Omega.T)
        if min_eig(Omega) <= 0:
            continue
        sigma = g2 * eps / max_eig(Omega)       # sigma = beta3 eps lambda_min(omega^-T omega^-1)
        if best is None or sigma > best[0]:
            best = (sigma, eps, Omega)
    if best is None:
        c3 = Check("Theorem 1 (iii): Q of eq. (Eq:N) off the imaginary axis", FAILS,
                   {"gamma": gamma, "eps scanned": [1e-8, 1e3]},
                   "Q has imaginary-axis eigenvalues (or no positive definite Riccati solution) for every eps scanned")
        return [c1, c2, c3], None, None
    sigma, eps, Omega = best
    verified = verified_rate(Omega, closed_loop_jacobians(controller, nb))
    c3 = Check("Theorem 1 (iii): Q of eq. (Eq:N) off the imaginary axis", HOLDS,
               {"gamma": gamma, "eps": eps, "Omega (eq. riccati)": Omega,
                "sigma = gamma2 eps / lambda_max(Omega)": sigma, "rate sigma/2 [1/s]": sigma / 2,
                "rate verified with Omega at the samples [1/s]": verified},
               "the paper's sigma uses lambda_max(omega^-T omega^-1); the bound needs lambda_min "
               "(= 1/lambda_max(Omega)), see docs/derivations.md")
    return [c1, c2, c3], min(sigma / 2, verified), Omega


# ---- the optimal constant contraction metric (Lemma 1): a generalised eigenvalue problem -------

SDP_SOLVER = "CLARABEL"
SDP_TOLERANCES = {"tol_gap_abs": 1e-10, "tol_gap_rel": 1e-10, "tol_feas": 1e-10}   # Clarabel's defaults: 1e-8
RATE_RTOL = 1e-9              # bisection stops when the bracket on lam is this narrow (relative)
MAX_SOLVES = 60


@dataclass
class MetricSolution:
    """The best constant metric over sampled closed-loop Jacobians J_i: the largest lam with
    J_i^T Omega + Omega J_i <= -2 lam Omega for all i (Lemma 1, eq. crate with sigma = 2 lam)."""

    rate: float                  # lam of `metric`, verified by generalised eigenvalues at every sample [1/s]
    metric: np.ndarray           # Omega, in the original coordinates
    upper: float                 # no constant metric contracts faster over the samples [1/s]
    upper_reason: str            # what proves `upper`
    solver: str                  # solver, tolerances and bisection
    statuses: dict               # solver status -> number of solves
    solves: int
    infeasible: dict | None = None   # the verified dual certificate at the smallest infeasible lam tried


def verified_rate(Omega: np.ndarray, jacobians: list[np.ndarray]) -> float:
    """Largest lam with Omega J + J^T Omega <= -2 lam Omega at every sample (generalised eigenvalues)."""
    lam = np.inf
    for J in jacobians:
        S = Omega @ J
        mu = linalg.eigh(-0.5 * (S + S.T), Omega, eigvals_only=True)
        lam = min(lam, float(mu[0]))
    return lam


def modal_basis(J: np.ndarray) -> np.ndarray:
    """Real basis W with W^-1 J W block diagonal: a unit eigenvector per real eigenvalue, and for a pair
    sigma +- i omega the real and imaginary parts of its eigenvector, made orthogonal by its phase.
    In these coordinates J is normal, so the identity metric contracts at -max Re eig J, the best
    rate of any constant metric for J alone."""
    mu, V = np.linalg.eig(J)
    cols, done = [], set()
    for k in np.argsort(-mu.real, kind="stable"):
        if k in done:
            continue
        v = V[:, k]
        if abs(mu[k].imag) <= 1e-12 * abs(mu[k]):
            cols.append(np.real(v) / np.linalg.norm(np.real(v)))
            done.add(k)
            continue
        partner = min((j for j in range(len(mu)) if j != k and j not in done), key=lambda j: abs(mu[j] - mu[k].conjugate()))
        done |= {k, partner}
        v = v * np.exp(-0.5j * np.angle(v @ v))        # v^T v real: Re v orthogonal to Im v
        cols += [v.real / np.linalg.norm(v.real), v.imag / np.linalg.norm(v.imag)]
    return np.column_stack(cols)


def _coordinates(jacobians, scale, nominal):
    """Scaled modal coordinates eta = T y, T = diag(scale) W, and the Jacobians J_y = T^-1 J T.

    diag(scale) makes the states O(1) (the MEMS spans 1e-5 m to 1e-11 C); W (modal_basis of the
    nominal Jacobian) makes the nominal Jacobian block diagonal and normal, so that the optimal
    metric near the nominal point is close to the identity."""
    S = np.diag(scale)
    J0 = np.linalg.solve(S, nominal @ S)
    W = _well_conditioned_modal_basis(J0)
    T = S @ W
    return T, [np.linalg.solve(T, J @ T) for J in jacobians]


def _well_conditioned_modal_basis(J: np.ndarray) -> np.ndarray:
    """modal_basis(J), or the identity where J is (nearly) defective."""
    try:
        W = modal_basis(J)
        if np.linalg.cond(W) < 1e8:
            return W
    except np.linalg.LinAlgError:
        pass
    return np.eye(J.shape[0])


def _congruence(J: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """C and K = C^-1 J C for the LMI of one sample, used as C^T (J^T Omega + Omega J + 2 lam Omega) C <= 0,
    a congruence, which changes no solution: C = W_J D with W_J the modal basis of J and
    D = diag(sqrt(rho / |Re mu_j|)) (rho the smallest |Re mu_j|), so that K is block diagonal and every
    row of the LMI is of the size of the slowest rate. Without it the MEMS electrical pole (6e9 1/s)
    would swamp the mechanical rate (1e2 1/s) below the solver's tolerance."""
    W = _well_conditioned_modal_basis(J)
    L = np.linalg.solve(W, J @ W)
    d = np.abs(np.diag(L))
    rho = max(float(np.min(d)), 1e-12 * float(np.max(d)), 1e-300)
    D = np.sqrt(rho / np.maximum(d, rho))
    return W * D, L * (1.0 / D)[:, None] * D[None, :]


class _GEVP:
    """For a fixed lam: maximise t subject to trace(Omega) = n, Omega >= t I and
    C_i^T (J_i^T Omega + Omega J_i + 2 lam Omega) C_i <= -t I for all i (coordinates of _coordinates,
    congruences of _congruence). t > 0 exactly when a metric with rate lam exists (the LMIs are
    homogeneous in Omega, so the trace only fixes Omega's scale); t < 0 comes with dual multipliers
    Z_i >= 0 proving that none exists."""

    def __init__(self, Jy: list[np.ndarray], solver: str):
        import cvxpy as cp  # imported here: controller FMUs import this module and never solve SDPs
        n = Jy[0].shape[0]
        self.cp, self.solver = cp, solver
        # Omega = sum_k x_k E_k over a basis E_k of the symmetric matrices; x[-1] is t. Each LMI is then
        # one numeric matrix times x (vec, column-major), which cvxpy compiles fast for hundreds of samples.
        basis = []
        for i in range(n):
            for j in range(i, n):
                E = np.zeros((n, n))
                E[i, j] = E[j, i] = 1.0
                basis.append(E)
        identity = np.eye(n)

        def vec(A: np.ndarray) -> np.ndarray:
            return A.reshape(-1, order="F")
        self.basis = basis
        self.x = cp.Variable(len(basis) + 1)
        self.lam = cp.Parameter()
        self.C, self.lmis = [], []
        for J in Jy:
            C, K = _congruence(J)
            self.C.append(C)
            CEC = [C.T @ E @ C for E in basis]
            F = np.column_stack([vec(K.T @ P + P @ K) for P in CEC] + [vec(identity)])
            F_lam = np.column_stack([vec(2.0 * P) for P in CEC] + [np.zeros(n * n)])
            self.lmis.append(cp.reshape(-(F @ self.x) - self.lam * (F_lam @ self.x), (n, n), order="F") >> 0)
        F_Omega = np.column_stack([vec(E) for E in basis] + [-vec(identity)])
        trace = np.array([np.trace(E) for E in basis] + [0.0])
        self.problem = cp.Problem(cp.Maximize(self.x[-1]),
                                  [trace @ self.x == n, cp.reshape(F_Omega @ self.x, (n, n), order="F") >> 0, *self.lmis])

    @property
    def Omega(self) -> np.ndarray | None:
        if self.x.value is None:
            return None
        return sum(v * E for v, E in zip(self.x.value[:-1], self.basis))

    def solve(self, lam: float) -> tuple[str, float | None]:
        self.lam.value = lam
        try:
            kw = SDP_TOLERANCES if self.solver == "CLARABEL" else {}
            with warnings.catch_warnings():           # "may be inaccurate": the status is reported instead
                warnings.simplefilter("ignore", UserWarning)
                self.problem.solve(solver=self.solver, **kw)
        except self.cp.error.SolverError:
            return "solver error", None
        return self.problem.status, None if self.x.value is None else float(self.x.value[-1])

    def multipliers(self) -> list[np.ndarray]:
        """Z_i of the LMIs, mapped through C_i onto J_i^T Omega + Omega J_i + 2 lam Omega."""
        return [C @ np.asarray(c.dual_value) @ C.T for C, c in zip(self.C, self.lmis)]


def infeasibility_margin(jacobians: list[np.ndarray], Z: list[np.ndarray], lam: float) -> tuple[float, float]:
    """The dual certificate that no Omega > 0 has J_i^T Omega + Omega J_i <= -2 lam Omega for all i:
    Z_i >= 0 with G = sum_i (J_i Z_i + Z_i J_i^T + 2 lam Z_i) > 0, since then
    0 < <G, Omega> = sum_i <Z_i, J_i^T Omega + Omega J_i + 2 lam Omega> <= 0 for any such Omega.
    Z_i are first projected onto the PSD cone. Returns (lambda_min(G), rounding bound), both divided
    by trace(G); the certificate holds when the first exceeds the second."""
    Zp = []
    for Zi in Z:
        w, V = np.linalg.eigh(0.5 * (Zi + Zi.T))
        Zp.append((V * np.maximum(w, 0.0)) @ V.T)
    G = sum(J @ Zi + Zi @ J.T + 2 * lam * Zi for J, Zi in zip(jacobians, Zp))
    G = 0.5 * (G + G.T)
    E = sum(np.abs(J) @ np.abs(Zi) * 2 + 2 * abs(lam) * np.abs(Zi) for J, Zi in zip(jacobians, Zp))
    n, eps = G.shape[0], np.finfo(float).eps
    rounding = (n + len(Z) + 2) * eps * np.linalg.norm(E) + n * eps * np.linalg.norm(G)
    tr = float(np.trace(G))
    if not tr > 0:
        return -np.inf, np.inf
    return float(np.min(np.linalg.eigvalsh(G))) / tr, rounding / tr


def optimal_metric(jacobians: list[np.ndarray], scale: np.ndarray, nominal: np.ndarray,
                   rtol: float = RATE_RTOL, solver: str = SDP_SOLVER) -> MetricSolution:
    """The largest lam over constant metrics for the sampled Jacobians, by bisection on lam with LMI
    feasibility (_GEVP) in scaled modal coordinates (_coordinates). The returned rate is the one
    verified by generalised eigenvalues at every sample (in the coordinates eta / scale, a diagonal
    similarity), whatever the solver reported; `upper` is proven by a sample's own eigenvalue or by a
    verified dual certificate."""
    T, Jy = _coordinates(jacobians, scale, nominal)
    S = np.diag(scale)
    Js = [np.linalg.solve(S, J @ S) for J in jacobians]
    W = np.linalg.solve(S, T)                              # eta / scale = W y

    def rate_of(P):                                        # P: metric in y; verified on eta / scale
        Wi = np.linalg.inv(W)
        return verified_rate(Wi.T @ P @ Wi, Js)

    abscissa = [float(np.max(np.linalg.eigvals(J).real)) for J in jacobians]
    k = int(np.argmax(abscissa))
    upper, reason = -abscissa[k], f"sample {k}'s Jacobian has an eigenvalue with real part {abscissa[k]:.6g}"
    n = len(scale)
    best_rate, best_P = rate_of(np.eye(n)), np.eye(n)
    gevp = _GEVP(Jy, solver)
    statuses: dict[str, int] = {}
    infeasible = None
    size = max(abs(upper), 1e-300)
    lo, hi = best_rate, upper

    def probe(lam):
        nonlocal best_rate, best_P, upper, reason, infeasible
        status, t = gevp.solve(lam)
        statuses[status] = statuses.get(status, 0) + 1
        if t is not None and t > 0 and gevp.Omega is not None:
            P = gevp.Omega
            if np.min(np.linalg.eigvalsh(P)) > 0:
                r = rate_of(P)
                if r > best_rate:
                    best_rate, best_P = r, P
            return True
        if t is not None:
            Z = gevp.multipliers()
            margin, rounding = infeasibility_margin(Jy, Z, lam)
            if margin > rounding and lam < upper:
                upper, reason = lam, f"dual certificate at lam = {lam:.8g}"
            if margin > rounding and (infeasible is None or infeasible["lam"] > max(lam, 0.0)):
                # keep the first certificate at lam <= 0 (the probe at 0): it answers "any positive rate?"
                weights = np.array([np.trace(z) for z in Z])
                infeasible = {"lam": lam, "min eig G / trace G": margin, "rounding bound / trace G": rounding,
                              "samples with multipliers": int(np.sum(weights > 1e-6 * np.max(weights))),
                              "heaviest sample": int(np.argmax(weights))}
        return False

    if lo < 0 < hi:                                        # the question that matters first
        if probe(0.0):
            lo = max(lo, 0.0)
        else:
            hi = 0.0
    step = size
    while hi - lo > 8 * size and sum(statuses.values()) < MAX_SOLVES // 2:   # far below: walk down geometrically
        lam = hi - step
        if probe(lam):
            lo = lam
            break
        hi, step = lam, 4 * step
    while hi - lo > rtol * max(abs(lo), abs(hi), size * 1e-3) and sum(statuses.values()) < MAX_SOLVES:
        mid = 0.5 * (lo + hi)
        if probe(mid):
            lo = mid
        else:
            hi = mid
    Wi = np.linalg.inv(T)
    Omega = Wi.T @ best_P @ Wi
    opts = ", ".join(f"{k}={v:g}" for k, v in SDP_TOLERANCES.items()) if solver == "CLARABEL" else "defaults"
    return MetricSolution(best_rate, 0.5 * (Omega + Omega.T), upper, reason,
                          f"{solver} via cvxpy ({opts}); bisection on lam to rtol {rtol:g}", statuses,
                          sum(statuses.values()), infeasible)


def lemma1(controller: Controller, nb: Neighbourhood) -> tuple[Check, MetricSolution]:
    """Lemma 1 with the best constant metric over the neighbourhood's samples."""
    jac = closed_loop_jacobians(controller, nb)
    nominal = controller.F_d() @ controller.hess_H_d(*nb.samples[0])
    sol = optimal_metric(jac, nb.scale, nominal)
    numbers = {"optimal rate lam over the samples [1/s] (sigma = 2 lam)": sol.rate,
               "no constant metric is faster than [1/s]": sol.upper,
               "  because": sol.upper_reason,
               "Omega": sol.metric,
               "cond(Omega)": float(np.linalg.cond(sol.metric)),
               "nominal spectral abscissa [1/s]": float(np.max(np.linalg.eigvals(nominal).real)),
               "solver": sol.solver,
               "solves (status: count)": ", ".join(f"{k}: {v}" for k, v in sorted(sol.statuses.items())) or "none"}
    if sol.rate > 0:
        verdict = HOLDS
        note = ("Omega maximises the rate over constant metrics (SDP); the rate is verified by generalised "
                "eigenvalues at every sample")
    elif sol.upper <= 0:
        verdict = FAILS
        c = sol.infeasible
        if c is not None:
            eta = nb.samples[c["heaviest sample"]][0]
            numbers["infeasibility certificate"] = (
                f"multipliers Z_i >= 0 on {c['samples with multipliers']} of {len(jac)} samples with "
                f"G = sum_i (J_i Z_i + Z_i J_i^T + 2 lam Z_i) >= {c['min eig G / trace G']:.3g} trace(G) I > 0 "
                f"at lam = {c['lam']:.6g} (rounding bound {c['rounding bound / trace G']:.2g} trace(G)), so no "
                f"metric has rate >= {c['lam']:.6g}; "
                f"heaviest at eta = {np.array2string(eta, precision=4)}")
        note = ("no constant metric exists over these samples: eq. (crate) has no solution with sigma > 0 "
                f"({sol.upper_reason}); the best constant metric has rate {sol.rate:.6g} 1/s")
    else:
        verdict = INCONCLUSIVE
        note = "the solver found no metric with a positive rate and no certificate that none exists"
    return Check("Lemma 1: constant contraction metric (eq. crate)", verdict, numbers, note), sol


# ---- the whole certificate ---------------------------------------------------------------------

def certify(controller: Controller, reference: Reference | None = None, horizon: float = 0.0,
            radius: float = 0.1, eta0=None, n_times: int = 21) -> Certificate:
    """Evaluate every condition that applies to `controller` over the stated neighbourhood."""
    nb = neighbourhood(controller, reference, horizon, radius, eta0, n_times)
    cert = Certificate(controller.name, {"description": nb.description, "half_widths": nb.radius,
                                         "n_samples": len(nb.samples), "times": nb.times})
    applies = {"Proposition 1": "Assumption 1", "Proposition 2": "Assumption 2",
               "Theorem 2": "Assumption 3", "Theorem 3": "Assumption 4"}[controller.name]
    makers = {"Assumption 1": lambda: assumption_1(controller), "Assumption 2": lambda: assumption_2(controller, nb),
              "Assumption 3": lambda: assumption_3(controller, nb), "Assumption 4": lambda: assumption_4(controller, nb)}
    for name, make in makers.items():
        cert.checks.append(make() if name == applies else
                           Check(name, NOT_APPLICABLE, {}, f"{controller.name} rests on {applies}"))
    cert.checks.append(ph_condition(controller))
    t1_checks, t1_rate, t1_metric = theorem1(controller, nb)
    cert.checks += t1_checks
    l1, sol = lemma1(controller, nb)
    cert.checks.append(l1)
    cert.rate_upper = sol.upper
    options = [(r, m) for r, m in ((t1_rate, t1_metric), (sol.rate, sol.metric)) if r is not None and r > 0]
    if options:
        cert.rate, metric = max(options, key=lambda o: o[0])
        cert.metric = metric.tolist()
    return cert


def theorem1_conditions(controller: Controller, reference: Reference | None = None, horizon: float = 0.0,
                        radius: float = 0.1) -> list[Check]:
    """Conditions (i)-(iii) of Theorem 1 ("holds through appropriate selection of the gains") checked by
    numbers over the neighbourhood of `neighbourhood`: three Checks with verdicts and the numbers behind them."""
    return theorem1(controller, neighbourhood(controller, reference, horizon, radius))[0]


def contraction_rate(controller: Controller, reference: Reference | None = None, horizon: float = 0.0,
                     radius: float = 0.1, eta0=None) -> MetricSolution:
    """The optimal constant contraction metric (Lemma 1) over the neighbourhood: its verified rate [1/s],
    Omega, the proven upper bound and, where no metric exists, the dual certificate."""
    nb = neighbourhood(controller, reference, horizon, radius, eta0)
    return lemma1(controller, nb)[1]


def admissible_D_d(controller: Controller) -> tuple[float, float] | None:
    """(-b, b) with b = sqrt(4 R_m R_e_bar): the D_d allowed by the pH condition (eq. pHcondition) for a
    one-degree-of-freedom loop (None otherwise: the condition is a matrix inequality, see ph_condition)."""
    plant = controller.plant
    if plant.n_m != 1 or plant.n_e != 1:
        return None
    b = closed_loop.scalar_D_d_bound(plant.R_m[0, 0], 0.5 * (controller.R_e_bar + controller.R_e_bar.T)[0, 0])
    return -b, b


def decay_bound_holds(Omega: np.ndarray, rate: float, t: np.ndarray, error: np.ndarray, slack: float = 1e-6) -> bool:
    """The certificate's promise on a simulated error e(t) = eta - eta*: |e(t)|_Omega <= exp(-rate t) |e(0)|_Omega."""
    norms = np.sqrt(np.einsum("ti,ij,tj->t", error, Omega, error))
    return bool(np.all(norms <= np.exp(-rate * (t - t[0])) * norms[0] * (1 + slack) + 1e-300))


# ---- the design alone: what a controller FMU checks at initialization ---------------------------

class DesignConditionWarning(UserWarning):
    """A controller's parameters violate a condition of its proposition or theorem and it runs anyway (strict = 0)."""


def violated(controller: Controller, jet=None) -> list[Check]:
    """The design checks (design_checks) that fail at the target: what strict = 1 refuses, strict = 0 warns of."""
    return [c for c in design_checks(controller, jet) if c.verdict == FAILS]


def violation_text(owner: str, controller: Controller, failed: list[Check], strict: int) -> str:
    """The one wording of failed design checks, for the controller FMU's initialization (fmus/controller.py) and
    `plant scenario` alike: refused with strict = 1, "running anyway" with strict = 0."""
    text = (f"{owner}: the parameters violate {controller.name}'s conditions: "
            + "; ".join(f"{c.name} ({', '.join(f'{k} = {v:.4g}' for k, v in c.numbers.items())})"
                        + (f" [{c.note}]" if c.note else "") for c in failed))
    return text + (" (strict = 1)" if strict else "; running anyway (strict = 0)")


def design_checks(controller: Controller, jet=None) -> list[Check]:
    """The conditions of the controller's proposition or theorem that its parameters decide alone,
    at the target (eta_d, or eta*(t) of `jet`): cheap enough for an FMU's initialization.

    Proposition 1: Assumption 1, K_e >= 0, eq. (phi12) (hess H_d(eta_d) > 0); the strict pH
    condition is enforced when the controller is built. Proposition 2: hess phi(x_e_d) > 0
    (Assumption 2), K_e >= 0, eq. (Phic22) (hess H_d(eta_d) > 0). Theorem 2: R_m > 0 (Assumption 3),
    K_e >= 0, Theorem 1 (i). Theorem 3: K_e > 0, hess phi(x_e*) > 0 (Assumption 4), Theorem 1 (i).
    Theorem 1 (ii), (iii) and contraction rates need a neighbourhood of the reference over a horizon:
    `certify` (emcosim certify) evaluates them.
    """
    plant, name = controller.plant, controller.name
    k_e = min_eig(controller.K_e)
    checks = []
    if name == "Proposition 1":
        checks.append(assumption_1(controller))
    if name in ("Proposition 1", "Proposition 2"):
        verdict, h, note = definiteness(controller.hess_H_d(controller.target()))
        label = "eq. (phi12)" if name == "Proposition 1" else "eq. (Phic22)"
        checks.append(Check(f"{label}: hess H_d(eta_d) > 0", verdict,
                            {"min eig of hess H_d(eta_d) scaled to a unit diagonal": h}, note))
    if name == "Theorem 2":
        r = min_eig(plant.R_m)
        checks.append(Check("Assumption 3: R_m > 0", _verdict(r > 0), {"min eig R_m": r}))
    if name in ("Proposition 2", "Theorem 3"):
        which = "Assumption 2: hess phi(x_e_d) > 0" if name == "Proposition 2" else "Assumption 4: hess phi(x_e*) > 0"
        if controller.tracking and jet is None:
            checks.append(Check(which, NOT_APPLICABLE, {}, "no reference given"))
        else:
            x_e = plant.split(controller.target(jet) if controller.tracking else controller.target())[2]
            h = min_eig(plant.hess_phi(x_e))
            checks.append(Check(which, _verdict(h > 0), {"min eig hess phi": h}))
    strict_k = name == "Theorem 3"
    checks.append(Check(f"K_e = R_e_bar - R_e {'>' if strict_k else '>='} 0 ({name})",
                        _verdict(k_e > 0 if strict_k else k_e >= 0), {"min eig K_e": k_e},
                        "the closed loop itself only needs R_e_bar > 0 (erratum 4)" if strict_k else ""))
    if name in ("Theorem 2", "Theorem 3"):
        eig = np.linalg.eigvals(controller.F_d())
        checks.append(Check("Theorem 1 (i): F_d Hurwitz", _verdict(np.max(eig.real) < 0),
                            {"max real part of eig F_d": float(np.max(eig.real))}))
    return checks
