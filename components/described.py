"""Plants from a description: the run-time part (no sympy) of the classes components.codegen generates.

A generated model module (components/plants/<name>_model.py, or `codegen.module_source(desc)`) defines
a subclass of `DescribedOneDOF` (n_m = n_e = 1, constant M: today's scalar fast path of OneDOFPlant) or
of `DescribedPlant` (any n_m, n_e: numpy arrays) whose model functions are the description's formulas,
differentiated by sympy once. Parameters are resolved and checked by name here, the domain is checked
by inequality, and feasible references (Definition 1) are found for any n_m = n_e.

The math-function dispatchers (sqrt, exp, ...) send floats to math and complex numbers to cmath, so the
generated functions take complex arguments (complex-step derivatives) at the cost of one isinstance.
"""
from __future__ import annotations

import cmath
import math
from typing import Any, Callable, Mapping, Sequence

import numpy as np

from . import operating_point as _op
from .device import DESIGNS, Design, Device, VariableSpec
from .parameters import Parameter, resolve
from .ph_plant import DomainError, EMPlant, Jet, OneDOFPlant


def _dispatch(real: Callable, complex_: Callable) -> Callable:
    def f(x):
        return complex_(x) if isinstance(x, complex) else real(x)
    f.__name__ = real.__name__
    return f


sqrt = _dispatch(math.sqrt, cmath.sqrt)
exp = _dispatch(math.exp, cmath.exp)
log = _dispatch(math.log, cmath.log)
sin = _dispatch(math.sin, cmath.sin)
cos = _dispatch(math.cos, cmath.cos)
tan = _dispatch(math.tan, cmath.tan)
sinh = _dispatch(math.sinh, cmath.sinh)
cosh = _dispatch(math.cosh, cmath.cosh)
tanh = _dispatch(math.tanh, cmath.tanh)
atan = _dispatch(math.atan, cmath.atan)
asin = _dispatch(math.asin, cmath.asin)
acos = _dispatch(math.acos, cmath.acos)
pi = math.pi


def _analytic_abs(z: complex) -> complex:
    """|x| continued analytically off the real axis (x or -x by the sign of the real part), so that a complex
    step through |x| (sympy's sqrt(x^2) = Abs(x) of real symbols) keeps the derivative sign(x) dx."""
    return z if z.real >= 0 else -z


fabs = _dispatch(math.fabs, _analytic_abs)


class _Described:
    """What both described plant kinds share: parameters by name, the domain by inequality."""

    PARAMETERS: dict[str, Parameter] = {}
    VARIABLES: Mapping[str, tuple[VariableSpec, ...]] = {}
    DOMAIN: tuple[str, ...] = ()
    """The description's domain inequalities as written (`q < c`); margin j > 0 is inequality j."""
    DOMAIN_PARAMETERS: tuple[tuple[str, ...], ...] = ()
    """The parameters in each inequality (named with their values in a DomainError)."""
    GAMMA_IN_DEVICE_UNITS: bool = False
    """Gamma, phi derived in the device's scale (Gamma^T q in the unit of x_e): z (eq. z) has a unit and so has k_c."""
    domain_reasons: tuple[str, ...] = ()
    """What a violation of each inequality means physically (optional, appended to the DomainError)."""
    params: dict[str, float]

    def _set_parameters(self, params: Mapping[str, float]) -> None:
        self.params = resolve(self.PARAMETERS, params, self.name)   # type: ignore[attr-defined]
        for k, v in self.params.items():
            setattr(self, "_p_" + k, v)                # what the generated functions read
            if not hasattr(type(self), k):               # the parameters as attributes, unless a method's name
                setattr(self, k, v)
        self._setup()
        self._check_structure()

    def _check_structure(self) -> None:
        """The conditions of eq. (open-loop elecmech) on the constant matrices, at these parameter values
        (the description was checked at its defaults only): R_m, R_e symmetric positive semi-definite,
        J_e skew-symmetric, G_e invertible, a constant M symmetric positive definite. A ValueError names
        the matrix, its value and the parameters."""
        values = ", ".join(f"{k} = {v:g}" for k, v in self.params.items())
        owner = self.name                                            # type: ignore[attr-defined]

        def refuse(what: str, A: np.ndarray, condition: str) -> None:
            raise ValueError(f"{owner}: {what} = {np.round(A, 12).tolist()} violates {condition} "
                             f"(eq. open-loop elecmech) with {values}")

        for what in ("R_m", "R_e"):
            A = np.asarray(getattr(self, what), dtype=float)
            tiny = -1e-12 * max(1.0, float(np.max(np.abs(A))))
            if not np.allclose(A, A.T, rtol=1e-12, atol=0.0) or np.min(np.linalg.eigvalsh(A)) < tiny:
                refuse(what, A, f"{what} = {what}^T >= 0")
        J_e = np.asarray(self.J_e, dtype=float)                     # type: ignore[attr-defined]
        if not np.allclose(J_e, -J_e.T, rtol=1e-12, atol=0.0):
            refuse("J_e", J_e, "J_e = -J_e^T")
        G_e = np.asarray(self.G_e, dtype=float)                     # type: ignore[attr-defined]
        if np.linalg.matrix_rank(G_e) < G_e.shape[0]:
            refuse("G_e", G_e, "rank G_e = n_e")
        if self.constant_mass:                                       # type: ignore[attr-defined]
            M_inv = np.asarray(self.M_inv(np.zeros(len(self.VARIABLES["q"]))), dtype=float)   # type: ignore[attr-defined]
            if not np.all(np.isfinite(M_inv)) or np.min(np.linalg.eigvalsh((M_inv + M_inv.T) / 2)) <= 0:
                refuse("M^-1", M_inv, "M = M^T > 0")

    def _setup(self) -> None:
        """Generated: the constant matrices (and bounds) from the parameters."""
        raise NotImplementedError

    def margins(self, q) -> tuple:
        """Generated: the domain margins g_j(q) (positive inside)."""
        return ()

    def _domain_error(self, q) -> None:
        for j, g in enumerate(self.margins(q)):
            if not np.real(g) > 0:
                names = ", ".join(f"{s} = {self.params[s]:g} {self.PARAMETERS[s].unit}" for s in self.DOMAIN_PARAMETERS[j])
                where = ", ".join(f"{v.name} = {np.real(x):.6g} {v.unit}" for v, x in zip(self.VARIABLES["q"], q))
                reason = f": {self.domain_reasons[j]}" if j < len(self.domain_reasons) else ""
                raise DomainError(f"{self.name}: {where} violates {self.DOMAIN[j]}"   # type: ignore[attr-defined]
                                  + (f" ({names})" if names else "") + reason)


class DescribedOneDOF(_Described, OneDOFPlant):
    """A described plant with n_m = n_e = 1 and constant M: scalar V_s, dV, d2V, psi, dpsi, d2psi
    (generated) on OneDOFPlant's fast path. Inequalities linear in q set q_min / q_max."""

    linear_domain: bool = True

    def __init__(self, **params: float):
        self._set_parameters(params)

    def domain_margin(self, eta) -> float:
        if self.linear_domain:
            return OneDOFPlant.domain_margin(self, eta)
        return float(min((np.real(g) for g in self.margins(np.real(eta[:1]))), default=math.inf))

    def check_state(self, eta) -> None:
        OneDOFPlant.check_state(self, eta)
        q = np.real(eta[0])
        if not (self.linear_domain and self.q_min < q < self.q_max):
            self._domain_error((q,))
        if not np.real(self.psi(q)) > 0:                         # eq. (elec energy): Psi > 0
            raise DomainError(f"{self.name}: Psi(q) = {np.real(self.psi(q)):.6g} is not positive at q = {q:.6g} "
                              f"(eq. elec energy: the stored energy must be positive) with "
                              + ", ".join(f"{k} = {v:g}" for k, v in self.params.items()))


class DescribedPlant(_Described, EMPlant):
    """A described plant of any n_m, n_e (numpy arrays); the model functions are generated."""

    def __init__(self, **params: float):
        self._set_parameters(params)

    def domain_margin(self, eta) -> float:
        q = np.real(np.asarray(eta)[:self.n_m])
        return float(min((g for g in self.margins(q)), default=math.inf))

    def check_state(self, eta) -> None:
        EMPlant.check_state(self, eta)
        q = np.real(np.asarray(eta)[:self.n_m])
        self._domain_error(q)
        Psi = np.real(np.asarray(self.Psi(q), dtype=complex))
        if not np.min(np.linalg.eigvalsh((Psi + Psi.T) / 2)) > 0:    # eq. (elec energy): Psi > 0
            raise DomainError(f"{self.name}: Psi(q) = {np.round(Psi, 12).tolist()} is not positive definite at "
                              f"q = {q.tolist()} (eq. elec energy) with "
                              + ", ".join(f"{k} = {v:g}" for k, v in self.params.items()))

    def force_jet(self, q, qd, qdd, qddd) -> tuple[np.ndarray, np.ndarray]:
        """Generated: (F*, dF*/dt) of the p-row of eq. (open-loop elecmech) along a reference jet,
        F* = M q*'' + (dM/dt) q*' + R_m q*' + grad V(q*) + 1/2 p*^T dM^-1/dq p* (p* = M q*'), the force
        -grad_q H_e(q*, x_e*) the reference needs (Definition 1)."""
        raise NotImplementedError

    def feasible_state(self, jet: Jet) -> tuple[np.ndarray, np.ndarray]:
        """(eta*, x_e*') of a reference jet, Definition 1, for n_e = n_m.

        x_e* solves -1/2 x_e^T dPsi/dq_k(q*) x_e = F*_k (k = 1..n_m) by Newton's method from a real start
        on the side x_e_sign, then one Newton step in complex arithmetic (exact first derivatives for a
        complex jet: complex step). Differentiating in time: A x_e*' = -F*' - 1/2 x_e*^T (dPsi_k/dt) x_e*
        with A_ki = (dPsi/dq_k(q*) x_e*)_i.
        """
        if self.n_e > self.n_m:
            return self._feasible_by_rule(jet)
        if self.n_e < self.n_m:
            raise NotImplementedError(f"{self.name}: feasible_state needs n_e >= n_m (here n_m = {self.n_m}, "
                                      f"n_e = {self.n_e}): the force balance is overdetermined")
        q, qd, qdd, qddd = (np.asarray(v).reshape(-1) for v in (jet.q, jet.qd, jet.qdd, jet.qddd))
        q_real = np.real(q).astype(float)
        if not all(np.real(g) > 0 for g in self.margins(q_real)):
            self._domain_error(q_real)
        F, F_dot = self.force_jet(q, qd, qdd, qddd)
        dPsi_real = np.real(self.dPsi(q_real)).astype(float)
        x = self._solve_real(dPsi_real, np.real(F).astype(float), q_real)
        complex_jet = any(np.iscomplexobj(v) for v in (q, qd, qdd, qddd))
        dPsi = self.dPsi(q) if complex_jet else dPsi_real
        if complex_jet:                                     # one Newton step in complex arithmetic
            r = -0.5 * np.einsum("i,kij,j->k", x, dPsi, x) - F
            x = x - np.linalg.solve(-np.einsum("kij,j->ki", dPsi_real, x), r)
        A = np.einsum("kij,j->ki", dPsi, x)
        dPsi_dt = np.einsum("klij,l->kij", self.d2Psi(q), qd)
        x_dot = np.linalg.solve(A, -F_dot - 0.5 * np.einsum("i,kij,j->k", x, dPsi_dt, x))
        p = np.linalg.solve(self.M_inv(q), qd)             # p* = M(q*) q*'
        return np.concatenate([q, p, x]), x_dot

    OPERATING_POINT: tuple | None = None
    """The description's operating-point rule (components.operating_point.Rule.as_tuple), n_e > n_m; None: the
    least electrical energy (the default)."""

    def operating_rule(self) -> _op.Rule:
        return _op.Rule.from_tuple(self.OPERATING_POINT) if self.OPERATING_POINT else _op.Rule(given=False)

    def _feasible_by_rule(self, jet: Jet, branch_only: bool = False) -> Any:
        """(eta*, x_e*') for n_e > n_m: x_e* by the operating-point rule (components.operating_point) from the force
        balance A(q*) w = -F*, A_ki = (dPsi/dq_k)_ii / 2, w = x_e*^2, and x_e*' from its time derivative."""
        q, qd, qdd, qddd = (np.asarray(v).reshape(-1) for v in (jet.q, jet.qd, jet.qdd, jet.qddd))
        q_real = np.real(q).astype(float)
        if not all(np.real(g) > 0 for g in self.margins(q_real)):
            self._domain_error(q_real)
        dPsi, Psi = np.asarray(self.dPsi(q)), np.asarray(self.Psi(q))
        off = [D - np.diag(np.diag(D)) for D in (*np.real(dPsi), np.real(Psi))]
        if any(np.any(o != 0) for o in off):
            raise ValueError(f"{self.name}: an operating point for n_e = {self.n_e} > n_m = {self.n_m} needs "
                             "diagonal Psi(q) and dPsi/dq_k (components.operating_point): not available for "
                             "coupled coils")
        A = np.einsum("kii->ki", dPsi) / 2
        F, F_dot = self.force_jet(q, qd, qdd, qddd)
        rule = self.operating_rule()
        names = [v.name for v in self.VARIABLES["x_e"]]
        try:
            cost = _op.weights(rule, np.diag(Psi), self.R_e, self.J_e, self.G_e)
            x, branch = _op.solve(rule, A, -np.asarray(F), cost, self.x_e_sign)
        except _op.NoOperatingPoint as exc:
            where = ", ".join(f"{v.name}* = {x_:.6g}" for v, x_ in zip(self.VARIABLES["q"], q_real))
            raise ValueError(f"{self.name}: infeasible reference at {where} with the operating point "
                             f"{rule.describe(names)}: {exc} (Definition 1)") from None
        if branch_only:
            return branch
        A_dot = np.einsum("klii,l->ki", np.asarray(self.d2Psi(q)), qd) / 2
        x_dot = _op.rate(rule, branch, A, A_dot, -np.asarray(F_dot), x)
        p = np.linalg.solve(self.M_inv(q), qd)
        return np.concatenate([q, p, x]), x_dot

    def electrical_branch(self, jet: Jet) -> tuple:
        """The energized ports of x_e*(jet) chosen by the operating-point rule (n_e > n_m; () otherwise): where it
        changes along a reference x_e*(t) is not differentiable."""
        if self.n_e <= self.n_m:
            return ()
        return self._feasible_by_rule(jet, branch_only=True)

    def _solve_real(self, dPsi: np.ndarray, F: np.ndarray, q: np.ndarray) -> np.ndarray:
        """Real x with -1/2 x^T dPsi_k x = F_k, by damped Newton from x_e_sign * (a common magnitude)."""
        scale = math.sqrt(2.0 * float(np.max(np.abs(F))) / max(float(np.max(np.abs(dPsi))), 1e-300)) or 1.0
        x = self.x_e_sign * scale * np.ones(self.n_e)
        where = ", ".join(f"{v.name}* = {x_:.6g}" for v, x_ in zip(self.VARIABLES["q"], q))
        for _ in range(100):
            r = -0.5 * np.einsum("i,kij,j->k", x, dPsi, x) - F
            A = -np.einsum("kij,j->ki", dPsi, x)
            if not np.all(np.isfinite(A)) or np.linalg.cond(A) > 1e14:
                break
            step = np.linalg.solve(A, r)
            t = 1.0
            norm = float(np.linalg.norm(r))
            while t > 1e-4:
                x_new = x - t * step
                if np.linalg.norm(-0.5 * np.einsum("i,kij,j->k", x_new, dPsi, x_new) - F) < norm:
                    break
                t /= 2
            x = x_new
            if np.linalg.norm(t * step) <= 1e-15 * max(float(np.linalg.norm(x)), 1e-300):
                r = -0.5 * np.einsum("i,kij,j->k", x, dPsi, x) - F
                if np.linalg.norm(r) <= 1e-10 * max(float(np.linalg.norm(F)), 1e-300):
                    return x
                break
        raise ValueError(f"{self.name}: infeasible reference at {where}: no real x_e* solves "
                         f"-1/2 x_e^T dPsi/dq_k(q*) x_e = F*_k = {F.tolist()} (Definition 1)")


# ---- the Device of a description ---------------------------------------------------------------------
GAIN_SHAPES = {"q_d": ("m", 1), "R_e_bar": ("e", "e"), "D_d": ("e", "m"), "k_c": ("e", "e"), "W": ("e", "e")}
DESIGN_GAINS = {"Proposition1": ("q_d", "R_e_bar", "D_d", "W"), "Proposition2": ("q_d", "R_e_bar", "k_c", "D_d"),
                "Theorem2": ("R_e_bar", "D_d", "W"), "Theorem3": ("R_e_bar", "k_c", "D_d")}
GAIN_TEXT = {"q_d": "set-point position", "R_e_bar": "desired electrical damping R_e_bar = R_e + K_e > 0 (eq. barRe)",
             "D_d": "coupled damping D_d of eq. (closedloop)", "k_c": "weight K_c of Phi_2 / Theta_2 = 1/2 (z - L)^T K_c (z - L)",
             "W": "weight W of Phi_1 / Theta_1 = 1/2 (x_e - x_c)^T W (x_e - x_c) (eqs. c1, u1-track; the paper's examples: 1)"}


def _electrical_damping_unit(a: str, b: str) -> str:
    """unit(x_e_i) unit(x_e_j) / J / s: Ohm for fluxes [Wb], 1/Ohm for charges [C]."""
    if a == b == "Wb":
        return "Ohm"
    if a == b == "C":
        return "1/Ohm"
    return f"{a}2/J/s" if a == b else f"{a}.{b}/J/s"


def _input_weight_unit(a: str, b: str) -> str:
    """unit(u_i) unit(u_j) / J, the unit of K_c (Theta_2 = 1/2 (z - L)^T K_c (z - L) [J], z_i in J/unit(u_i)):
    V/C for voltages, A/Wb for currents."""
    if a == b == "V":
        return "V/C"
    if a == b == "A":
        return "A/Wb"
    return f"{a}2/J" if a == b else f"{a}.{b}/J"


def gain_unit(gain: str, i: int, j: int, q: Sequence[VariableSpec], x_e: Sequence[VariableSpec],
              u: Sequence[VariableSpec] | None = None) -> str:
    """The unit of entry (i, j) of a gain (0-based), from the units of the description's variables
    (docs/derivations.md, "Units of the gains"). k_c needs the inputs u."""
    if gain == "k_c" and u is not None:
        return _input_weight_unit(u[i].unit, u[j].unit)
    if gain == "q_d":
        return q[i].unit
    if gain == "D_d":
        return f"{x_e[i].unit}/{q[j].unit}" if q[j].unit != "1" else x_e[i].unit
    if gain == "R_e_bar":
        return _electrical_damping_unit(x_e[i].unit, x_e[j].unit)
    if gain == "W":                                # Phi_1 [J] / (x_e_i x_e_j)
        a, b = x_e[i].unit, x_e[j].unit
        return {"Wb": "1/H", "C": "1/F"}[a] if a == b and a in ("Wb", "C") else f"J/{a}/{b}"
    return "1"


def make_device(plant_cls: Any, defaults: Mapping[str, list], forms: Mapping[str, tuple[Callable, tuple[str, ...]]],
                gain_parameters: Mapping[str, Parameter], designs: Sequence[str] | None = None) -> Device:
    """The Device of a described plant: `defaults[gain]` a matrix (list of rows) of default values for the
    gains given as numbers; `forms[gain]` = (function of the gain parameters -> matrix, their names) for a
    plant-specific form (MEMS: R_e_bar = 1/rbar_e); `designs` the designs that apply (default: all)."""
    from .proposition1 import Proposition1
    from .proposition2 import Proposition2
    from .theorem2 import Theorem2
    from .theorem3 import Theorem3

    V = plant_cls.VARIABLES
    n_m, n_e = len(V["q"]), len(V["x_e"])
    dims = {"m": n_m, "e": n_e, 1: 1}
    scalar = n_m == 1 and n_e == 1

    def entries(gain: str) -> list[tuple[str, int, int]]:
        r, c = (dims[d] for d in GAIN_SHAPES[gain])
        if r * c == 1:
            return [(gain, 0, 0)]
        if gain == "q_d":
            return [(f"q_d_{i + 1}", i, 0) for i in range(r)]
        return [(f"{gain}_{i + 1}_{j + 1}", i, j) for i in range(r) for j in range(c)]

    specs: dict[str, list[Parameter]] = {}
    for gain in GAIN_SHAPES:
        if gain == "W" and gain not in forms and gain not in defaults:
            continue                               # Phi_1 / Theta_1 with the paper's W = I
        if gain in forms:
            specs[gain] = [gain_parameters[n] for n in forms[gain][1]]
            continue
        values = defaults[gain]
        out = []
        for name, i, j in entries(gain):
            condition = "> 0" if scalar and gain in ("R_e_bar", "k_c", "W") else "any"
            what = GAIN_TEXT[gain] + (f", entry ({i + 1}, {j + 1})" if name != gain else "")
            if gain == "q_d" and name != gain:
                what = f"{GAIN_TEXT[gain]} {V['q'][i].name}_d"
            unit = gain_unit(gain, i, j, V["q"], V["x_e"], V["u"] if plant_cls.GAMMA_IN_DEVICE_UNITS else None)
            out.append(Parameter(name, float(values[i][j]), unit, what, condition))
        specs[gain] = out

    def matrix(gain: str, g: Mapping[str, float]) -> np.ndarray | None:
        if gain not in specs:                      # W not a gain: the controller's default (identity)
            return None
        if gain in forms:
            fn, names = forms[gain]
            return np.asarray(fn(*(g[n] for n in names)), dtype=float)
        r, c = (dims[d] for d in GAIN_SHAPES[gain])
        a = np.zeros((r, c))
        for name, i, j in entries(gain):
            a[i, j] = g[name]
        return a[:, 0] if gain == "q_d" else a

    builders = {
        "Proposition1": lambda P, m: Proposition1(P, m["q_d"], m["R_e_bar"], D_d=m["D_d"], W=m["W"]),
        "Proposition2": lambda P, m: Proposition2(P, m["q_d"], m["R_e_bar"], k_c=m["k_c"], D_d=m["D_d"]),
        "Theorem2": lambda P, m: Theorem2(P, m["R_e_bar"], D_d=m["D_d"], W=m["W"]),
        "Theorem3": lambda P, m: Theorem3(P, m["R_e_bar"], k_c=m["k_c"], D_d=m["D_d"]),
    }
    chosen = list(DESIGNS) if designs is None else list(designs)
    unknown = [d for d in chosen if d not in DESIGNS]
    if unknown:
        raise ValueError(f"{plant_cls.__name__}: unknown design(s) {unknown}; the designs are {list(DESIGNS)}")
    out_designs = {}
    for name in chosen:
        gains = tuple(g for g in DESIGN_GAINS[name] if g in specs)
        table = {p.name: p for gain in gains for p in specs[gain]}

        def make(P: EMPlant, g: Mapping[str, float], _name=name) -> object:
            return builders[_name](P, {gain: matrix(gain, g) for gain in DESIGN_GAINS[_name]})
        out_designs[name] = Design(name, table, make)     # type: ignore[arg-type]
    return Device(plant_cls.DEVICE_NAME, plant_cls.name, plant_cls.PARAMETERS, V["q"], V["p"], V["x_e"], V["u"],
                  plant=plant_cls, designs=out_designs)
