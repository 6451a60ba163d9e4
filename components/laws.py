"""The four control laws stated once, symbolically, in a plant description's symbols (docs/native-fmus.md).

Two statements cover the paper's four laws, because each regulation law is its tracking law at a constant
reference (the paper: "identical in form"):

    family c1 (Assumptions 1 and 3): eq. (c1) of Proposition 1, eq. (u1-track) of Theorem 2
        u = G_e^-1 { (J_e - R_e_bar) W (x_e - x_e* + L_2) - K_e Psi(q) x_e + D_d M^-1(q) p }
        L_2 = W^-1 [ (J_e - R_e_bar)^-1 (x_e*' - D_d M^-1(q*) p*) - Psi(q*) x_e* ]          (eq. feasibleT2)
      at a constant reference (p* = 0, x_e*' = 0) L_2 = -W^-1 Psi(q_d) x_e_d = L_1 of eq. (RegL): eq. (c1).

    family u2 (Assumptions 2 and 4): eq. (u2) of Proposition 2, eq. (tracker2) of Theorem 3
        u = G_e^-1 { (R_e - J_e) Psi(q) x_e + (D_d - Gamma^T) M^-1(q) p + (J_e - R_e_bar) grad phi(x_e) }
            - K_c (z - L_3),       z = -G_e^T (J_e - R_e_bar)^-T (Gamma^T q + x_e)                 (eq. z)
        K_c (z* - L_3) = G_e^-1 [ (D_d - Gamma^T) M^-1(q*) p* + (J_e - R_e_bar) grad phi(x_e*) - x_e*' ]
                                                                         (eq. L2, with erratum 2's G_e)
      at a constant reference L_3 = z_d - K_c^-1 G_e^-1 (J_e - R_e_bar) grad phi(x_e_d) = L of
      components/proposition2.py: eq. (u2).

The reference enters as the feasible state (q*, p*, x_e*) and x_e*' of Definition 1; for a plant with
n_m = n_e = 1 and constant mass `feasible_reference` states them in the jet (q*, q*', q*'', q*''') in closed
form (components.ph_plant.OneDOFPlant.feasible_scalar), so a law is then a function of (eta, jet).

The gains are symbols named as the controller FMUs' parameters (R_e_bar, D_d, W, k_c; entries
R_e_bar_1_2, ... where a matrix is larger than 1 x 1). The hand-written numpy laws of components/
(proposition1.py, ..., theorem3.py) stay the independent truth the tests compare these with.
"""
from __future__ import annotations

from dataclasses import dataclass, fields

import sympy

from .description import Description
from .symbolic import plant_expressions


@dataclass(frozen=True)
class Law:
    """One control law: u (n_e) in the plant's symbols, the gains and the reference."""

    family: str                                   # "c1" or "u2"
    equations: str                                # the paper's equations it states
    gains: tuple[sympy.Symbol, ...]               # R_e_bar, D_d, then W (c1) or k_c (u2), each row-major
    reference: tuple[sympy.Symbol, ...]           # (q*, p*, x_e*, x_e*') or the jet (q*, q*', q*'', q*''')
    u: sympy.Matrix


def _matrix(name: str, rows: int, cols: int) -> sympy.Matrix:
    if rows == cols == 1:
        return sympy.Matrix([[sympy.Symbol(name, real=True)]])
    return sympy.Matrix(rows, cols, lambda i, j: sympy.Symbol(f"{name}_{i + 1}_{j + 1}", real=True))


def _names(prefix: str, symbols) -> tuple[sympy.Symbol, ...]:
    return tuple(sympy.Symbol(f"{s.name}_{prefix}", real=True) for s in symbols)


def _reference_symbols(desc: Description):
    q_s, p_s, x_s = (_names("star", group) for group in (desc.q_symbols, desc.p_symbols, desc.x_e_symbols))
    xd_s = tuple(sympy.Symbol(f"{s.name}_star_dot", real=True) for s in desc.x_e_symbols)
    return q_s, p_s, x_s, xd_s


def law(desc: Description, family: str) -> Law:
    """The law of `family` ("c1" or "u2") for the plant of `desc`, with the feasible reference as symbols
    (q*, p*, x_e*, x_e*')."""
    E = plant_expressions(desc)
    m, e = desc.n_m, desc.n_e
    q, p, x = (sympy.Matrix(v) for v in (E.q, E.p, E.x_e))
    q_s, p_s, x_s, xd_s = _reference_symbols(desc)
    star = dict(zip(E.q, q_s))
    Qs, Ps, Xs, XDs = (sympy.Matrix(v) for v in (q_s, p_s, x_s, xd_s))
    R_e_bar, D_d = _matrix("R_e_bar", e, e), _matrix("D_d", e, m)
    JR_bar = desc.J_e - R_e_bar                                   # J_e - R_e_bar
    K_e = R_e_bar - desc.R_e                                      # eq. (barRe)
    G_inv = desc.G_e.inv()
    M_inv, Psi = E.M_inv, E.Psi
    M_inv_s, Psi_s = M_inv.xreplace(star), Psi.xreplace(star)
    if family == "c1":
        W = _matrix("W", e, e)
        L_2 = W.inv() * (JR_bar.inv() * (XDs - D_d * M_inv_s * Ps) - Psi_s * Xs)              # eq. (feasibleT2)
        u = G_inv * (JR_bar * W * (x - Xs + L_2) - K_e * Psi * x + D_d * M_inv * p)     # eq. (c1), (u1-track)
        gains = (*R_e_bar, *D_d, *W)
        return Law("c1", "eq. (c1), eq. (u1-track), eq. (feasibleT2)", tuple(gains), q_s + p_s + x_s + xd_s, u)
    if family != "u2":
        raise ValueError(f"no control law family {family!r} (c1, u2)")
    if desc.Gamma is None or desc.phi is None:
        raise ValueError(f"{desc.source}: eq. (u2) needs Gamma and phi of Assumption 2/4, which the plant lacks")
    Gamma = desc.Gamma
    K_c = _matrix("k_c", e, e)
    grad_phi = sympy.Matrix([desc.phi.diff(s) for s in desc.x_e_symbols])
    grad_phi_s = grad_phi.xreplace(dict(zip(desc.x_e_symbols, x_s)))
    A = -desc.G_e.T * JR_bar.inv().T                                                             # eq. (z)
    z, z_s = A * (Gamma.T * q + x), A * (Gamma.T * Qs + Xs)
    L_3 = z_s - K_c.inv() * G_inv * ((D_d - Gamma.T) * M_inv_s * Ps + JR_bar * grad_phi_s - XDs)   # eq. (L2)
    u = (G_inv * ((desc.R_e - desc.J_e) * Psi * x + (D_d - Gamma.T) * M_inv * p + JR_bar * grad_phi)
         - K_c * (z - L_3))                                                                      # eq. (u2), (tracker2)
    gains = (*R_e_bar, *D_d, *K_c)
    return Law("u2", "eq. (u2), eq. (tracker2), eq. (z), eq. (L2)", tuple(gains), q_s + p_s + x_s + xd_s, u)


def jet_symbols(desc: Description) -> tuple[sympy.Symbol, ...]:
    """(q*, q*', q*'', q*''') of a one-degree-of-freedom plant."""
    name = desc.q_symbols[0].name
    return tuple(sympy.Symbol(f"{name}_star{suffix}", real=True) for suffix in ("", "_dot", "_ddot", "_dddot"))


def feasible_reference(desc: Description) -> tuple[tuple[sympy.Symbol, ...], dict]:
    """Definition 1 in closed form for n_m = n_e = 1 and constant mass: the jet symbols and the substitution
    {q*, p*, x_e*, x_e*'} -> expressions of the jet. The p-row of eq. (open-loop elecmech) gives
    -1/2 Psi'(q*) x_e*^2 = m q*'' + R_m q*' + V'(q*) =: F*, so x_e* = s sqrt(2 F* / g), g = -Psi'(q*),
    s = x_e_sign, and x_e*' = (F*' g - F* g') / (x_e* g^2) (components.ph_plant.OneDOFPlant.feasible_scalar)."""
    if not (desc.n_m == 1 and desc.n_e == 1 and desc.constant_mass):
        raise ValueError(f"{desc.source}: a closed-form feasible reference needs n_m = n_e = 1 and constant M "
                         "(any other plant: Newton, not generated yet)")
    E = plant_expressions(desc)
    qs, qd, qdd, qddd = jet = jet_symbols(desc)
    q = E.q[0]
    m = desc.M[0, 0]
    R_m = desc.R_m[0, 0]
    force = m * qdd + R_m * qd + E.grad_V[0].xreplace({q: qs})
    force_dot = m * qddd + R_m * qdd + E.hess_V[0, 0].xreplace({q: qs}) * qd
    g = -E.dPsi[0][0, 0].xreplace({q: qs})
    g_dot = -E.d2Psi[0][0][0, 0].xreplace({q: qs}) * qd
    x_e = desc.x_e_sign * sympy.sqrt(2 * force / g)
    x_e_dot = (force_dot * g - force * g_dot) / (x_e * g * g)
    q_s, p_s, x_s, xd_s = _reference_symbols(desc)
    return jet, {q_s[0]: qs, p_s[0]: m * qd, x_s[0]: x_e, xd_s[0]: x_e_dot}


def tracking_law(desc: Description, family: str) -> Law:
    """`law` with the reference given by its jet (q*, q*', q*'', q*''') (one-degree-of-freedom plants)."""
    jet, subs = feasible_reference(desc)
    base = law(desc, family)
    return Law(base.family, base.equations + ", Definition 1", base.gains, jet, base.u.xreplace(subs))


FAMILY = {"Proposition1": "c1", "Theorem2": "c1", "Proposition2": "u2", "Theorem3": "u2"}
TRACKING = {"Proposition1": False, "Theorem2": True, "Proposition2": False, "Theorem3": True}


@dataclass(frozen=True)
class DesignLaw:
    """The law of one design of a one-degree-of-freedom device as its controller FMU computes it: u and its
    Jacobian in the FMU's inputs (q, p, x_e, then the jet when tracking) and its gain parameters (the
    design's, in their order: q_d for regulation, rbar_e or R_e_bar, k_c, D_d, ...), with what the
    controller's construction checks (components.closed_loop: R_e_bar > 0, k_c > 0, eq. pHcondition) and
    the reference's feasibility (Definition 1: q* inside the domain, 2 F* / g > 0)."""

    design: str
    inputs: tuple[sympy.Symbol, ...]
    gains: tuple[sympy.Symbol, ...]
    u: sympy.Expr
    jacobian: tuple[sympy.Expr, ...]
    R_e_bar: sympy.Expr
    k_c: sympy.Expr
    ph_margin: sympy.Expr                          # R_m - D_d^2 / (4 R_e_bar), eq. (pHcondition) for n = 1
    reference_margin: sympy.Expr                   # the domain margin at q*
    reference_ratio: sympy.Expr                    # 2 F* / g of Definition 1 (> 0: x_e* is real)


def design_law(desc: Description, design: str, gain_names: tuple[str, ...]) -> DesignLaw:
    """The DesignLaw of `design` (Proposition1, Proposition2, Theorem2, Theorem3) for a plant with
    n_m = n_e = 1 and constant mass; `gain_names`: the design's gain parameters (components.device)."""
    from .description import gain_table
    from .symbolic import plant_expressions

    if design not in FAMILY:
        raise ValueError(f"no design {design!r} ({', '.join(FAMILY)})")
    stated = tracking_law(desc, FAMILY[design])
    jet, subs = feasible_reference(desc)
    symbols = {n: sympy.Symbol(n, real=True) for n in gain_names}
    defaults, forms, _ = gain_table(desc)

    def gain(name: str) -> sympy.Expr:
        if name in symbols:
            return symbols[name]
        if name in forms:
            return forms[name][0][0, 0]
        if name in defaults:
            return sympy.Float(defaults[name][0][0])
        if name == "W":                             # Phi_1 / Theta_1 with W = I, as in the paper
            return sympy.Integer(1)
        raise ValueError(f"{desc.source}: design {design} has no gain {name}")

    values = {"R_e_bar": gain("R_e_bar"), "D_d": gain("D_d")}
    values["W" if FAMILY[design] == "c1" else "k_c"] = gain("W" if FAMILY[design] == "c1" else "k_c")
    replace = {s: values[s.name] for s in stated.gains}
    E = plant_expressions(desc)
    if TRACKING[design]:
        inputs = E.eta + jet
        reference = dict(zip(jet, jet))
    else:
        q_d = symbols["q_d"]
        inputs = E.eta
        reference = {jet[0]: q_d, jet[1]: sympy.Integer(0), jet[2]: sympy.Integer(0), jet[3]: sympy.Integer(0)}
    u = stated.u[0].xreplace(replace).xreplace(reference)
    q = E.q[0]
    margin = E.domain_margin
    x_star = _reference_symbols(desc)[2][0]
    ratio = (subs[x_star] / desc.x_e_sign) ** 2                              # x_e*^2 = 2 F* / g (Definition 1)
    R_m = desc.R_m[0, 0]
    return DesignLaw(
        design, tuple(inputs), tuple(symbols[n] for n in gain_names), u, tuple(u.diff(s) for s in inputs),
        values["R_e_bar"], values.get("k_c", sympy.Integer(1)),
        R_m - values["D_d"] ** 2 / (4 * values["R_e_bar"]),
        (sympy.oo if margin is None else margin.xreplace({q: jet[0]})).xreplace(reference),
        ratio.xreplace(reference))


# ---- the design's conditions (components.certificates.design_checks), stated beside the laws --------------
# In the symbols of `law`: the state eta, the gains (R_e_bar, D_d, W or k_c) and the feasible reference
# (q*, p*, x_e*, x_e*'); the generated C (components.c_codegen.design_checks_c_source) evaluates them at the target.

def F_d(desc: Description, family: str) -> sympy.Matrix:
    """F_d = J_d - R_d of eq. (closedloop) with the gains' symbols: [[0, I, 0], [-I, -R_m, Gamma],
    [0, -Gamma^T + D_d, J_e - R_e_bar]], Gamma = 0 for family c1 (Proposition 1, Theorem 2). Theorem 1 (i)
    asks it to be Hurwitz (components.closed_loop.F_d is its numpy form)."""
    m, e = desc.n_m, desc.n_e
    R_e_bar, D_d = _matrix("R_e_bar", e, e), _matrix("D_d", e, m)
    Gamma = desc.Gamma if family == "u2" else sympy.zeros(m, e)
    if Gamma is None:
        raise ValueError(f"{desc.source}: eq. (u2) needs Gamma and phi of Assumption 2/4, which the plant lacks")
    return sympy.BlockMatrix([[sympy.zeros(m, m), sympy.eye(m), sympy.zeros(m, e)],
                              [-sympy.eye(m), -desc.R_m, Gamma],
                              [sympy.zeros(e, m), -Gamma.T + D_d, desc.J_e - R_e_bar]]).as_explicit()


def hess_phi(desc: Description) -> sympy.Matrix:
    """hess phi(x_e) of Assumptions 2/4 (eq. assHereg / assHe): > 0 at x_e_d, x_e*(t)."""
    if desc.phi is None:
        raise ValueError(f"{desc.source}: the plant has no phi of Assumption 2/4")
    return sympy.hessian(desc.phi, desc.x_e_symbols)


def hess_H_d(desc: Description, family: str) -> sympy.Matrix:
    """The Hessian of the closed loop's energy H_d (eq. closedloop), whose value at the target eqs. (phi12)
    (Proposition 1) and (Phic22) (Proposition 2) ask to be > 0:
        c1: H_d = H(eta) + Phi_1(x_e), Phi_1 quadratic with weight W (its gradient W (x_e - x_e* + L_2) is eq. (c1)'s)
        u2: H_d = 1/2 p^T M^-1(q) p + V(q) + phi(x_e) + 1/2 (z - L_3)^T K_c (z - L_3), z of eq. (z)
    (the linear terms L_2, L_3 do not enter the Hessian; components.proposition1/2.hess_H_d are the numpy forms)."""
    E = plant_expressions(desc)
    e = desc.n_e
    q, p, x = (sympy.Matrix(v) for v in (E.q, E.p, E.x_e))
    if family == "c1":
        W = _matrix("W", e, e)
        H_d = E.H + (x.T * W * x)[0, 0] / 2
    elif family == "u2":
        if desc.Gamma is None or desc.phi is None:
            raise ValueError(f"{desc.source}: eq. (u2) needs Gamma and phi of Assumption 2/4, which the plant lacks")
        R_e_bar, K_c = _matrix("R_e_bar", e, e), _matrix("k_c", e, e)
        z = -desc.G_e.T * (desc.J_e - R_e_bar).inv().T * (desc.Gamma.T * q + x)              # eq. (z)
        H_d = (p.T * E.M_inv * p)[0, 0] / 2 + E.V + desc.phi + (z.T * K_c * z)[0, 0] / 2
    else:
        raise ValueError(f"no control law family {family!r} (c1, u2)")
    return sympy.hessian(H_d, E.eta)


@dataclass(frozen=True)
class DesignMatrices:
    """What components.certificates.design_checks decides, as matrices at the target eta_d (regulation) or
    eta*(t) of the jet (tracking), in a DesignLaw's inputs and gains (each None where the design does not ask it):

        hess_H_d   n x n   eq. (phi12) / (Phic22): hess H_d(eta_d) > 0 (scaled to a unit diagonal)
        hess_q_H   n_m^2   Assumption 1: hess_q H(eta_d) > 0
        R_m        n_m^2   Assumptions 1, 3: R_m > 0
        hess_phi   n_e^2   Assumptions 2, 4: hess phi(x_e_d), hess phi(x_e*) > 0
        K_e        n_e^2   K_e = R_e_bar - R_e >= 0 (> 0 for Theorem 3), eq. (barRe)
        F_d        n x n   Theorem 1 (i): F_d Hurwitz (Theorems 2 and 3)"""

    hess_H_d: sympy.Matrix | None
    hess_q_H: sympy.Matrix | None
    R_m: sympy.Matrix | None
    hess_phi: sympy.Matrix | None
    K_e: sympy.Matrix
    F_d: sympy.Matrix | None


def design_matrices_at_reference(desc: Description, design: str, gains: dict[str, sympy.Matrix]) -> DesignMatrices:
    """The DesignMatrices of `design` for any plant (any n_m, n_e, M(q)) at the feasible reference of `law`'s
    symbols (q*, p*, x_e*): eta_d for regulation (Propositions 1, 2), eta*(t) for tracking (Theorems 2, 3). The
    native controller evaluates them at the reference it solves (closed form or Newton, components.c_codegen);
    `gains`: R_e_bar, D_d and W or k_c as matrices (components.c_codegen._design_gains)."""
    family = FAMILY[design]
    E = plant_expressions(desc)
    q_s, p_s, x_s, _ = _reference_symbols(desc)
    m, e = desc.n_m, desc.n_e
    replace: dict = {}
    for name, shape in (("R_e_bar", (e, e)), ("D_d", (e, m)), ("W", (e, e)), ("k_c", (e, e))):
        if name in gains:
            replace.update(zip(_matrix(name, *shape), sympy.Matrix(gains[name]).reshape(*shape)))
    target = dict(zip(E.eta, (*q_s, *p_s, *x_s)))

    def at_target(M: sympy.Matrix) -> sympy.Matrix:
        return M.xreplace(replace).xreplace(target)
    regulation = design in ("Proposition1", "Proposition2")
    hess_H = sympy.hessian(E.H, E.eta)
    return DesignMatrices(
        hess_H_d=at_target(hess_H_d(desc, family)) if regulation else None,
        hess_q_H=at_target(hess_H[:m, :m]) if design == "Proposition1" else None,
        R_m=desc.R_m if design in ("Proposition1", "Theorem2") else None,
        hess_phi=at_target(hess_phi(desc).xreplace(dict(zip(desc.x_e_symbols, E.x_e))))
        if family == "u2" else None,
        K_e=at_target(_matrix("R_e_bar", e, e) - desc.R_e),
        F_d=at_target(F_d(desc, family)) if not regulation else None)


def design_matrices(desc: Description, design: str, gain_names: tuple[str, ...]) -> DesignMatrices:
    """The DesignMatrices of `design` for a plant with n_m = n_e = 1 and constant mass in a DesignLaw's inputs and
    gains (`design_law`): design_matrices_at_reference with Definition 1's closed form substituted."""
    law_of = design_law(desc, design, gain_names)
    jet, subs = feasible_reference(desc)
    one = {"R_e_bar": law_of.R_e_bar, "D_d": _design_gain(desc, gain_names, "D_d"),
           "W": _design_gain(desc, gain_names, "W"), "k_c": law_of.k_c}
    D = design_matrices_at_reference(desc, design, {n: sympy.Matrix([[v]]) for n, v in one.items()})
    if TRACKING[design]:
        reference: dict = {}
    else:
        q_d = sympy.Symbol("q_d", real=True)
        reference = {jet[0]: q_d, jet[1]: sympy.Integer(0), jet[2]: sympy.Integer(0), jet[3]: sympy.Integer(0)}

    def closed(M: sympy.Matrix | None) -> sympy.Matrix | None:
        return None if M is None else M.xreplace(subs).xreplace(reference)
    return DesignMatrices(*(closed(getattr(D, f.name)) for f in fields(DesignMatrices)))


def _design_gain(desc: Description, gain_names: tuple[str, ...], name: str) -> sympy.Expr:
    """A gain of a one-degree-of-freedom design as design_law takes it: its parameter, its form or default in
    the description's gain table, W = 1 (the paper's Phi_1 / Theta_1)."""
    from .description import gain_table
    if name in gain_names:
        return sympy.Symbol(name, real=True)
    defaults, forms, _ = gain_table(desc)
    if name in forms:
        return forms[name][0][0, 0]
    if name in defaults:
        return sympy.Float(defaults[name][0][0])
    if name == "W":
        return sympy.Integer(1)
    raise ValueError(f"{desc.source}: no gain {name}")


# ---- Definition 1 for any plant: the pieces the native controllers solve (components.c_codegen) ---------------
def jet_vector(desc: Description) -> tuple[sympy.Symbol, ...]:
    """The reference jet (q*, q*', q*'', q*''') of any plant as 4 n_m symbols in the order of a tracking
    controller's inputs (components.device.Device.jet_names: every q_i*, then every q_i*', ...); for n_m = 1
    these are `jet_symbols`."""
    return tuple(sympy.Symbol(f"{s.name}_star{suffix}", real=True)
                 for suffix in ("", "_dot", "_ddot", "_dddot") for s in desc.q_symbols)


def force_jet(desc: Description) -> tuple[sympy.Matrix, sympy.Matrix, sympy.Matrix]:
    """(p*, F*, F*') along the jet of `jet_vector`: the p-row of eq. (open-loop elecmech) on the reference,
        p* = M(q*) q*',   F* = M q*'' + M' q*' + R_m q*' + grad V(q*) + 1/2 p*^T dM^-1/dq p*  = -grad_q H_e(q*, x_e*),
    and F*' = dF*/dt (Definition 1; components.described.DescribedPlant.force_jet states the same)."""
    m = desc.n_m
    jet = jet_vector(desc)
    qs, qd, qdd, qddd = (jet[i * m:(i + 1) * m] for i in range(4))
    t = sympy.Symbol("t_path", real=True)
    path = {q: sympy.Function(f"path_{k}")(t) for k, q in enumerate(desc.q_symbols)}
    q_t = sympy.Matrix([path[q] for q in desc.q_symbols])
    M_t = desc.M.xreplace(path)
    q_dot = q_t.diff(t)
    p_t = M_t * q_dot
    F = (M_t * q_t.diff(t, 2) + M_t.diff(t) * q_dot + desc.R_m * q_dot
         + sympy.Matrix([desc.V.diff(q) for q in desc.q_symbols]).xreplace(path))
    if not desc.constant_mass:
        M_inv = desc.M.inv()
        F = F + sympy.Matrix([(p_t.T * M_inv.diff(q).xreplace(path) * p_t)[0, 0] / 2 for q in desc.q_symbols])
    F_dot = F.diff(t)
    back = [(path[desc.q_symbols[k]].diff(t, order), sym[k]) for order, sym in ((3, qddd), (2, qdd), (1, qd))
            for k in range(m)] + [(path[desc.q_symbols[k]], qs[k]) for k in range(m)]

    def unpath(expr: sympy.Expr) -> sympy.Expr:
        for old, new in back:
            expr = expr.subs(old, new)
        return expr
    return (p_t.applyfunc(unpath), F.applyfunc(unpath), F_dot.applyfunc(unpath))


@dataclass(frozen=True)
class NewtonReference:
    """Definition 1 for n_e = n_m (components.described.DescribedPlant.feasible_state): x_e* solves
        R_1(x_e*) = -1/2 x_e*^T dPsi/dq_k(q*) x_e* - F*_k = 0                     (k = 1..n_m)
    by Newton's method, and x_e*' solves the time derivative of R_1,
        R_2 = A x_e*' + F*' + 1/2 x_e*^T (dPsi_k/dt) x_e* = 0,   A_ki = (dPsi/dq_k(q*) x_e*)_i;
    the reference's derivatives follow from the implicit function theorem: dx_e*/dj = A^-1 dR_1/dj,
    dx_e*'/dj = -A^-1 (dR_2/dj + dR_2/dx_e* dx_e*/dj). All in the symbols jet (jet_vector), x (x_e*), x_dot."""

    jet: tuple[sympy.Symbol, ...]
    x: tuple[sympy.Symbol, ...]
    x_dot: tuple[sympy.Symbol, ...]
    margin: sympy.Expr                    # the domain margin at q* (oo: no boundary)
    p: sympy.Matrix                       # p* = M(q*) q*'
    F: sympy.Matrix                       # F*
    dPsi: tuple[sympy.Matrix, ...]        # dPsi/dq_k at q*
    A: sympy.Matrix                       # A_ki = (dPsi_k x)_i
    b: sympy.Matrix                       # -(F*' + 1/2 x^T dPsi_k/dt x): A x_dot = b
    R_1: sympy.Matrix
    R_2: sympy.Matrix


def newton_reference(desc: Description) -> NewtonReference:
    """The NewtonReference of a plant with n_e = n_m (any M(q))."""
    if desc.n_e != desc.n_m:
        raise ValueError(f"{desc.source}: Newton's feasible reference needs n_e = n_m (here {desc.n_m}, {desc.n_e})")
    E = plant_expressions(desc)
    jet = jet_vector(desc)
    m = desc.n_m
    star = dict(zip(desc.q_symbols, jet[:m]))
    x = sympy.Matrix([sympy.Symbol(f"{s.name}_star", real=True) for s in desc.x_e_symbols])
    x_dot = sympy.Matrix([sympy.Symbol(f"{s.name}_star_dot", real=True) for s in desc.x_e_symbols])
    p, F, F_dot = force_jet(desc)
    dPsi = tuple(D.xreplace(star) for D in E.dPsi)
    dPsi_dt = [sum((E.d2Psi[k][j].xreplace(star) * jet[m + j] for j in range(m)), sympy.zeros(m, m))
               for k in range(m)]
    A = sympy.Matrix(m, m, lambda k, i: (dPsi[k] * x)[i])
    quad = sympy.Matrix([(x.T * dPsi_dt[k] * x)[0, 0] / 2 for k in range(m)])
    R_1 = sympy.Matrix([-(x.T * dPsi[k] * x)[0, 0] / 2 - F[k] for k in range(m)])
    margin = sympy.oo if E.domain_margin is None else E.domain_margin.xreplace(star)
    return NewtonReference(jet, tuple(x), tuple(x_dot), margin, p, F, dPsi, A, -(F_dot + quad), R_1,
                           A * x_dot + F_dot + quad)


@dataclass(frozen=True)
class ClosedReference:
    """Definition 1 in closed form in the jet (jet_vector): the feasible state (q*, p*, x_e*, x_e*') and what
    must be positive for it to exist: the domain margin at q* and `conditions` (n_m = n_e = 1: 2 F*/g; a bias
    operating point: the solved w = x_e*^2); F* (all zero at rest: the equilibrium x_e = 0 of
    components.ph_plant.EMPlant.equilibrium)."""

    jet: tuple[sympy.Symbol, ...]
    margin: sympy.Expr
    F: sympy.Matrix
    conditions: tuple[sympy.Expr, ...]
    state: tuple[sympy.Expr, ...]         # (q*, p*, x_e*, x_e*'): 2 n_m + 2 n_e entries


def closed_reference(desc: Description) -> ClosedReference:
    """The ClosedReference of a plant with n_m = n_e = 1 and constant M (`feasible_reference`) or with n_e > n_m
    and a bias operating point (components.operating_point: n_e - n_m coordinates given, the force balance
    A(q*) w = -F*, A_ki = (dPsi/dq_k)_ii / 2, w = x_e*^2, fixes the rest; x_e*' from A w' = -F*' - A' w)."""
    E = plant_expressions(desc)
    jet = jet_vector(desc)
    m, e = desc.n_m, desc.n_e
    star = dict(zip(desc.q_symbols, jet[:m]))
    p, F, F_dot = force_jet(desc)
    margin = sympy.oo if E.domain_margin is None else E.domain_margin.xreplace(star)
    if m == 1 and e == 1 and desc.constant_mass:
        _, subs = feasible_reference(desc)
        q_s, p_s, x_s, xd_s = _reference_symbols(desc)
        ratio = (subs[x_s[0]] / desc.x_e_sign) ** 2                           # 2 F* / g
        state = (jet[0], subs[p_s[0]], subs[x_s[0]], subs[xd_s[0]])
        return ClosedReference(jet, margin, F, (ratio,), state)
    rule = desc.operating_point
    if e <= m or rule is None or rule.kind != "bias":
        kind = "least_energy (the default)" if rule is None else rule.kind
        raise ValueError(f"{desc.source}: a closed-form feasible reference needs n_m = n_e = 1 with constant M, or "
                         f"n_e > n_m with a bias operating point (here n_m = {m}, n_e = {e}, rule {kind})")
    A = sympy.Matrix(m, e, lambda k, i: E.dPsi[k][i, i].xreplace(star) / 2)
    A_dot = sympy.Matrix(m, e, lambda k, i: sum(E.d2Psi[k][j][i, i].xreplace(star) * jet[m + j] for j in range(m)) / 2)
    held = {i for i, _ in rule.values} | {i for i, _, _ in rule.ratios}
    free = [i for i in range(e) if i not in held]
    M_red = A[:, free]
    for i, j, r in rule.ratios:
        M_red[:, free.index(j)] += r * r * A[:, i]
    fixed = sum((A[:, i] * v * v for i, v in rule.values), sympy.zeros(m, 1))
    M_inv = M_red.inv()
    w_free = M_inv * (-F - fixed)
    w = [sympy.Integer(0)] * e
    x = [sympy.Integer(0)] * e
    for k, i in enumerate(free):
        w[i], x[i] = w_free[k], desc.x_e_sign * sympy.sqrt(w_free[k])
    for i, v in rule.values:
        w[i], x[i] = sympy.Float(v * v), sympy.Float(v)
    for i, j, r in rule.ratios:
        w[i], x[i] = r * r * w[j], r * x[j]
    w_dot_free = M_inv * (-F_dot - A_dot * sympy.Matrix(w))
    x_dot = [sympy.Integer(0)] * e
    for k, i in enumerate(free):
        x_dot[i] = w_dot_free[k] / (2 * x[i])
    for i, j, r in rule.ratios:
        x_dot[i] = r * x_dot[j]
    return ClosedReference(jet, margin, F, tuple(w_free), (*jet[:m], *p, *x, *x_dot))


def least_reference_branch(desc: Description, ports: tuple[int, ...]) -> tuple[tuple[sympy.Expr, ...], tuple[sympy.Expr, ...]]:
    """One branch of a least-energy or least-input operating point (components.operating_point.solve and rate) in
    the jet of `jet_vector`: (w on `ports`, the feasible state (q*, p*, x_e*, x_e*')). n_m ports: a vertex of the
    linear program, w_B = A_B^-1 b; more ports: the even share of tied ports, w_T = A_T^T (A_T A_T^T)^-1 b; b = -F*,
    A_ki = (dPsi/dq_k)_ii / 2 at q*; x_e* = x_e_sign sqrt(w) on the ports, 0 elsewhere; x_e*' from A w' = -F*' - A' w
    (the even share differentiated: w_T' = A_T'^T y + A_T^T y', y = G^-1 b, y' = G^-1 (b' - (A_T' A_T^T + A_T A_T'^T) y),
    G = A_T A_T^T). Which branch holds at a jet is chosen numerically (components.c_codegen)."""
    E = plant_expressions(desc)
    jet = jet_vector(desc)
    m, e = desc.n_m, desc.n_e
    star = dict(zip(desc.q_symbols, jet[:m]))
    p, F, F_dot = force_jet(desc)
    A = sympy.Matrix(m, e, lambda k, i: E.dPsi[k][i, i].xreplace(star) / 2)
    A_dot = sympy.Matrix(m, e, lambda k, i: sum(E.d2Psi[k][j][i, i].xreplace(star) * jet[m + j] for j in range(m)) / 2)
    A_T, A_T_dot = A[:, list(ports)], A_dot[:, list(ports)]
    if len(ports) == m:
        A_inv = A_T.inv()
        w_T = A_inv * (-F)
        w_full = sympy.zeros(e, 1)
        for k, i in enumerate(ports):
            w_full[i] = w_T[k]
        w_dot = A_inv * (-F_dot - A_dot * w_full)
    else:
        G_inv = (A_T * A_T.T).inv()
        y = G_inv * (-F)
        y_dot = G_inv * (-F_dot - (A_T_dot * A_T.T + A_T * A_T_dot.T) * y)
        w_T = A_T.T * y
        w_dot = A_T_dot.T * y + A_T.T * y_dot
    x = [sympy.Integer(0)] * e
    x_dot = [sympy.Integer(0)] * e
    for k, i in enumerate(ports):
        x[i] = desc.x_e_sign * sympy.sqrt(w_T[k])
        x_dot[i] = w_dot[k] / (2 * x[i])
    return tuple(w_T), (*jet[:m], *p, *x, *x_dot)


def operating_point_costs(desc: Description) -> tuple[sympy.Expr, ...]:
    """The cost per unit of w_i = x_e_i^2 a least rule minimises (components.operating_point.weights), at q*:
    Psi_ii (least_energy) or ((R_e - J_e)_ii Psi_ii / G_e_ii)^2 (least_input)."""
    E = plant_expressions(desc)
    star = dict(zip(desc.q_symbols, jet_vector(desc)[:desc.n_m]))
    psi = [E.Psi[i, i].xreplace(star) for i in range(desc.n_e)]
    rule = desc.operating_point
    if rule is not None and rule.kind == "least_input":
        RJ = desc.R_e - desc.J_e
        return tuple((RJ[i, i] * psi[i] / desc.G_e[i, i]) ** 2 for i in range(desc.n_e))
    return tuple(psi)
