"""Which of the paper's designs apply to a plant description, and why (issue 25, `emcosim plant check`).

For a `components.description.Description` (eq. open-loop elecmech with H_e = x_e^T Psi(q) x_e / 2) the
check reports

- the set-point q_d: assignable, i.e. in the set E of Section 3 (a real x_e_d with grad_q H(q_d, 0, x_e_d) = 0
  inside the domain);
- a reference q*(t): feasible (Definition 1: x_e*(t) exists at the sampled times and q*(t) stays in the domain);
- Assumptions 1-4 (eqs. ass:class1, assHereg, cond1T2, assHe), each as a list of tests with a verdict
  "holds" / "fails" / "not decided" and the method that decided it: symbolic (sympy, for every admissible
  parameter value under the parameters' conditions), exact at the parameter values (sympy numbers), or
  numeric over a stated box (samples; not rigorous between samples);
- which of Proposition 1/2 and Theorem 2/3 apply (each needs its assumption) and, if not, the failing
  condition. `Report.designs` lists those that apply for `components.codegen.device`.

The formulas are the paper's definitions evaluated on the description's sympy objects; the numeric checks of a
built controller stay in components.certificates (whose eigenvalue helpers and verdict names are reused here).
docs/plant-check.md explains how to read the report.
"""
from __future__ import annotations

import json
import math
from dataclasses import asdict, dataclass, field
from itertools import product
from typing import Any, Callable, Mapping, Sequence

import numpy as np
import sympy
from scipy import optimize

from .bounded import time_limit
from .certificates import FAILS, HOLDS, max_eig, min_eig, reference_period
from .device import DESIGNS
from .ph_plant import Jet
from .references import Constant, Reference, Sinusoid, SmoothStep

NOT_DECIDED = "not decided"
NOT_FINITE = "not finite"          # the start of the reason where a number of a numeric test overflowed
ASSUMPTION_OF = {"Proposition1": "Assumption 1", "Proposition2": "Assumption 2",
                 "Theorem2": "Assumption 3", "Theorem3": "Assumption 4"}
NO_OPERATING_POINT = "no operating point"   # how missing_operating_point's reason starts
TIMES = 21          # sampled times of a reference
SAMPLES = 32        # random points per sampled time in the box (besides its centre and vertices)
RADIUS = 0.1        # default box: half-width RADIUS x the state's scale around eta*(t)
SOLVE_STARTS = 24   # starts of the numeric solve for x_e when dPsi/dq_k are not all diagonal

JetFunction = Callable[[float], Jet]


# ---- the report ------------------------------------------------------------------------------------

@dataclass
class Test:
    """One condition with its verdict, how it was decided and the numbers behind it."""

    condition: str
    verdict: str
    method: str
    detail: str = ""


@dataclass
class Verdict:
    """An assumption (or the set-point / reference question): its tests; the verdict combines them."""

    name: str
    tests: list[Test] = field(default_factory=list)

    @property
    def verdict(self) -> str:
        verdicts = [t.verdict for t in self.tests]
        if FAILS in verdicts:
            return FAILS
        if verdicts and all(v == HOLDS for v in verdicts):
            return HOLDS
        return NOT_DECIDED

    def failing(self) -> list[Test]:
        return [t for t in self.tests if t.verdict == FAILS] or [t for t in self.tests if t.verdict != HOLDS]


@dataclass
class DesignVerdict:
    name: str
    applies: bool
    reason: str
    start: str = ""
    """What the design commands at the scenario's initial state and its fastest rate (emcosim.devices.start)."""
    exceeds_actuator: bool = False
    """Its start input leaves the description's actuator range ([model] u_max)."""

    @property
    def status(self) -> str:
        if not self.applies:
            return "does not apply"
        return "applies, but exceeds the actuator" if self.exceeds_actuator else "applies"


@dataclass
class Report:
    plant: str
    source: str
    parameters: dict[str, float]
    q_d: list[float] | None
    x_e_d: list[float] | None
    setpoint: Verdict
    reference: Verdict | None
    assumptions: list[Verdict]
    design_verdicts: list[DesignVerdict]
    box: str
    operating_point: str = ""
    """n_e > n_m: the rule that fixed the free electrical coordinates at every point tested."""

    @property
    def designs(self) -> list[str]:
        """The designs that apply ("Proposition1", ...), for components.codegen.device(desc, designs)."""
        return [d.name for d in self.design_verdicts if d.applies]

    def not_applicable(self) -> list[str]:
        """"<design>: <why>" for each design that does not apply (what `emcosim plant build` does not build)."""
        return [f"{d.name}: {d.reason}" for d in self.design_verdicts if not d.applies]

    def assumption(self, number: int) -> Verdict:
        return self.assumptions[number - 1]

    def to_dict(self) -> dict[str, Any]:
        def verdict(v: Verdict | None) -> dict | None:
            return None if v is None else {"name": v.name, "verdict": v.verdict, "tests": [asdict(t) for t in v.tests]}
        return {"plant": self.plant, "source": self.source, "parameters": self.parameters, "q_d": self.q_d,
                "x_e_d": self.x_e_d, "box": self.box, "setpoint": verdict(self.setpoint),
                "reference": verdict(self.reference), "assumptions": [verdict(a) for a in self.assumptions],
                "designs": [{**asdict(d), "status": d.status} for d in self.design_verdicts], "applies": self.designs,
                "operating_point": self.operating_point}

    def to_json(self) -> str:
        return json.dumps(self.to_dict(), indent=2)

    def text(self) -> str:
        lines = [f"Plant check: {self.plant} ({self.source})",
                 "  parameters: " + ", ".join(f"{k} = {v:.6g}" for k, v in self.parameters.items()),
                 f"  numeric checks: {self.box}"]
        if self.operating_point:
            tested = ("no design can be built" if self.operating_point.startswith(NO_OPERATING_POINT)
                      else "Assumptions 1-4 are tested there")
            lines.append(f"  operating point (n_e > n_m): {self.operating_point}; {tested}")
        for v in [self.setpoint, self.reference, *self.assumptions]:
            if v is None:
                continue
            lines.append(f"{v.name}: {v.verdict}")
            for t in v.tests:
                detail = f"; {t.detail}" if t.detail else ""
                lines.append(f"  [{t.verdict:>11}] {t.condition} -- {t.method}{detail}")
        lines.append("Designs:")
        for d in self.design_verdicts:
            lines.append(f"  {d.name:<12} {d.status}: {d.reason}")
            if d.start:
                lines.append(f"  {'':<12} {d.start}")
        return "\n".join(lines)


# ---- exact arithmetic helpers ----------------------------------------------------------------------

def exact(value: float) -> sympy.Rational:
    """The float as the exact decimal it prints as (0.64042 -> 32021/50000)."""
    return sympy.Rational(repr(float(value)))


def positive_definite(A: sympy.Matrix, stopped: list[str] | None = None) -> bool | None:
    """Sylvester's criterion: True when sympy proves every leading principal minor > 0, False when one is
    proven <= 0, None when sympy cannot decide (or not within SYMBOLIC_SECONDS: then `stopped` gets a note)."""
    from .description import SYMBOLIC_SECONDS

    decided: list[bool | None] = []
    with time_limit(SYMBOLIC_SECONDS) as limit:
        for k in range(1, A.shape[0] + 1):
            minor = sympy.simplify(A[:k, :k].det())
            positive = minor.is_positive
            if positive is False:
                return False
            decided.append(positive)
    if limit.expired:
        if stopped is not None:
            stopped.append(f"; the symbolic check stopped at its time limit of {SYMBOLIC_SECONDS:g} s (SYMBOLIC_SECONDS)")
        return None
    return True if all(d is True for d in decided) else None


def _is_zero(e: sympy.Expr) -> bool:
    """e == 0 identically; ValueError if sympy cannot tell within SYMBOLIC_SECONDS."""
    from .description import SYMBOLIC_SECONDS

    if e == 0:
        return True
    result = False
    with time_limit(SYMBOLIC_SECONDS) as limit:
        result = sympy.simplify(e) == 0
    if limit.expired:
        raise ValueError(f"the symbolic identity check of {str(e)[:80]} = 0 took longer than {SYMBOLIC_SECONDS:g} s "
                         "(SYMBOLIC_SECONDS); simplify the description's expressions")
    return result


def _numbers(values: Any) -> str:
    return "(" + ", ".join(f"{float(v):.6g}" for v in values) + ")"


# ---- the model of a description --------------------------------------------------------------------

class Model:
    """The description's functions: symbolic (sympy) and numeric at the parameter values."""

    def __init__(self, desc: Any, parameters: Mapping[str, float] | None = None):
        self.desc = desc
        given = dict(parameters or {})
        unknown = set(given) - set(desc.parameters)
        if unknown:
            raise ValueError(f"{desc.source}: unknown parameter(s) {sorted(unknown)}; known: {list(desc.parameters)}")
        self.values = {n: desc.parameters[n].check(given.get(n, p.default), desc.name) for n, p in desc.parameters.items()}
        self.exact_values = {s: exact(self.values[s.name]) for s in desc.parameter_symbols}
        for entry in ("M", "V", "Psi", "R_m", "J_e", "R_e", "G_e"):
            at = self.at_values(getattr(desc, entry))
            if at.has(sympy.zoo, sympy.nan, sympy.oo, sympy.I):
                raise ValueError(f"{desc.source}: [model] {entry}: not finite at the parameter values "
                                 f"{self.values} (a pole?): {at}")
        self.q, self.p, self.x = desc.q_symbols, desc.p_symbols, desc.x_e_symbols
        self.n_m, self.n_e = len(self.q), len(self.x)
        xv = sympy.Matrix(self.x)
        self.H_e = (xv.T * desc.Psi * xv)[0, 0] / 2                                    # eq. (elec energy)
        self.grad_q_H_e = sympy.Matrix([sympy.diff(self.H_e, qk) for qk in self.q])
        self.grad_V = sympy.Matrix([sympy.diff(desc.V, qk) for qk in self.q])
        self.dPsi = [desc.Psi.diff(qk) for qk in self.q]
        self.diagonal = all(_is_zero(D[i, j]) for D in self.dPsi for i in range(self.n_e) for j in range(self.n_e)
                            if i != j)
        # grad_q H_e = A(q) w with w_i = x_e_i^2 when every dPsi/dq_k is diagonal
        self.A = sympy.Matrix(self.n_m, self.n_e, lambda k, i: self.dPsi[k][i, i] / 2)
        self.sign = float(getattr(desc, "x_e_sign", 1.0))
        self._numeric: dict[str, Callable] = {}

    def at_values(self, e: Any) -> Any:
        """An expression or matrix at the exact parameter values."""
        return e.subs(self.exact_values)

    def numeric(self, key: str, e: Any, args: Sequence[sympy.Symbol]) -> Callable:
        if key not in self._numeric:
            self._numeric[key] = sympy.lambdify(args, self.at_values(e), "numpy")
        return self._numeric[key]

    # ---- the domain ----
    def domain_margins(self, q: Any) -> np.ndarray:
        f = self.numeric("domain", sympy.Matrix(list(self.desc.domain_margins) or [1]), self.q)
        return np.asarray(f(*q), dtype=float).ravel()

    def in_domain(self, q: Any) -> bool:
        return bool(np.all(self.domain_margins(q) > 0))

    # ---- the force balance of the p-row of eq. (open-loop elecmech) ----
    def required_force(self, q: np.ndarray, qd: np.ndarray, qdd: np.ndarray) -> np.ndarray:
        """b with grad_q H_e(q*, x_e*) = b along a reference, from the p-row of eq. (open-loop elecmech):
        p* = M q*', p*' = -grad V - grad_q(p^T M^-1 p / 2) - grad_q H_e - R_m q*'."""
        if "force" not in self._numeric:
            qd_s = sympy.symbols(f"_qd0:{self.n_m}", real=True)
            qdd_s = sympy.symbols(f"_qdd0:{self.n_m}", real=True)
            M, Mi = self.desc.M, self.desc.M.inv()
            pv = sympy.Matrix(self.p)
            T = (pv.T * Mi * pv)[0, 0] / 2
            grad_T = sympy.Matrix([sympy.diff(T, qk) for qk in self.q])
            p_star = M * sympy.Matrix(qd_s)
            dM_dt = sum((M.diff(qk) * v for qk, v in zip(self.q, qd_s)), sympy.zeros(self.n_m, self.n_m))
            p_dot = M * sympy.Matrix(qdd_s) + dM_dt * sympy.Matrix(qd_s)
            b = -(p_dot + self.desc.R_m * sympy.Matrix(qd_s) + self.grad_V
                  + grad_T.subs(dict(zip(self.p, p_star))))
            self.numeric("force", b, (*self.q, *qd_s, *qdd_s))
        return np.asarray(self._numeric["force"](*q, *qd, *qdd), dtype=float).ravel()

    def momentum(self, q: np.ndarray, qd: np.ndarray) -> np.ndarray:
        return np.asarray(self.numeric("M", self.desc.M, self.q)(*q), dtype=float) @ qd

    def electrical_state(self, q: np.ndarray, b: np.ndarray) -> tuple[np.ndarray | None, str]:
        """A real x_e with grad_q H_e(q, x_e) = b, numerically; (None, why) if there is none (or none was found);
        (None, NOT_FINITE + why) where the numbers are not finite (overflow): no verdict from them."""
        if not np.all(np.isfinite(b)) or not np.all(np.isfinite(q)):
            return None, f"{NOT_FINITE}: the required force {_numbers(b)} at q = {_numbers(q)}"
        if self.diagonal:
            A = np.asarray(self.numeric("A", self.A, self.q)(*q), dtype=float).reshape(self.n_m, self.n_e)
            if self.n_e > self.n_m and self.psi_diagonal:       # the operating-point rule (n_e > n_m)
                x, branch, how = self.rule_state(q, A, b)
                if x is None:
                    return None, how
                return x, how
            if self.n_m == self.n_e and np.linalg.cond(A) < 1e12:
                w = np.linalg.solve(A, b)
                how = "x_e_i^2 = w_i from the linear system A(q) w = b (A_ki = dPsi_ii/dq_k / 2)"
            else:                                    # n_e < n_m: overdetermined
                tol = 1e-9 * max(float(np.linalg.norm(b)), 1e-300)
                w = np.linalg.lstsq(A, b, rcond=None)[0]
                how = "x_e_i^2 = w_i, the minimum-norm w > 0 solving A(q) w = b (not unique: n_e != n_m)"
                if not (np.all(w > 0) and np.linalg.norm(A @ w - b) <= tol):
                    w, res = optimize.nnls(A, b)
                    if res > tol:
                        return None, f"no w = x_e^2 >= 0 solves A(q) w = b (nnls residual {res:.3g})"
                    how = "x_e_i^2 = w_i >= 0 from nnls on A(q) w = b (not unique: n_e != n_m)"
            if not np.all(np.isfinite(w)):
                return None, f"{NOT_FINITE}: x_e^2 = w = {_numbers(w)} (A(q) = {_numbers(A.ravel())})"
            if np.any(w < 0):
                return None, f"x_e^2 = w = {_numbers(w)} has a negative entry: no real x_e"
            return self.sign * np.sqrt(w), how
        return self._electrical_state_search(q, b)

    @property
    def rule(self) -> Any:
        """The description's operating-point rule (n_e > n_m), or the default least electrical energy."""
        from .operating_point import Rule
        return getattr(self.desc, "operating_point", None) or Rule(given=False)

    @property
    def psi_diagonal(self) -> bool:
        Psi = self.desc.Psi
        return all(_is_zero(Psi[i, j]) for i in range(self.n_e) for j in range(self.n_e) if i != j)

    def rule_state(self, q: np.ndarray, A: np.ndarray, b: np.ndarray) -> tuple[np.ndarray | None, tuple, str]:
        """x_e with A(q) x_e^2 = b by the operating-point rule (components.operating_point): (x_e, branch, how)."""
        from .operating_point import NoOperatingPoint, solve, weights
        names = [v.name for v in self.desc.x_e]
        Psi = np.asarray(self.numeric("Psi", self.desc.Psi, self.q)(*q), dtype=float).reshape(self.n_e, self.n_e)
        how = (f"operating point: {self.rule.describe(names)} (x_e not unique: n_e > n_m, "
               "components.operating_point)")
        try:
            x, branch = solve(self.rule, A, b, weights(self.rule, np.diag(Psi), *self.electrical_matrices()), self.sign)
        except NoOperatingPoint as exc:
            return None, (), f"{how}: {exc}"
        return x, branch, how

    def electrical_matrices(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """R_e, J_e, G_e at the parameter values."""
        return tuple(np.array(self.at_values(getattr(self.desc, k)).evalf(), dtype=float)   # type: ignore[return-value]
                     for k in ("R_e", "J_e", "G_e"))

    def branch(self, q: np.ndarray, b: np.ndarray) -> tuple:
        """The energized ports the rule chooses at (q, b) (n_e > n_m), () otherwise."""
        if not (self.diagonal and self.n_e > self.n_m and self.psi_diagonal):
            return ()
        A = np.asarray(self.numeric("A", self.A, self.q)(*q), dtype=float).reshape(self.n_m, self.n_e)
        return self.rule_state(q, A, b)[1]

    def _electrical_state_search(self, q: np.ndarray, b: np.ndarray) -> tuple[np.ndarray | None, str]:
        g = self.numeric("grad_q_H_e", self.grad_q_H_e, (*self.q, *self.x))
        scale = max(float(np.linalg.norm(b)), 1e-300)
        rng = np.random.default_rng(25)
        for size in np.logspace(-6, 3, SOLVE_STARTS):
            x0 = self.sign * size * (1.0 + 0.1 * rng.standard_normal(self.n_e))
            try:
                sol = optimize.least_squares(lambda x: (np.asarray(g(*q, *x), dtype=float).ravel() - b) / scale, x0,
                                             xtol=1e-15, ftol=1e-15, gtol=1e-15)
            except ValueError:                      # residuals not finite at the start: try the next size
                continue
            if np.linalg.norm(sol.fun) < 1e-10:
                return sol.x, f"least squares from {SOLVE_STARTS} starts (dPsi/dq_k not all diagonal)"
        return None, f"no solution found by least squares from {SOLVE_STARTS} starts (not a proof that none exists)"

    def exact_electrical_state(self, q_d: Sequence[sympy.Rational]) -> tuple[list[sympy.Expr] | None, bool | None, str]:
        """x_e_d of the set E at q_d exactly (n_e = n_m, diagonal dPsi/dq_k): (x_e_d, exists, how)."""
        if not (self.diagonal and self.n_m == self.n_e):
            return None, None, "not solvable exactly here (dPsi/dq_k not all diagonal or n_e != n_m)"
        subs = dict(zip(self.q, q_d))
        A = self.at_values(self.A).subs(subs)
        b = -self.at_values(self.grad_V).subs(subs)                                   # grad_q H = 0 with p = 0
        if A.det() == 0:
            return None, None, "A(q_d) is singular: x_e_d not unique"
        w = [sympy.simplify(v) for v in A.LUsolve(b)]
        if any(v.is_negative for v in w):
            return None, False, f"x_e_d^2 = w = {_numbers(w)} has a negative entry: no real x_e_d"
        if not all(v.is_nonnegative for v in w):
            return None, None, "sign of x_e_d^2 not decided"
        sign = sympy.Integer(1 if self.sign > 0 else -1)
        return [sign * sympy.sqrt(v) for v in w], True, "x_e_d_i^2 = w_i, A(q_d) w = -grad V(q_d), solved exactly"


# ---- set-point: the set E --------------------------------------------------------------------------

def default_q_d(desc: Any) -> list[float] | None:
    """The [controller] q_d default of the description (numbers only; an expression in gains is not used)."""
    value = getattr(desc, "controller", {}).get("q_d")
    if value is None:
        return None
    flat = value if isinstance(value, list) else [value]
    flat = [v[0] if isinstance(v, list) and len(v) == 1 else v for v in flat]
    if all(isinstance(v, (int, float)) and not isinstance(v, bool) for v in flat) and len(flat) == len(desc.q):
        return [float(v) for v in flat]
    return None


def check_setpoint(model: Model, q_d: list[float] | None) -> tuple[Verdict, list[sympy.Expr] | None, np.ndarray | None]:
    """q_d in E (Section 3): a real x_e_d with grad_q H(q_d, 0, x_e_d) = 0, q_d in the domain."""
    v = Verdict("Set-point q_d assignable (set E, Section 3)")
    if q_d is None:
        v.tests.append(Test("q_d given", NOT_DECIDED, "no q_d given and no [controller] q_d default",
                            "Assumptions 1, 2 at eta_d need a set-point"))
        return v, None, None
    q_exact = [exact(x) for x in q_d]
    margins = [model.at_values(g).subs(dict(zip(model.q, q_exact))) for g in model.desc.domain_margins]
    outside = [t for t, g in zip(model.desc.domain_text, margins) if not g.is_positive]
    v.tests.append(Test("q_d inside the domain " + " and ".join(model.desc.domain_text or ["(no domain)"]),
                        FAILS if outside else HOLDS, "exact at q_d and the parameter values",
                        f"violates {', '.join(outside)}" if outside else ""))
    cond = "real x_e_d with grad_q H(q_d, 0, x_e_d) = 0"
    x_exact, exists, how = model.exact_electrical_state(q_exact)
    if exists is not None:
        method = "x_e_d_i^2 = w_i with A(q_d) w = -grad V(q_d), A_ki = dPsi_ii/dq_k / 2, solved exactly"
        v.tests.append(Test(cond, HOLDS if exists else FAILS, method,
                            f"x_e_d = {_numbers([sympy.N(x) for x in x_exact])}" if exists else how))
        if outside or not exists:
            return v, None, None                                    # no eta_d in E
        return v, x_exact, np.array([float(sympy.N(x, 17)) for x in x_exact])
    qv = np.array(q_d, dtype=float)
    x_num, how = model.electrical_state(qv, -np.asarray(model.numeric("grad_V", model.grad_V, model.q)(*qv),
                                                         dtype=float).ravel())
    found = HOLDS if x_num is not None else (FAILS if model.diagonal and not how.startswith(NOT_FINITE) else NOT_DECIDED)
    v.tests.append(Test(cond, found, "numerically: " + how, "" if x_num is None else f"x_e_d = {_numbers(x_num)}"))
    return v, None, None if outside else x_num


# ---- reference: Definition 1 -----------------------------------------------------------------------

@dataclass
class Trajectory:
    """eta*(t) at the sampled times where it exists."""

    times: np.ndarray
    eta: list[np.ndarray]          # (q*, p*, x_e*) per feasible time
    feasible_times: np.ndarray
    description: str


def _jet_function(reference: Any, n_m: int) -> JetFunction:
    """t -> Jet of a components.references kind (n_m = 1), an object with .jet(t) (a stacked reference), or a
    function t -> Jet."""
    if isinstance(reference, Reference):
        if n_m != 1:
            raise ValueError(f"a {reference.name} is a scalar q*(t); this plant has n_m = {n_m}: give a jet function")
        return reference.jet
    if hasattr(reference, "jet"):
        return reference.jet
    if not callable(reference):
        raise ValueError(f"reference {reference!r} is neither a reference generator nor a function t -> Jet")
    return reference


def default_horizon(reference: Any) -> float:
    """One period of a sinusoid, the end of a smooth step, 0 for a constant (or a sinusoid without motion);
    for a stacked reference (.generators, one per position) the longest of its generators'. Any other
    reference needs an explicit horizon."""
    generators = getattr(reference, "generators", None)
    if generators is not None:
        return max((default_horizon(g) for g in generators), default=0.0)
    if isinstance(reference, Sinusoid):
        return reference_period(reference) or 0.0
    if isinstance(reference, SmoothStep):
        return reference.params["t_start"] + reference.params["duration"]
    if isinstance(reference, Constant):
        return 0.0
    raise ValueError("give the horizon over which the reference is checked")


def check_reference(model: Model, reference: Any, horizon: float | None,
                    times: int) -> tuple[Verdict, Trajectory]:
    """Definition 1 at sampled times: x_e*(t) exists (real) and q*(t) is inside the domain."""
    horizon = default_horizon(reference) if horizon is None else float(horizon)
    if not (math.isfinite(horizon) and horizon >= 0):
        raise ValueError(f"horizon = {horizon!r} must be finite and >= 0")
    jet_of = _jet_function(reference, model.n_m)
    ts = np.linspace(0.0, horizon, times) if horizon > 0 else np.array([0.0])
    what = f"{len(ts)} times evenly in [0, {horizon:.6g}] s"
    v = Verdict(f"Reference feasible (Definition 1), {what}")
    etas, ok_times, outside, infeasible = [], [], [], []
    branches: list[tuple] = []
    how = ""
    for t in ts:
        jet = jet_of(float(t))
        q, qd, qdd = (np.asarray(a, dtype=float).reshape(model.n_m) for a in (jet.q, jet.qd, jet.qdd))
        if not model.in_domain(q):
            outside.append(t)
            continue
        force = model.required_force(q, qd, qdd)
        x, how_t = model.electrical_state(q, force)
        if x is None:
            infeasible.append((t, how_t))
            continue
        how = how_t
        etas.append(np.concatenate([q, model.momentum(q, qd), x]))
        ok_times.append(t)
        branches.append(model.branch(q, force))
    v.tests.append(Test("q*(t) inside the domain " + " and ".join(model.desc.domain_text or ["(no domain)"]),
                        FAILS if outside else HOLDS, f"numerically at {what}",
                        f"outside at t = {_numbers(outside[:5])} s" if outside else ""))
    if infeasible:
        t0, why = infeasible[0]
        verdict = FAILS if model.diagonal and not any(w.startswith(NOT_FINITE) for _, w in infeasible) else NOT_DECIDED
        v.tests.append(Test("real x_e*(t) with grad_q H_e(q*, x_e*) = -(p*' + R_m q*' + grad V + grad_q T)", verdict,
                            f"numerically at {what}",
                            f"none at {len(infeasible)} of {len(ts)} times, first t = {t0:.6g} s: {why}"))
    else:
        v.tests.append(Test("real x_e*(t) with grad_q H_e(q*, x_e*) = -(p*' + R_m q*' + grad V + grad_q T)", HOLDS,
                            f"numerically at {what}", how))
    if model.n_e > model.n_m:
        from .operating_point import switches
        names = [x.name for x in model.desc.x_e]
        why = switches(ok_times, branches, names)
        v.tests.append(Test("x_e*(t) of the operating-point rule is C^3 (smooth: no port switches on or off)",
                            FAILS if why else HOLDS, f"the energized ports at {what}; {model.rule.describe(names)}",
                            why or ""))
    return v, Trajectory(ts, etas, np.array(ok_times), f"reference ({what})")


# ---- the assumptions -------------------------------------------------------------------------------

def _decide(A: sympy.Matrix, model: Model, at: Mapping[sympy.Symbol, Any], what: str,
            symbolic: bool = True) -> tuple[bool | None, str]:
    """A > 0 symbolically for every admissible parameter value (the parameters' conditions as sympy
    assumptions), else exactly at the parameter values. `symbolic` is False when `at` holds numbers computed
    at the parameter values (x_e_d): then only the exact evaluation is consistent."""
    stopped: list[str] = []
    if symbolic:
        decided = positive_definite(A.subs(at), stopped)
        if decided is not None:
            return decided, f"symbolic for every admissible parameter value{what}"
    decided = positive_definite(model.at_values(A).subs(at), stopped)
    return decided, f"exact at the parameter values{what}{''.join(stopped[-1:])}"


def R_m_test(model: Model) -> Test:
    """R_m > 0 (Assumptions 1 and 3)."""
    ok, how = _decide(model.desc.R_m, model, {}, "")
    if how.startswith("exact"):
        how = "not decided symbolically for every admissible parameter value; " + how
    R = np.array(model.at_values(model.desc.R_m).evalf(), dtype=float)
    verdict = HOLDS if ok else (FAILS if ok is False else NOT_DECIDED)
    return Test("R_m > 0", verdict, how, f"R_m = {R.tolist()}, min eig {min_eig(R):.6g}")


def hess_q_H(model: Model) -> sympy.Matrix:
    """hess_q H at p = 0: hess V + hess_q H_e (the kinetic term is quadratic in p)."""
    return sympy.hessian(model.desc.V + model.H_e, model.q)


def assumption_1(model: Model, q_d: list[float] | None, x_e_d: list[sympy.Expr] | None,
                 x_num: np.ndarray | None) -> Verdict:
    """R_m > 0 and hess_q H(eta_d) > 0 (eq. ass:class1)."""
    v = Verdict("Assumption 1 (eq. ass:class1)", [R_m_test(model)])
    cond = "hess_q H(eta_d) > 0"
    Hqq = hess_q_H(model)
    everywhere = positive_definite(model.at_values(Hqq))
    if everywhere is not None and not (Hqq.free_symbols & set(model.q + model.x)):
        v.tests.append(Test(cond, HOLDS if everywhere else FAILS, "exact at the parameter values, for every eta_d "
                            f"(hess_q H = {Hqq.tolist()} is constant)"))
    elif q_d is None:
        v.tests.append(Test(cond, NOT_DECIDED, "needs a set-point q_d"))
    elif x_e_d is None and x_num is None:
        v.tests.append(Test(cond, NOT_DECIDED, "q_d is not assignable: no eta_d"))
    else:
        at = dict(zip(model.q, [exact(x) for x in q_d]))
        xs = x_e_d if x_e_d is not None else [exact(x) for x in x_num]
        at.update(zip(model.x, xs))
        ok, how = _decide(Hqq, model, at, " at eta_d", symbolic=False)
        if x_e_d is None:
            how += " (x_e_d found numerically)"
        value = np.array(model.at_values(Hqq).subs(at).evalf(), dtype=float)
        v.tests.append(Test(cond, HOLDS if ok else (FAILS if ok is False else NOT_DECIDED), how,
                            f"hess_q H(eta_d) = {value.tolist()}, min eig {min_eig(value):.6g}"))
    return v


def structure_tests(model: Model) -> list[Test]:
    """grad_q H_e = -Gamma grad phi (eq. assHereg / assHe): Psi affine in q, then the identity."""
    desc = model.desc
    tests = []
    curved = [(k, j) for k, D in enumerate(model.dPsi) for j, qj in enumerate(model.q)
              if not all(_is_zero(e) for e in D.diff(qj))]
    if curved:
        k, j = curved[0]
        tests.append(Test("Psi affine in q (d2Psi/dq_k dq_l = 0 identically)", FAILS, "symbolic",
                          f"d2Psi/dq{k + 1}dq{j + 1} = {sympy.simplify(model.dPsi[k].diff(model.q[j])).tolist()}: "
                          "grad_q H_e depends on q, so no constant Gamma and phi(x_e) exist"))
        return tests
    tests.append(Test("Psi affine in q (d2Psi/dq_k dq_l = 0 identically)", HOLDS, "symbolic"))
    if desc.Gamma is None or desc.phi is None:
        tests.append(Test("grad_q H_e + Gamma grad phi = 0", NOT_DECIDED,
                          "no Gamma, phi given in [model] and none derived (some dPsi/dq_k is not diagonal)"))
        return tests
    grad_phi = sympy.Matrix([sympy.diff(desc.phi, xi) for xi in model.x])
    residual = model.grad_q_H_e + desc.Gamma * grad_phi
    ok = all(_is_zero(e) for e in residual)
    tests.append(Test("grad_q H_e + Gamma grad phi = 0 identically", HOLDS if ok else FAILS, "symbolic",
                      f"Gamma = {desc.Gamma.tolist()} ({desc.gamma_source}), phi = {desc.phi}"
                      + ("" if ok else f"; residual {list(residual)}")))
    return tests


def hess_phi(model: Model) -> sympy.Matrix:
    return sympy.hessian(model.desc.phi, model.x)


def _hess_phi_everywhere(model: Model) -> tuple[bool | None, str]:
    """hess phi > 0 for every x_e of the branch the plant uses: x_e = sign sqrt(w), w > 0 (diagonal dPsi/dq_k)."""
    if not model.diagonal:
        return None, ""
    s = 1 if model.sign > 0 else -1
    branch = {xi: s * sympy.Symbol(f"_w{i}", positive=True) for i, xi in enumerate(model.x)}
    ok, how = _decide(hess_phi(model), model, branch, "")
    sign = "> 0" if s > 0 else "< 0"
    return ok, f"{how}, for every x_e with entries {sign} (the branch x_e = {s:+d} sqrt(w) with w > 0)"


def hess_phi_at(model: Model, x_e: Sequence[Any], exactly: bool) -> tuple[bool | None, float, str]:
    H = hess_phi(model)
    if exactly:
        ok, how = _decide(H, model, dict(zip(model.x, x_e)), "", symbolic=False)
        value = np.array(model.at_values(H).subs(dict(zip(model.x, x_e))).evalf(), dtype=float)
        return ok, min_eig(value), how
    with np.errstate(all="ignore"):
        value = np.array(model.numeric("hess_phi", H, model.x)(*x_e), dtype=float).reshape(model.n_e, model.n_e)
    if not np.all(np.isfinite(value)):
        return None, math.nan, "numerically (hess phi not finite there)"
    lam = min_eig(value)
    return bool(lam > 0), lam, "numerically"


def assumption_2(model: Model, structure: list[Test], q_d: list[float] | None, x_e_d: list[sympy.Expr] | None,
                 x_num: np.ndarray | None) -> Verdict:
    """grad_q H_e = -Gamma grad phi and hess phi(x_e_d) > 0 (eq. assHereg)."""
    v = Verdict("Assumption 2 (eq. assHereg)", list(structure))
    if model.desc.phi is None or FAILS in [t.verdict for t in structure]:
        return v
    cond = "hess phi(x_e_d) > 0"
    if x_e_d is not None or x_num is not None:
        ok, lam, how = hess_phi_at(model, x_e_d if x_e_d is not None else list(x_num), x_e_d is not None)
        v.tests.append(Test(cond, HOLDS if ok else (FAILS if ok is False else NOT_DECIDED), how + " at x_e_d",
                            f"min eig {lam:.6g}"))
    else:
        ok, how = _hess_phi_everywhere(model)
        if ok and q_d is None:
            v.tests.append(Test(cond, HOLDS, how))
        else:
            v.tests.append(Test(cond, NOT_DECIDED, "needs an assignable set-point q_d"))
    return v


def _scale(etas: list[np.ndarray], model: Model) -> np.ndarray:
    """Per-state size of the target: max |eta*_i| over the sampled reference (its momenta p* = M(q*) q*'); a
    momentum at rest along the whole reference (p*_i = 0: a set-point, or an axis that does not move) gets
    sqrt(M_ii k_i) max |q*|, the momentum of an oscillation of amplitude max |q*| at the axis' own frequency,
    with k_i = |d^2 H / dq_i^2| at eta* the device's stiffness there (its potential's and its electrical energy's
    curvature; the largest k_j where that is 0; 1 in the state's units where all are 0)."""
    E = np.array(etas)
    s = np.max(np.abs(E), axis=0)
    m = model.n_m
    at_rest = s[m:2 * m] == 0
    if np.any(at_rest):
        M = np.asarray(model.numeric("M", model.desc.M, model.q)(*E[0, :m]), dtype=float).reshape(m, m)
        k = np.abs(np.diag(stiffness(model, E[0])))
        k = np.where(np.isfinite(k) & (k > 0), k, np.max(k[np.isfinite(k)], initial=0.0) or 1.0)
        s[m:2 * m] = np.where(at_rest, np.sqrt(np.diag(M) * k) * np.max(s[:m]), s[m:2 * m])
    return np.where(s > 0, s, 1.0)


def stiffness(model: Model, eta: np.ndarray) -> np.ndarray:
    """hess_q H at eta = (q, p, x_e): the device's stiffness (potential and electrical energy, eq. (H))."""
    m = model.n_m
    f = model.numeric("hess_q_H", hess_q_H(model), (*model.q, *model.p, *model.x))
    with np.errstate(all="ignore"):
        return np.asarray(f(*eta[:2 * m], *eta[2 * m:]), dtype=float).reshape(m, m)


def sample_box(model: Model, etas: list[np.ndarray], box: float | Mapping[str, tuple[float, float]],
               samples: int) -> tuple[list[np.ndarray], str]:
    """Points of the set S: a box of relative half-width `box` x scale around each eta*(t), or the given
    bounds per state; centre(s), vertices (n <= 8) and `samples` random points each; outside-domain dropped."""
    n = 2 * model.n_m + model.n_e
    rng = np.random.default_rng(25)
    if isinstance(box, Mapping):
        names = [v.name for v in (*model.desc.q, *model.desc.p, *model.desc.x_e)]
        missing = [name for name in names if name not in box]
        if missing or set(box) - set(names):
            raise ValueError(f"box: give bounds (lo, hi) for every state {names}; missing {missing}, "
                             f"unknown {sorted(set(box) - set(names))}")
        lo = np.array([float(box[name][0]) for name in names])
        hi = np.array([float(box[name][1]) for name in names])
        if not np.all(lo < hi):
            raise ValueError(f"box: every lower bound must be below its upper bound: {dict(box)}")
        centres, half = [(lo + hi) / 2], (hi - lo) / 2
        what = "the given box " + ", ".join(f"{nm} in [{a:.6g}, {b:.6g}]" for nm, a, b in zip(names, lo, hi))
    else:
        r = float(box)
        if not (math.isfinite(r) and r > 0):
            raise ValueError(f"box = {box!r} must be > 0 (relative half-width) or bounds per state")
        half = r * _scale(etas, model)
        centres = etas
        what = (f"boxes of half-widths {_numbers(half)} (= {r:g} x state scale) around eta* at "
                f"{len(etas)} time(s)")
    corners = np.array(list(product([-1.0, 1.0], repeat=n))) if n <= 8 else np.zeros((0, n))
    points = []
    for c in centres:
        offsets = np.vstack([np.zeros(n), corners, rng.uniform(-1, 1, (samples, n))]) * half
        points += [c + d for d in offsets if model.in_domain((c + d)[:model.n_m])]
    what += (f"; {len(points)} points (centre, {len(corners)} vertices, {samples} random each; outside the domain "
             "dropped); sampled, not rigorous between samples")
    return points, what


def box_contains(model: Model, box: Mapping[str, tuple[float, float]], etas: list[np.ndarray]) -> Test:
    """S (a given box) must contain the target eta*(t) (eq. cond1T2: S is an open set containing eta*)."""
    names = [v.name for v in (*model.desc.q, *model.desc.p, *model.desc.x_e)]
    lo = np.array([float(box[n][0]) for n in names])
    hi = np.array([float(box[n][1]) for n in names])
    out = [k for k, eta in enumerate(etas) if not np.all((lo < eta) & (eta < hi))]
    detail = f"{len(out)} of {len(etas)} sampled eta* outside the box" if out else ""
    return Test("S (the given box) contains eta*", NOT_DECIDED if out else HOLDS, "numerically at the sampled eta*",
                detail)


def assumption_3(model: Model, points: list[np.ndarray] | None, why_not: str,
                 contains: Test | None = None, box: str = "") -> Verdict:
    """R_m > 0 and alpha I < [[hess_q H, d_q grad_p H], [., M^-1]] < beta I on S (eq. cond1T2)."""
    v = Verdict("Assumption 3 (eq. cond1T2)", [R_m_test(model)] + ([contains] if contains else []))
    cond = "alpha I < [[hess_q H, d_q grad_p H], [., M^-1]] < beta I on S, 0 < alpha < beta"
    m = model.n_m
    H = model.desc.M.inv()
    pv = sympy.Matrix(model.p)
    Hfull = (pv.T * H * pv)[0, 0] / 2 + model.desc.V + model.H_e
    block = sympy.hessian(Hfull, (*model.q, *model.p))
    if not (block.free_symbols & set(model.q + model.p + model.x)):
        ok = positive_definite(model.at_values(block))
        v.tests.append(Test(cond, HOLDS if ok else (FAILS if ok is False else NOT_DECIDED),
                            f"exact at the parameter values: the block {block.tolist()} is constant"))
        return v
    if not points:
        v.tests.append(Test(cond, NOT_DECIDED, why_not or "no sample of S inside the domain"))
        return v
    f = model.numeric("cond1T2", block, (*model.q, *model.p, *model.x))
    lo, hi = np.inf, -np.inf
    bad: list[np.ndarray] = []                  # samples where the block is not finite: no NaN may "win" min/max
    for eta in points:
        with np.errstate(all="ignore"):
            B = np.asarray(f(*eta[:2 * m], *eta[2 * m:]), dtype=float).reshape(2 * m, 2 * m)
        if not np.all(np.isfinite(B)):
            bad.append(eta)
            continue
        lo, hi = min(lo, min_eig(B)), max(hi, max_eig(B))
    if bad:
        v.tests.append(Test(cond, NOT_DECIDED, "numerically over S (see the box)",
                            f"the block is not finite (overflow, 0/0) at {len(bad)} of {len(points)} samples, first at "
                            f"eta = {_numbers(bad[0])}: no sampled verdict"))
        return v
    v.tests.append(Test(cond, HOLDS if lo > 0 else FAILS, "numerically over S (see the box)",
                        f"alpha (sampled min eig) = {lo:.6g}, beta (sampled max eig) = {hi:.6g}"
                        + (f"; S: {box}" if box else "")))
    return v


def assumption_4(model: Model, structure: list[Test], trajectory: Trajectory | None, why_not: str) -> Verdict:
    """grad_q H_e = -Gamma grad phi and hess phi(x_e*(t)) > 0 along the reference (eq. assHe)."""
    v = Verdict("Assumption 4 (eq. assHe)", list(structure))
    if model.desc.phi is None or FAILS in [t.verdict for t in structure]:
        return v
    cond = "hess phi(x_e*(t)) > 0 along the reference"
    if trajectory is not None and trajectory.eta:
        lams = [hess_phi_at(model, list(eta[2 * model.n_m:]), False)[1] for eta in trajectory.eta]
        if not all(math.isfinite(lam) for lam in lams):
            k = next(i for i, lam in enumerate(lams) if not math.isfinite(lam))
            v.tests.append(Test(cond, NOT_DECIDED, f"numerically at the {len(lams)} feasible time(s) of the "
                                f"{trajectory.description}", f"hess phi not finite at t = {trajectory.feasible_times[k]:.6g} s"))
            return v
        k = int(np.argmin(lams))
        v.tests.append(Test(cond, HOLDS if lams[k] > 0 else FAILS,
                            f"numerically at the {len(lams)} feasible time(s) of the {trajectory.description}",
                            f"min eig {lams[k]:.6g} at t = {trajectory.feasible_times[k]:.6g} s"))
        return v
    ok, how = _hess_phi_everywhere(model)
    if ok and trajectory is None:
        v.tests.append(Test(cond, HOLDS, how + ": every feasible reference on this branch"))
    else:
        v.tests.append(Test(cond, NOT_DECIDED, why_not or "needs a feasible reference or set-point"))
    return v


# ---- the designs -----------------------------------------------------------------------------------

def missing_operating_point(model: Model) -> str:
    """Why no design can fix the electrical operating point ("" where one can): for n_e > n_m the free
    electrical coordinates of x_e* (Definition 1) and of x_e_d are fixed by components.operating_point, which
    needs diagonal Psi(q) and dPsi/dq_k; coupled coils (a non-diagonal one) have no such rule, in the
    controllers (Python and C) as here."""
    if model.n_e <= model.n_m or (model.diagonal and model.psi_diagonal):
        return ""
    which = "dPsi/dq_k" if not model.diagonal else "Psi(q)"
    return (f"{NO_OPERATING_POINT}: n_e = {model.n_e} > n_m = {model.n_m} with coupled coils ({which} not diagonal); "
            "the operating-point rules (components.operating_point) need diagonal Psi(q) and dPsi/dq_k")


def designs(assumptions: list[Verdict], setpoint: Verdict, reference: Verdict | None, q_d_given: bool,
            no_operating_point: str = "") -> list[DesignVerdict]:
    """Proposition 1 needs Assumption 1 (then D_d = 0 satisfies eq. pHcondition strictly, R_m > 0);
    Proposition 2 needs Assumption 2 (D_d = 0 satisfies eq. pHcondition, R_m >= 0); Theorem 2 needs
    Assumption 3, Theorem 3 Assumption 4 (Theorem 1 (i)-(iii) then hold through the gains: K_e, D_d,
    Theta_1 / Theta_2, Section 5). A regulation design also needs an assignable set-point, a tracking
    design a feasible reference, when one is given; every design needs an operating point
    (`no_operating_point`: why there is none, missing_operating_point), checked first."""
    out = []
    for name in DESIGNS:
        if no_operating_point:
            out.append(DesignVerdict(name, False, no_operating_point))
            continue
        a = assumptions[int(ASSUMPTION_OF[name][-1]) - 1]
        tracking = name.startswith("Theorem")
        if tracking and reference is not None and reference.verdict == FAILS:
            out.append(DesignVerdict(name, False, f"the reference is infeasible: {_first(reference)}"))
            continue
        if not tracking and q_d_given and setpoint.verdict == FAILS:
            out.append(DesignVerdict(name, False, f"q_d is not assignable: {_first(setpoint)}"))
            continue
        if a.verdict == HOLDS:
            extra = {"Proposition1": "; D_d = 0 satisfies eq. (pHcondition) strictly since R_m > 0",
                     "Proposition2": "; D_d = 0 satisfies eq. (pHcondition) since R_m >= 0",
                     "Theorem2": "; K_e, D_d, Theta_1 are then chosen for Theorem 1 (i)-(iii)",
                     "Theorem3": "; K_e > 0, D_d, Theta_2 are then chosen for Theorem 1 (i)-(iii)"}[name]
            out.append(DesignVerdict(name, True, f"{a.name} holds{extra}"))
        else:
            out.append(DesignVerdict(name, False, f"{a.name} {a.verdict}: {_first(a)}"))
    return out


def _first(v: Verdict) -> str:
    bad = v.failing()
    if not bad:
        return ""
    t = bad[0]
    return f"{t.condition} {t.verdict}" + (f" ({t.detail})" if t.detail else "")


# ---- the whole check -------------------------------------------------------------------------------

def check(desc: Any, q_d: float | Sequence[float] | None = None, reference: Any = None,
          box: float | Mapping[str, tuple[float, float]] | None = None, samples: int = SAMPLES, times: int = TIMES,
          horizon: float | None = None, parameters: Mapping[str, float] | None = None) -> Report:
    """Assumptions 1-4, the set-point q_d (default: the description's [controller] q_d) and the reference
    (a components.references kind for n_m = 1, an object with .jet(t) or a function t -> Jet) over `horizon`
    (default: default_horizon) at `times` evenly spaced times; the set S of Assumption 3 is `box`
    (relative half-width around eta*(t), default RADIUS, or bounds per state name) sampled with `samples`
    random points per time. `parameters` override the description's defaults."""
    model = Model(desc, parameters)
    if q_d is not None:
        q_list = [float(x) for x in np.atleast_1d(np.asarray(q_d, dtype=float))]
        if len(q_list) != model.n_m:
            raise ValueError(f"q_d has {len(q_list)} entries; the plant has n_m = {model.n_m} positions")
    else:
        q_list = default_q_d(desc)
    setpoint, x_e_d, x_num = check_setpoint(model, q_list)
    ref_verdict, trajectory = (None, None)
    why_not = ""
    if reference is not None:
        ref_verdict, trajectory = check_reference(model, reference, horizon, times)
        etas = trajectory.eta
        if not etas:
            why_not = "the reference is feasible at none of the sampled times"
    elif x_num is not None:
        etas = [np.concatenate([np.array(q_list), np.zeros(model.n_m), x_num])]     # the constant reference eta_d
    else:
        etas = []
        why_not = "needs a reference, an assignable set-point or a box"
    points, box_text = (None, "no numeric box (no reference, set-point or box)")
    if etas or isinstance(box, Mapping):
        points, box_text = sample_box(model, etas, RADIUS if box is None else box, samples)
        if reference is None and not isinstance(box, Mapping):
            box_text = "constant reference eta* = eta_d: " + box_text
    structure = structure_tests(model)
    assumptions = [assumption_1(model, q_list, x_e_d, x_num),
                   assumption_2(model, structure, q_list, x_e_d, x_num),
                   assumption_3(model, points, why_not,
                                box_contains(model, box, etas) if isinstance(box, Mapping) and etas else None,
                                box_text),
                   assumption_4(model, structure, trajectory if reference is not None else _constant(etas),
                                why_not)]
    return Report(desc.name, desc.source, dict(model.values), q_list,
                  None if x_num is None else [float(x) for x in x_num], setpoint, ref_verdict, assumptions,
                  designs(assumptions, setpoint, ref_verdict, q_list is not None, missing_operating_point(model)),
                  box_text, _operating_point_text(model))


def _operating_point_text(model: Model) -> str:
    """The Report's operating-point line (n_e > n_m; "" otherwise)."""
    if model.n_e <= model.n_m:
        return ""
    return missing_operating_point(model) or model.rule.describe([v.name for v in model.desc.x_e])


def _constant(etas: list[np.ndarray]) -> Trajectory | None:
    """The set-point as a constant reference (Assumption 4 with eta* = eta_d), None without one."""
    if not etas:
        return None
    return Trajectory(np.array([0.0]), etas, np.array([0.0]), "constant reference eta_d")
