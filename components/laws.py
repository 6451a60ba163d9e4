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

from dataclasses import dataclass

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


def design_matrices(desc: Description, design: str, gain_names: tuple[str, ...]) -> DesignMatrices:
    """The DesignMatrices of `design` for a plant with n_m = n_e = 1 and constant mass (the DesignLaw's gains
    and reference: `design_law`)."""
    law_of = design_law(desc, design, gain_names)
    family = FAMILY[design]
    E = plant_expressions(desc)
    jet, subs = feasible_reference(desc)
    q_s, p_s, x_s, _ = _reference_symbols(desc)
    e = desc.n_e
    gains = {"R_e_bar": law_of.R_e_bar, "D_d": _design_gain(desc, gain_names, "D_d"),
             "W": _design_gain(desc, gain_names, "W"), "k_c": law_of.k_c}
    replace = {_matrix(n, e, e if n != "D_d" else desc.n_m)[0, 0]: v for n, v in gains.items()}
    if TRACKING[design]:
        reference: dict = {}
    else:
        q_d = sympy.Symbol("q_d", real=True)
        reference = {jet[0]: q_d, jet[1]: sympy.Integer(0), jet[2]: sympy.Integer(0), jet[3]: sympy.Integer(0)}
    target = {s: subs[r] for s, r in zip(E.eta, (*q_s, *p_s, *x_s))}

    def at_target(M: sympy.Matrix) -> sympy.Matrix:
        return M.xreplace(replace).xreplace(target).xreplace(reference)
    m = desc.n_m
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
