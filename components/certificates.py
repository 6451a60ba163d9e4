"""Certificates of a controller design: the assumptions, the pH condition, Theorem 1's conditions and
contraction rates (Sections 2, 4, 5, 6 of the paper).

Everything is evaluated over a stated neighbourhood of the target: a tube around eta*(t) (or the box
around eta_d) with half-widths `radius` per state, covered by samples (times x box vertices, centre and
random points). Bounds over the neighbourhood are therefore *sampled*, not rigorous between samples;
the report says so.

Rates: a contraction metric Omega > 0 with Omega J + J^T Omega <= -2 lam Omega at every sample,
J = F_d hess H_d(eta, t) the closed-loop Jacobian, makes distances in the metric decay like
exp(-lam t) (Lemma 1, eq. crate, with sigma = 2 lam). Every reported rate is the value verified by
exact generalised eigenvalues at every sample, whatever method proposed the metric.
"""
from __future__ import annotations

import json
from dataclasses import asdict, dataclass, field
from itertools import product

import numpy as np
from scipy import linalg, optimize

from . import closed_loop
from .controller import Controller
from .references import Reference

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
        lines.append(f"  certified rate: {'none' if self.rate is None else f'{self.rate:.6g} 1/s'}")
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
    if isinstance(v, (float, np.floating)):
        return f"{v:.6g}"
    if isinstance(v, (list, tuple, np.ndarray)):
        a = np.asarray(v)
        if np.iscomplexobj(a):
            return "[" + ", ".join(f"{z.real:.4g}{z.imag:+.4g}j" for z in a.ravel()) + "]"
        return np.array2string(a, precision=4)
    return str(v)


# ---- the neighbourhood -------------------------------------------------------------------------

@dataclass
class Neighbourhood:
    """Samples (eta, jet) of the tube {eta*(t) + d : |d_i| <= radius_i, t in [0, horizon]}."""

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


def neighbourhood(controller: Controller, reference: Reference | None = None, horizon: float = 0.0,
                  radius: float = 0.1, eta0=None, n_times: int = 21, n_random: int = 8,
                  seed: int = 0) -> Neighbourhood:
    """The tube of relative half-width `radius` (times each state's scale) around the target; if eta0
    is given the half-widths grow to contain it, so the certificate covers the start of the run."""
    times = np.linspace(0.0, horizon, n_times) if (reference is not None and horizon > 0) else np.array([0.0])
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
    what = "set-point eta_d" if len(times) == 1 else f"reference eta*(t), t in [0, {horizon:g}] s ({len(times)} times)"
    desc = (f"box around the {what} with half-widths {np.array2string(half, precision=3)} "
            f"(state scales {np.array2string(scale, precision=3)}); {len(samples)} samples "
            f"(centre, {2 ** n} vertices, {n_random} random points per time; outside-domain points dropped); "
            "bounds are sampled, not rigorous between samples")
    return Neighbourhood(samples, times, half, scale, desc)


# ---- assumptions -------------------------------------------------------------------------------

def _min_eig(A: np.ndarray) -> float:
    return float(np.min(np.linalg.eigvalsh(0.5 * (A + A.T))))


def _max_eig(A: np.ndarray) -> float:
    return float(np.max(np.linalg.eigvalsh(0.5 * (A + A.T))))


def _verdict(ok: bool) -> str:
    return HOLDS if ok else FAILS


def assumption_1(controller: Controller) -> Check:
    """hess_q H(eta_d) > 0 and R_m > 0."""
    plant, eta_d = controller.plant, controller.target()
    m = plant.n_m
    h = _min_eig(plant.hess_H(eta_d)[:m, :m])
    r = _min_eig(plant.R_m)
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
    h = _min_eig(plant.hess_phi(plant.split(controller.target())[2]))
    return Check("Assumption 2", _verdict(res < 1e-10 and h > 0),
                 {"max rel. residual grad_q H_e + Gamma grad phi": res, "min eig hess phi(x_e_d)": h})


def assumption_3(controller: Controller, nb: Neighbourhood) -> Check:
    """R_m > 0 and alpha I < [[hess_q H, d_q grad_p H], [., M^-1]] < beta I on the neighbourhood (eq. cond1T2)."""
    plant = controller.plant
    m = plant.n_m
    lo, hi = np.inf, -np.inf
    for eta, _ in nb.samples:
        block = plant.hess_H(eta)[:2 * m, :2 * m]
        lo, hi = min(lo, _min_eig(block)), max(hi, _max_eig(block))
    r = _min_eig(plant.R_m)
    return Check("Assumption 3", _verdict(r > 0 and lo > 0),
                 {"min eig R_m": r, "alpha (sampled min eig)": lo, "beta (sampled max eig)": hi})


def assumption_4(controller: Controller, nb: Neighbourhood) -> Check:
    """grad_q H_e = -Gamma grad phi and hess phi(x_e*(t)) > 0 along the reference (eq. assHe)."""
    plant = controller.plant
    res = _gamma_phi_residual(controller, nb)
    jets = {id(j): j for _, j in nb.samples}.values()
    h = min(_min_eig(plant.hess_phi(plant.split(controller.target(j))[2])) for j in jets)
    return Check("Assumption 4", _verdict(res < 1e-10 and h > 0),
                 {"max rel. residual grad_q H_e + Gamma grad phi": res, "min eig hess phi(x_e*(t))": h})


# ---- pH condition and Theorem 1 ----------------------------------------------------------------

def ph_condition(controller: Controller) -> Check:
    """eq. (pHcondition); required by Propositions 1 (strictly) and 2, not by Theorems 2 and 3."""
    plant = controller.plant
    margin = closed_loop.ph_margin(plant.R_m, controller.R_e_bar, controller.D_d)
    numbers = {"min eig R_m - D_d^T R_e_bar^-1 D_d / 4": margin}
    if plant.n_m == 1 and plant.n_e == 1:
        bound = closed_loop.scalar_D_d_bound(plant.R_m[0, 0], 0.5 * (controller.R_e_bar + controller.R_e_bar.T)[0, 0])
        numbers["admissible D_d range"] = [-bound, bound]
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
    g1 = min(_min_eig(h) for h in hess)
    g2 = max(_max_eig(h) for h in hess)
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
        if _min_eig(Omega) <= 0:
            continue
        sigma = g2 * eps / _max_eig(Omega)       # sigma = beta3 eps lambda_min(omega^-T omega^-1)
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


# ---- contraction metric search (Lemma 1) -------------------------------------------------------

def verified_rate(Omega: np.ndarray, jacobians: list[np.ndarray]) -> float:
    """Largest lam with Omega J + J^T Omega <= -2 lam Omega at every sample (generalised eigenvalues)."""
    lam = np.inf
    for J in jacobians:
        S = Omega @ J
        mu = linalg.eigh(-0.5 * (S + S.T), Omega, eigvals_only=True)
        lam = min(lam, float(mu[0]))
    return lam


def _eigen_metric(J: np.ndarray) -> np.ndarray:
    """(V^-1)^H V^-1 for J = V Lambda V^-1: the metric in which the linear flow of J contracts at -max Re(eig J)."""
    _, V = np.linalg.eig(J)
    Vi = np.linalg.inv(V)
    Omega = np.real(Vi.conj().T @ Vi)
    return 0.5 * (Omega + Omega.T)


def search_metric(jacobians: list[np.ndarray], scale: np.ndarray, nominal: np.ndarray,
                  refine: bool = True) -> tuple[float, np.ndarray]:
    """A constant metric maximising the verified rate: candidates from the nominal Jacobian (eigen-metric,
    shifted Lyapunov metrics), then local refinement (Nelder-Mead on a log-Cholesky factor) in scaled
    coordinates xi = eta / scale. Returns (rate, Omega) in the original coordinates."""
    S = np.diag(scale)
    Si = np.diag(1.0 / scale)
    Js = [Si @ J @ S for J in jacobians]
    J0 = Si @ nominal @ S
    n = J0.shape[0]
    alpha = -np.max(np.linalg.eigvals(J0).real)            # nominal decay rate
    candidates = [np.eye(n), _eigen_metric(J0)]
    if alpha > 0:
        for f in (0.5, 0.9, 0.99):
            A = J0 + f * alpha * np.eye(n)
            try:
                P = linalg.solve_continuous_lyapunov(A.T, -np.eye(n))
                candidates.append(0.5 * (P + P.T))
            except (linalg.LinAlgError, ValueError):
                pass
    scored = []
    for P in candidates:
        if np.all(np.isfinite(P)) and _min_eig(P) > 0:
            P = P / _max_eig(P)
            scored.append((verified_rate(P, Js), P))
    rate, P = max(scored, key=lambda s: s[0])
    if refine:
        L0 = np.linalg.cholesky(P)
        idx = np.tril_indices(n)

        def unpack(x):
            L = np.zeros((n, n))
            L[idx] = x
            L[np.diag_indices(n)] = np.exp(np.diag(L))
            return L @ L.T

        x0 = L0[idx].copy()
        d = np.diag_indices(n)
        L0log = L0.copy()
        L0log[d] = np.log(np.diag(L0))
        x0 = L0log[idx]
        res = optimize.minimize(lambda x: -verified_rate(unpack(x), Js), x0, method="Nelder-Mead",
                                options={"maxiter": 400 * len(x0), "xatol": 1e-10, "fatol": 1e-12 * max(abs(rate), 1e-300)})
        P_ref = unpack(res.x)
        r_ref = verified_rate(P_ref, Js)
        if r_ref > rate:
            rate, P = r_ref, P_ref
    Omega = Si @ P @ Si
    return rate, Omega


def lemma1(controller: Controller, nb: Neighbourhood, refine: bool = True) -> tuple[Check, float, np.ndarray]:
    jac = closed_loop_jacobians(controller, nb)
    nominal = controller.F_d() @ controller.hess_H_d(*nb.samples[0])
    rate, Omega = search_metric(jac, nb.scale, nominal, refine)
    verdict = HOLDS if rate > 0 else INCONCLUSIVE
    return Check("Lemma 1: constant contraction metric (eq. crate)", verdict,
                 {"rate lam [1/s] (sigma = 2 lam)": rate, "Omega": Omega,
                  "nominal spectral abscissa [1/s]": float(np.max(np.linalg.eigvals(nominal).real))},
                 "metric searched directly (eigen-/Lyapunov candidates, local refinement), rate verified by "
                 "generalised eigenvalues at every sample; no constant metric can beat the nominal decay rate"), rate, Omega


# ---- the whole certificate ---------------------------------------------------------------------

def certify(controller: Controller, reference: Reference | None = None, horizon: float = 0.0,
            radius: float = 0.1, eta0=None, n_times: int = 21, refine: bool = True) -> Certificate:
    """Evaluate every condition that applies to `controller` over the stated neighbourhood."""
    nb = neighbourhood(controller, reference, horizon, radius, eta0, n_times)
    cert = Certificate(controller.name, {"description": nb.description, "half_widths": nb.radius,
                                         "n_samples": len(nb.samples)})
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
    l1, l1_rate, l1_metric = lemma1(controller, nb, refine)
    cert.checks.append(l1)
    options = [(r, m) for r, m in ((t1_rate, t1_metric), (l1_rate, l1_metric)) if r is not None and r > 0]
    if options:
        cert.rate, metric = max(options, key=lambda o: o[0])
        cert.metric = metric.tolist()
    return cert


def decay_bound_holds(Omega: np.ndarray, rate: float, t: np.ndarray, error: np.ndarray, slack: float = 1e-6) -> bool:
    """The certificate's promise on a simulated error e(t) = eta - eta*: |e(t)|_Omega <= exp(-rate t) |e(0)|_Omega."""
    norms = np.sqrt(np.einsum("ti,ij,tj->t", error, Omega, error))
    return bool(np.all(norms <= np.exp(-rate * (t - t[0])) * norms[0] * (1 + slack) + 1e-300))


# ---- the design alone: what a controller FMU checks at initialization ---------------------------

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
    k_e = _min_eig(controller.K_e)
    checks = []
    if name == "Proposition 1":
        checks.append(assumption_1(controller))
    if name in ("Proposition 1", "Proposition 2"):
        h = _min_eig(controller.hess_H_d(controller.target()))
        label = "eq. (phi12)" if name == "Proposition 1" else "eq. (Phic22)"
        checks.append(Check(f"{label}: hess H_d(eta_d) > 0", _verdict(h > 0), {"min eig hess H_d(eta_d)": h}))
    if name == "Theorem 2":
        r = _min_eig(plant.R_m)
        checks.append(Check("Assumption 3: R_m > 0", _verdict(r > 0), {"min eig R_m": r}))
    if name in ("Proposition 2", "Theorem 3"):
        which = "Assumption 2: hess phi(x_e_d) > 0" if name == "Proposition 2" else "Assumption 4: hess phi(x_e*) > 0"
        if controller.tracking and jet is None:
            checks.append(Check(which, NOT_APPLICABLE, {}, "no reference given"))
        else:
            x_e = plant.split(controller.target(jet) if controller.tracking else controller.target())[2]
            h = _min_eig(plant.hess_phi(x_e))
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
