"""C99 printer of a described plant's model: the expressions of components.symbolic, printed as C.

`model_c_source(desc)` prints every model function of `plant_expressions(desc)` (the same sympy
expressions components.codegen prints as Python) as a C99 function with common subexpressions shared
(sympy.cse). Every function has the one signature

    void emc_<name>(const double *par, const double *eta, const double *u, double *out)

with `par` the description's parameters in their order, `eta` = (q, p, x_e), `u` the inputs and `out`
the values, row-major for matrices:

    V (1), grad_V (n_m), hess_V (n_m^2), Psi (n_e^2), dPsi (n_m n_e^2), d2Psi (n_m^2 n_e^2), M_inv (n_m^2),
    H (1), grad_H (n), hess_H (n^2), f (n: eq. open-loop elecmech), jacobian (n^2: df/deta), g (n n_e: df/du),
    margin (1: the event indicator at the domain boundary, +INFINITY without one)

and `emc_check_parameters(par)`: the index of the first parameter that violates its condition ("> 0",
">= 0", finite, TINY <= |value| <= HUGE, components.parameters.Parameter.check), -1 if none.

Every symbol is printed with a prefix (P_ parameters, S_ states, U_ inputs, T_ temporaries): a parameter
named `c` or `k` would otherwise collide with C identifiers. The header EMC_MODEL_SIZES gives the sizes.
"""
from __future__ import annotations

import math
import re
from itertools import combinations
from typing import Sequence

import sympy
from sympy.printing.c import C99CodePrinter

from .description import Description
from .parameters import HUGE, TINY
from .source_text import c_comment, c_string
from .symbolic import PlantExpressions, plant_expressions

FUNCTIONS = ("V", "grad_V", "hess_V", "Psi", "dPsi", "d2Psi", "M_inv", "H", "grad_H", "hess_H", "f", "jacobian", "g",
             "margin")


class _Printer(C99CodePrinter):
    """C99 with float literals that round-trip (repr), integers as doubles, pi and e as numbers."""

    def _print_Float(self, expr):
        return repr(float(expr))

    def _print_Integer(self, expr):
        return repr(float(expr))

    def _print_Rational(self, expr):
        return f"({float(expr.p)!r}/{float(expr.q)!r})"

    def _print_Pi(self, expr):
        return repr(math.pi)

    def _print_Exp1(self, expr):
        return repr(math.e)


def _c_name(prefix: str, name: str) -> str:
    return prefix + re.sub(r"[^0-9A-Za-z_]", "_", name)


def _flat(items) -> list[sympy.Expr]:
    out = []
    for item in items:
        if isinstance(item, sympy.MatrixBase):
            out.extend(item)
        else:
            out.append(item)
    return out


def model_values(E: PlantExpressions) -> dict[str, list[sympy.Expr]]:
    """The values of every C function (module docstring), flattened row-major."""
    margin = E.domain_margin
    return {
        "V": [E.V], "grad_V": list(E.grad_V), "hess_V": list(E.hess_V), "Psi": list(E.Psi),
        "dPsi": _flat(E.dPsi), "d2Psi": _flat(D for row in E.d2Psi for D in row), "M_inv": list(E.M_inv),
        "H": [E.H], "grad_H": list(E.grad_H), "hess_H": list(E.hess_H), "f": list(E.f),
        "jacobian": list(E.jacobian), "g": list(E.g),
        "margin": [sympy.oo if margin is None else margin],
    }


class CWriter:
    """Prints functions of one description's symbols (parameters, eta, u) as C."""

    def __init__(self, E: PlantExpressions, arrays: Sequence[tuple[str, str, Sequence[sympy.Symbol]]] | None = None):
        desc = E.desc
        self.arrays: list[tuple[str, str, Sequence[sympy.Symbol]]] = list(arrays or [
            ("par", "P_", desc.parameter_symbols), ("eta", "S_", E.eta), ("u", "U_", E.u)])
        self.rename: dict[sympy.Symbol, sympy.Symbol] = {}
        for _, prefix, symbols in self.arrays:
            for s in symbols:
                self.rename[s] = sympy.Symbol(_c_name(prefix, s.name), real=True)
        names = [s.name for s in self.rename.values()]
        if len(set(names)) != len(names):
            raise ValueError(f"{desc.source}: two symbols print as one C name ({sorted(names)})")
        self.printer = _Printer({"math_macros": {}})      # C99 has no M_SQRT2, M_PI: numbers instead

    def code(self, expr) -> str:
        if expr == sympy.oo:
            return "INFINITY"
        return self.printer.doprint(expr)

    def function(self, name: str, values: Sequence[sympy.Expr], doc: str) -> str:
        exprs = [sympy.sympify(v).xreplace(self.rename) for v in values]
        finite = [e if e != sympy.oo else sympy.Integer(0) for e in exprs]
        temps, reduced = sympy.cse(finite, symbols=sympy.numbered_symbols("T_"), order="none")
        used = set().union(*(e.free_symbols for e in finite)) if finite else set()
        arguments = ", ".join(f"const double *{array}" for array, _, _ in self.arrays)
        lines = [c_comment(doc), f"void emc_{name}({arguments}, double *out)", "{"]
        for array, _, symbols in self.arrays:
            for i, s in enumerate(symbols):
                c = self.rename[s]
                if c in used:
                    lines.append(f"    const double {c} = {array}[{i}];")
        unused = [a for a, _, symbols in self.arrays if not any(self.rename[s] in used for s in symbols)]
        for array in unused:
            lines.append(f"    (void){array};")
        for t, v in temps:
            lines.append(f"    const double {t} = {self.code(v)};")
        for i, (e, orig) in enumerate(zip(reduced, exprs)):
            lines.append(f"    out[{i}] = {'INFINITY' if orig == sympy.oo else self.code(e)};")
        lines.append("}")
        return "\n".join(lines)


DOCS = {
    "V": "potential energy V(q) [J]", "grad_V": "grad V(q)", "hess_V": "Hessian of V (row-major)",
    "Psi": "Psi(q) of eq. (elec energy)", "dPsi": "d Psi / d q_k (k major)", "d2Psi": "d^2 Psi / d q_k d q_l",
    "M_inv": "M(q)^-1", "H": "H(eta) of eq. (open-loop elecmech)", "grad_H": "grad H(eta)", "hess_H": "Hessian of H (row-major)",
    "f": "eta' = F grad H + g u, eq. (open-loop elecmech)", "jacobian": "df/deta = F hess H (row-major)",
    "g": "df/du = [0; 0; G_e] (row-major)", "margin": "the margin to the boundary of the admissible domain",
}


def _check_parameters(desc: Description) -> str:
    """emc_check_parameters: Parameter.check's conditions, in C."""
    lines = ["/* the index of the first parameter that violates its condition (components.parameters), -1 if none */",
             "int emc_check_parameters(const double *par)", "{"]
    for i, p in enumerate(desc.parameters.values()):
        cond = {"> 0": f"par[{i}] > 0.0", ">= 0": f"par[{i}] >= 0.0", "any": "1"}[p.condition]
        lines.append(f"    if (!(isfinite(par[{i}]) && {cond} && (par[{i}] == 0.0 || "
                     f"(fabs(par[{i}]) >= {TINY!r} && fabs(par[{i}]) <= {HUGE!r})))) return {i};")
    lines += ["    return -1;", "}"]
    return "\n".join(lines)


def _generated_by(desc: Description) -> str:
    """The first line of a generated C file: what made it from which description (its sha256: never its path or
    text, issue 40)."""
    return c_comment(f"Generated by components.c_codegen from the description with sha256 {desc.sha256}; do not edit.")


def model_c_source(desc: Description) -> str:
    """The C99 source of the model functions of `desc` (module docstring)."""
    E = plant_expressions(desc)
    w = CWriter(E)
    n = 2 * desc.n_m + desc.n_e
    head = [_generated_by(desc), c_comment(f"{desc.name}: the model functions of eq. (open-loop elecmech) in C99."),
            "#include <math.h>", '#include "emc_model.h"', "",
            f"const int EMC_MODEL_SIZES[4] = {{{desc.n_m}, {desc.n_e}, {n}, {len(desc.parameters)}}};"
            "   /* n_m, n_e, n, parameters */", ""]
    body = [w.function(name, values, DOCS[name]) for name, values in model_values(E).items()]
    return "\n".join(head) + "\n" + "\n\n".join(body + [_check_parameters(desc)]) + "\n"


MODEL_HEADER = """/* The model functions a generated plant model supplies (components.c_codegen). */
#ifndef EMC_MODEL_H
#define EMC_MODEL_H

extern const int EMC_MODEL_SIZES[4];   /* n_m, n_e, n = 2 n_m + n_e, number of parameters */

#define EMC_MODEL_FUNCTION(name) void emc_##name(const double *par, const double *eta, const double *u, double *out)
EMC_MODEL_FUNCTION(V);
EMC_MODEL_FUNCTION(grad_V);
EMC_MODEL_FUNCTION(hess_V);
EMC_MODEL_FUNCTION(Psi);
EMC_MODEL_FUNCTION(dPsi);
EMC_MODEL_FUNCTION(d2Psi);
EMC_MODEL_FUNCTION(M_inv);
EMC_MODEL_FUNCTION(H);
EMC_MODEL_FUNCTION(grad_H);
EMC_MODEL_FUNCTION(hess_H);
EMC_MODEL_FUNCTION(f);
EMC_MODEL_FUNCTION(jacobian);
EMC_MODEL_FUNCTION(g);
EMC_MODEL_FUNCTION(margin);
int emc_check_parameters(const double *par);

#endif
"""

def law_c_source(desc: Description, families: Sequence[str], tracking: bool) -> str:
    """C99 functions of the control laws of components.laws, one per family ("c1", "u2"):

        void emc_law_<family>(const double *par, const double *gain, const double *eta, const double *ref,
                              double *out)

    gain: the law's gains (components.laws.Law.gains order); ref: the jet (q*, dq*/dt, d2q*/dt2, d3q*/dt3)
    when `tracking` (one-degree-of-freedom plants: Definition 1 in closed form), else the feasible reference
    (q*, p*, x_e*, dx_e*/dt); out: u (n_e)."""
    from .laws import law, tracking_law
    E = plant_expressions(desc)
    head = [_generated_by(desc), c_comment(f"{desc.name}: the control laws of components.laws in C99."),
            "#include <math.h>", ""]
    body = []
    for family in families:
        stated = tracking_law(desc, family) if tracking else law(desc, family)
        w = CWriter(E, [("par", "P_", desc.parameter_symbols), ("gain", "K_", stated.gains), ("eta", "S_", E.eta),
                        ("ref", "R_", stated.reference)])
        body.append(w.function(f"law_{family}", list(stated.u), f"u of {stated.equations}"))
    return "\n".join(head) + "\n" + "\n\n".join(body) + "\n"


def _check_values(name: str, parameters: Sequence, what: str) -> str:
    """int emc_<name>(const double *values): Parameter.check's conditions of `parameters`, in C."""
    lines = [f"/* the index of the first {what} that violates its condition (components.parameters), -1 if none */",
             f"int emc_{name}(const double *values)", "{"]
    for i, p in enumerate(parameters):
        cond = {"> 0": f"values[{i}] > 0.0", ">= 0": f"values[{i}] >= 0.0", "any": "1"}[p.condition]
        lines.append(f"    if (!(isfinite(values[{i}]) && {cond} && (values[{i}] == 0.0 || "
                     f"(fabs(values[{i}]) >= {TINY!r} && fabs(values[{i}]) <= {HUGE!r})))) return {i};")
    lines += ["    return -1;", "}"]
    return "\n".join(lines)


def _design_gains(desc: Description, design: str, gain_names: Sequence[str]) -> dict[str, sympy.Matrix]:
    """q_d, R_e_bar, D_d and W or k_c of `design` as matrices in its FMU's gain parameters (components.described.
    make_device names the entries: q_d, R_e_bar, ... for 1 x 1, else q_d_1, R_e_bar_1_2, ...), a device's own form
    (MEMS: R_e_bar = 1/rbar_e), the numbers of the [controller] table, or W = I (the paper's Phi_1 / Theta_1)."""
    from .description import gain_table
    defaults, forms, _ = gain_table(desc)
    symbols = {n: sympy.Symbol(n, real=True) for n in gain_names}
    m, e = desc.n_m, desc.n_e
    shapes = {"q_d": (m, 1), "R_e_bar": (e, e), "D_d": (e, m), "k_c": (e, e), "W": (e, e)}

    def entry(gain: str, i: int, j: int) -> str:
        r, c = shapes[gain]
        if r * c == 1:
            return gain
        return f"q_d_{i + 1}" if gain == "q_d" else f"{gain}_{i + 1}_{j + 1}"

    out = {}
    for gain, (r, c) in shapes.items():
        names = [[entry(gain, i, j) for j in range(c)] for i in range(r)]
        if all(n in symbols for row in names for n in row):
            out[gain] = sympy.Matrix(r, c, lambda i, j: symbols[names[i][j]])
        elif gain in forms:
            out[gain] = sympy.Matrix(forms[gain][0]).reshape(r, c)
        elif gain in defaults:
            out[gain] = sympy.Matrix(r, c, lambda i, j: sympy.Float(defaults[gain][i][j]))
        elif gain == "W":
            out[gain] = sympy.eye(e)
        elif gain != "q_d" or design in ("Proposition1", "Proposition2"):
            raise ValueError(f"{desc.source}: design {design} has no gain {gain}")
    return out


STRICT_PH = {"Proposition1": 1, "Proposition2": 0, "Theorem2": -1, "Theorem3": -1}   # eq. (pHcondition)


def controller_c_source(desc: Description, design: str, gain_parameters: Sequence) -> str:
    """C99 of a controller FMU's law (any n_m, n_e, M(q)): the law of components.laws in the FMU's inputs and gains,
    the feasible reference of Definition 1 (closed form: components.laws.closed_reference; Newton for n_e = n_m:
    components.laws.newton_reference, the iteration of components.described.DescribedPlant._solve_real), and

        const char *emc_ctrl_law(par, gain, in, u, du)   u (n_e) and, if du is not NULL, du/d in (n_e x inputs,
                                                         row-major); NULL, or why the reference is not feasible
        int emc_ctrl_check(par, gain, why, size)         the controller's construction checks (components.
                                                         closed_loop, components.controller): 0, or 1 and why
        int emc_check_gains(gain)                        the gain parameters' conditions

    (fmus/native/emc_controller.h). ValueError for a plant whose feasible reference has no native form yet."""
    from .laws import (
        FAMILY,
        TRACKING,
        closed_reference,
        jet_vector,
        law,
        least_reference_branch,
        newton_reference,
        operating_point_costs,
    )
    names = tuple(p.name for p in gain_parameters)
    family, tracking = FAMILY[design], TRACKING[design]
    m, e = desc.n_m, desc.n_e
    if e < m:
        raise ValueError(f"{desc.source}: n_e = {e} < n_m = {m}: the force balance of Definition 1 is overdetermined "
                         "(the pythonfmu controller has no feasible reference either)")
    n = 2 * m + e
    G = _design_gains(desc, design, names)
    weight = "W" if family == "c1" else "k_c"
    stated = law(desc, family)
    values = [*G["R_e_bar"], *G["D_d"], *G[weight]]
    u = stated.u.xreplace(dict(zip(stated.gains, values)))
    E = plant_expressions(desc)
    gains = tuple(sympy.Symbol(x, real=True) for x in names)
    jet = jet_vector(desc)
    par = ("par", "P_", desc.parameter_symbols)
    gain = ("gain", "K_", gains)
    w_law = CWriter(E, [par, gain, ("in", "I_", E.eta), ("ref", "R_", stated.reference)])
    variables = list(E.eta) + list(stated.reference)
    functions = [
        w_law.function("ctrl_u", list(u), f"u of {design}: {stated.equations} (components.laws)"),
        w_law.function("ctrl_du", [u[i].diff(s) for i in range(e) for s in variables],
                       "du / d(q, p, x_e, q*, p*, x_e*, x_e*') (row-major), symbolic"),
    ]
    if not tracking:
        q_d = G["q_d"]
        w_jet = CWriter(E, [par, gain, ("in", "I_", E.eta)])
        functions.append(w_jet.function("ctrl_jet", [*q_d, *([sympy.Integer(0)] * (3 * m))],
                                        "the constant reference jet (q_d, 0, 0, 0) of regulation"))
    w_ref = CWriter(E, [par, gain, ("jet", "J_", jet)])
    rule = desc.operating_point
    tables = ""
    if e > m and (rule is None or rule.kind != "bias"):
        if any(sympy.simplify(D[i, j]) != 0 for D in (E.Psi, *E.dPsi) for i in range(e) for j in range(e) if i != j):
            raise ValueError(f"{desc.source}: an operating point for n_e = {e} > n_m = {m} needs diagonal Psi(q) and "
                             "dPsi/dq_k (components.operating_point): not available for coupled coils")
        kind, n_conditions = "least", 0
        vertices = list(combinations(range(e), m))
        branches = vertices + [T for k in range(m + 1, e + 1) for T in combinations(range(e), k)]
        star = dict(zip(desc.q_symbols, jet[:m]))
        A = [E.dPsi[k][i, i].xreplace(star) / 2 for k in range(m) for i in range(e)]
        margin = sympy.oo if E.domain_margin is None else E.domain_margin.xreplace(star)
        F = _required_force(desc)
        functions.append(w_ref.function("ctrl_select", [margin, *F, *A, *(-F), *operating_point_costs(desc)],
                                        "(margin of q*, F*, A_ki = (dPsi/dq_k)_ii / 2, b = -F*, the rule's costs) at q*"))
        for index, ports in enumerate(branches):
            w, state = least_reference_branch(desc, ports)
            functions.append(w_ref.function(f"ctrl_state_{index}", [*w, *state],
                                            f"(w, q*, p*, x_e*, x_e*') with the ports {ports} energized"))
            if tracking:
                functions.append(w_ref.function(f"ctrl_dstate_{index}", [x.diff(j) for x in state for j in jet],
                                                f"d(q*, p*, x_e*, x_e*') / d jet with the ports {ports} (row-major)"))
        tables = _branch_tables(branches, e, len(vertices), tracking)
    elif (m == 1 and e == 1 and desc.constant_mass) or e > m:
        R = closed_reference(desc)
        kind, n_conditions = "closed", len(R.conditions)
        functions.append(w_ref.function("ctrl_feasibility", [R.margin, *R.F, *R.conditions],
                                        "(margin of q* to the domain's boundary, F*, what must be > 0: Definition 1)"))
        functions.append(w_ref.function("ctrl_state", list(R.state), "(q*, p*, x_e*, x_e*') of Definition 1"))
        if tracking:
            functions.append(w_ref.function("ctrl_dstate", [s.diff(j) for s in R.state for j in jet],
                                            "d(q*, p*, x_e*, x_e*') / d jet (row-major)"))
    else:
        N = newton_reference(desc)
        kind, n_conditions = "newton", 0
        functions.append(w_ref.function("ctrl_force", [N.margin, *N.F, *(x for D in N.dPsi for x in D)],
                                        "(margin of q* to the domain's boundary, F*, dPsi/dq_k(q*) k-major)"))
        w_x = CWriter(E, [par, gain, ("jet", "J_", jet), ("xs", "X_", N.x + N.x_dot)])
        functions.append(w_x.function("ctrl_rate", [*N.A, *N.b, *N.p], "(A, b, p*): A x_e*' = b, p* = M(q*) q*'"))
        if tracking:
            functions.append(w_x.function(
                "ctrl_sens", [*N.R_1.jacobian(jet), *N.R_2.jacobian(jet), *N.R_2.jacobian(N.x), *N.p.jacobian(jet)],
                "(dR_1/d jet, dR_2/d jet, dR_2/d(x_e*), d(p*)/d jet), row-major: the implicit function theorem"))
    Rs = (G["R_e_bar"] + G["R_e_bar"].T) / 2
    check_weight = not (weight == "W" and G["W"] == sympy.eye(e))
    S = desc.R_m - G["D_d"].T * Rs.inv() * G["D_d"] / 4 if STRICT_PH[design] >= 0 else sympy.zeros(m, m)
    functions.append(CWriter(E, [par, gain]).function(
        "ctrl_matrices", [*Rs, *G[weight], *S, *desc.R_m],
        "(R_e_bar's symmetric part, the weight W or K_c, R_m - 1/4 D_d^T R_e_bar^-1 D_d, R_m): components.closed_loop"))
    functions.append(_check_values("check_gains", gain_parameters, "gain parameter"))
    head = [_generated_by(desc), c_comment(f"{desc.name}: the {design} law."),
            "#include <math.h>", "#include <stdio.h>", "#include <string.h>", '#include "emc_controller.h"', "",
            f"#define NM {m}", f"#define NE {e}", f"#define NS {n}", f"#define NR {2 * m + 2 * e}",
            f"#define NJ {4 * m}", f"#define NC {n_conditions}", "#define NI EMC_N_CONTROLLER_INPUTS",
            f"#define X_E_SIGN {float(desc.x_e_sign)!r}", f"#define TRACKING {int(tracking)}",
            f"#define STRICT_PH {STRICT_PH[design]}", f"#define CHECK_WEIGHT {int(check_weight)}",
            f"#define WEIGHT_NAME {c_string(weight)}", ""]
    if design_checks_available(desc):
        functions.append(design_checks_c_source(desc, design, gain_parameters))
    glue = _CONTROLLER_GLUE + {"closed": _CLOSED_REFERENCE, "newton": _NEWTON_REFERENCE,
                               "least": _SOLVE + tables + _LEAST_REFERENCE}[kind] + _CONTROLLER_LAW
    return "\n".join(head) + "\n" + "\n\n".join(functions) + "\n" + glue


def _required_force(desc: Description) -> sympy.Matrix:
    """F* of components.laws.force_jet (the force the reference needs)."""
    from .laws import force_jet
    return force_jet(desc)[1]


def _branch_tables(branches: list[tuple[int, ...]], e: int, n_vertices: int, tracking: bool) -> str:
    """The C tables of a least rule's branches: their ports and their generated functions."""
    rows = ", ".join("{" + ", ".join(str(i) for i in (*ports, *([-1] * (e - len(ports))))) + "}" for ports in branches)
    lines = [f"#define NB {n_vertices}                  /* the vertices: n_m of the n_e ports */",
             f"#define NT {len(branches)}                  /* and the even shares of more ports */",
             "typedef void (*emc_branch)(const double *par, const double *gain, const double *jet, double *out);",
             f"static const int BRANCH_SIZE[NT] = {{{', '.join(str(len(b)) for b in branches)}}};",
             f"static const int BRANCH_PORTS[NT][NE] = {{{rows}}};",
             f"static const emc_branch STATE[NT] = {{{', '.join(f'emc_ctrl_state_{i}' for i in range(len(branches)))}}};"]
    if tracking:
        lines.append(f"static const emc_branch DSTATE[NT] = "
                     f"{{{', '.join(f'emc_ctrl_dstate_{i}' for i in range(len(branches)))}}};")
    return "\n".join(lines) + "\n"


# The hand-written C around the generated functions: bounded loops only (stated in each comment).
_CONTROLLER_GLUE = r"""
#define DIM (NM > NE ? NM : NE)
#define NEWTON_ITERATIONS 100        /* components.described.DescribedPlant._solve_real */
#define JACOBI_SWEEPS 64             /* cyclic Jacobi: quadratic convergence, a few sweeps in practice */

#define OUTSIDE "q* is outside the domain"
#define INFEASIBLE "no real x_e* balances the force the reference needs"
#define NOT_FINITE "the reference (q*, p*, x_e*, x_e*') or its Jacobian overflows at these inputs"
/* the smallest eigenvalue of the symmetric part of an n x n matrix (numpy's eigvalsh), by cyclic Jacobi rotations
   (at most JACOBI_SWEEPS sweeps) */
static double min_eigenvalue(int n, const double *M)
{
    double a[DIM * DIM], low;
    int i, j, k, sweep;
    for (i = 0; i < n; i++)
        for (j = 0; j < n; j++) a[i * n + j] = 0.5 * (M[i * n + j] + M[j * n + i]);
    for (sweep = 0; sweep < JACOBI_SWEEPS; sweep++) {
        double off = 0.0, diagonal = 0.0;
        for (i = 0; i < n; i++) {
            diagonal += a[i * n + i] * a[i * n + i];
            for (j = i + 1; j < n; j++) off += a[i * n + j] * a[i * n + j];
        }
        if (!(off > 1e-34 * diagonal)) break;
        for (i = 0; i < n; i++)
            for (j = i + 1; j < n; j++) {
                double theta, t, c, s, tau, apq = a[i * n + j];
                if (apq == 0.0) continue;
                theta = (a[j * n + j] - a[i * n + i]) / (2.0 * apq);
                t = fabs(theta) > 1e150 ? 0.5 / theta : (theta >= 0 ? 1.0 : -1.0) / (fabs(theta) + sqrt(theta * theta + 1.0));
                c = 1.0 / sqrt(t * t + 1.0);
                s = t * c;
                tau = s / (1.0 + c);
                a[i * n + i] -= t * apq;
                a[j * n + j] += t * apq;
                a[i * n + j] = a[j * n + i] = 0.0;
                for (k = 0; k < n; k++) {
                    double akp, akq;
                    if (k == i || k == j) continue;
                    akp = a[k * n + i];
                    akq = a[k * n + j];
                    a[k * n + i] = a[i * n + k] = akp - s * (akq + tau * akp);
                    a[k * n + j] = a[j * n + k] = akq + s * (akp - tau * akq);
                }
            }
    }
    low = a[0];
    for (i = 1; i < n; i++) low = fmin(low, a[i * n + i]);
    return low;
}

static int all_zero(int n, const double *v)
{
    int i;
    for (i = 0; i < n; i++)
        if (v[i] != 0.0) return 0;
    return 1;
}

static int all_finite(int n, const double *v)
{
    int i;
    for (i = 0; i < n; i++)
        if (!isfinite(v[i])) return 0;
    return 1;
}

/* the constructor's checks of components.controller and components.closed_loop: R_e_bar > 0 (eq. barRe), the
   weight W or K_c symmetric positive definite, eq. (pHcondition) (strictly for Proposition 1, weakly for
   Proposition 2); 0, or 1 with the reason in why */
int emc_ctrl_check(const double *par, const double *gain, char *why, size_t size)
{
    double g[2 * NE * NE + 2 * NM * NM], low, scale = 1.0;
    int i, j;
    emc_ctrl_matrices(par, gain, g);
    low = min_eigenvalue(NE, g);
    if (!(low > 0.0)) {
        snprintf(why, size, "R_e_bar violates R_e_bar = R_e + K_e > 0 (eq. barRe; smallest eigenvalue %.3g)", low);
        return 1;
    }
    if (CHECK_WEIGHT) {
        const double *W = g + NE * NE;
        for (i = 0; i < NE; i++)
            for (j = 0; j < NE; j++)
                if (!(fabs(W[i * NE + j] - W[j * NE + i]) <= 1e-8 + 1e-5 * fabs(W[j * NE + i]))) {
                    snprintf(why, size, "%s violates %s > 0 (symmetric positive definite): it is not symmetric",
                             WEIGHT_NAME, WEIGHT_NAME);
                    return 1;
                }
        low = min_eigenvalue(NE, W);
        if (!(low > 0.0)) {
            snprintf(why, size, "%s violates %s > 0 (symmetric positive definite; smallest eigenvalue %.3g)",
                     WEIGHT_NAME, WEIGHT_NAME, low);
            return 1;
        }
    }
    if (STRICT_PH >= 0) {
        low = min_eigenvalue(NM, g + 2 * NE * NE);
        for (i = 0; i < NM * NM; i++) scale = fmax(scale, fabs(g[2 * NE * NE + NM * NM + i]));
        if (STRICT_PH == 1 ? !(low > 0.0) : !(low >= -1e-12 * scale)) {
            snprintf(why, size, "D_d violates the pH condition (eq. pHcondition) R_m - 1/4 D_d^T R_e_bar^-1 D_d %s 0 "
                     "(smallest eigenvalue %.3g)", STRICT_PH == 1 ? ">" : ">=", low);
            return 1;
        }
    }
    return 0;
}
"""

_CLOSED_REFERENCE = r"""
/* (q*, p*, x_e*, x_e*') of the jet in closed form (components.laws.closed_reference) and, if dref is not NULL, its
   Jacobian in the jet (NR x NJ); NULL, or why it does not exist */
static const char *reference(const double *par, const double *gain, const double *jet, double *ref, double *dref)
{
    double feasibility[1 + NM + NC];
    int i;
    emc_ctrl_feasibility(par, gain, jet, feasibility);
    if (!(feasibility[0] > 0.0)) return OUTSIDE;
    if (!TRACKING && all_zero(NM, feasibility + 1)) {   /* grad V(q_d) = 0: x_e_d = 0 (EMPlant.equilibrium) */
        memset(ref, 0, sizeof(double) * NR);
        for (i = 0; i < NM; i++) ref[i] = jet[i];
        return NULL;
    }
    for (i = 0; i < NC; i++)
        if (!(feasibility[1 + NM + i] > 0.0)) return INFEASIBLE;
    emc_ctrl_state(par, gain, jet, ref);
#if TRACKING
    if (dref != NULL) emc_ctrl_dstate(par, gain, jet, dref);
#else
    (void)dref;
#endif
    return NULL;
}
"""

_SOLVE = r"""
/* A x = b for an n x n matrix A (row-major, destroyed) and nrhs right-hand sides b (n x nrhs, row-major, replaced by
   the solution), by Gaussian elimination with partial pivoting: 0, or -1 when A is singular */
static int solve(int n, double *A, int nrhs, double *b)
{
    int i, j, k, r;
    for (k = 0; k < n; k++) {
        int pivot = k;
        for (i = k + 1; i < n; i++)
            if (fabs(A[i * n + k]) > fabs(A[pivot * n + k])) pivot = i;
        if (!(fabs(A[pivot * n + k]) > 0.0) || !isfinite(A[pivot * n + k])) return -1;
        if (pivot != k) {
            for (j = 0; j < n; j++) { double t = A[k * n + j]; A[k * n + j] = A[pivot * n + j]; A[pivot * n + j] = t; }
            for (r = 0; r < nrhs; r++) {
                double t = b[k * nrhs + r];
                b[k * nrhs + r] = b[pivot * nrhs + r];
                b[pivot * nrhs + r] = t;
            }
        }
        for (i = k + 1; i < n; i++) {
            double f = A[i * n + k] / A[k * n + k];
            for (j = k; j < n; j++) A[i * n + j] -= f * A[k * n + j];
            for (r = 0; r < nrhs; r++) b[i * nrhs + r] -= f * b[k * nrhs + r];
        }
    }
    for (k = n - 1; k >= 0; k--)
        for (r = 0; r < nrhs; r++) {
            double s = b[k * nrhs + r];
            for (j = k + 1; j < n; j++) s -= A[k * n + j] * b[j * nrhs + r];
            b[k * nrhs + r] = s / A[k * n + k];
        }
    return 0;
}

"""

_NEWTON_REFERENCE = _SOLVE + r"""
#define NEWTON_FAILED "Newton's method (100 iterations) found no real x_e* that balances the force the reference needs"
#define SINGULAR "the force balance's Jacobian A_ki = (dPsi/dq_k x_e*)_i is singular"

/* the 2-norm condition number of an n x n matrix (numpy's cond): the ratio of its largest to its smallest singular
   value, by one-sided Jacobi rotations (at most JACOBI_SWEEPS sweeps); INFINITY for a singular matrix */
static double condition(int n, const double *A)
{
    double U[DIM * DIM], high = 0.0, low = INFINITY;
    int i, p, q, sweep;
    memcpy(U, A, sizeof(double) * (size_t)(n * n));
    for (sweep = 0; sweep < JACOBI_SWEEPS; sweep++) {
        int rotated = 0;
        for (p = 0; p < n; p++)
            for (q = p + 1; q < n; q++) {
                double alpha = 0.0, beta = 0.0, gamma = 0.0, zeta, t, c, s;
                for (i = 0; i < n; i++) {
                    alpha += U[i * n + p] * U[i * n + p];
                    beta += U[i * n + q] * U[i * n + q];
                    gamma += U[i * n + p] * U[i * n + q];
                }
                if (!(fabs(gamma) > 1e-15 * sqrt(alpha * beta))) continue;
                rotated = 1;
                zeta = (beta - alpha) / (2.0 * gamma);
                t = (zeta >= 0 ? 1.0 : -1.0) / (fabs(zeta) + sqrt(1.0 + zeta * zeta));
                c = 1.0 / sqrt(1.0 + t * t);
                s = c * t;
                for (i = 0; i < n; i++) {
                    double up = U[i * n + p], uq = U[i * n + q];
                    U[i * n + p] = c * up - s * uq;
                    U[i * n + q] = s * up + c * uq;
                }
            }
        if (!rotated) break;
    }
    for (p = 0; p < n; p++) {
        double norm = 0.0;
        for (i = 0; i < n; i++) norm += U[i * n + p] * U[i * n + p];
        norm = sqrt(norm);
        high = fmax(high, norm);
        low = fmin(low, norm);
    }
    return low > 0.0 ? high / low : INFINITY;
}

static double norm2(int n, const double *v)
{
    double s = 0.0;
    int i;
    for (i = 0; i < n; i++) s += v[i] * v[i];
    return sqrt(s);
}


/* r_k = -1/2 x^T dPsi_k x - F_k */
static void residual(const double *F, const double *D, const double *x, double *r)
{
    int i, j, k;
    for (k = 0; k < NM; k++) {
        double s = 0.0;
        for (i = 0; i < NE; i++)
            for (j = 0; j < NE; j++) s += x[i] * D[(k * NE + i) * NE + j] * x[j];
        r[k] = -0.5 * s - F[k];
    }
}

/* the real x with -1/2 x^T dPsi_k x = F_k (k = 1..n_m) by damped Newton from x_e_sign * (a common magnitude): the
   iteration, start, tolerances and failures of components.described.DescribedPlant._solve_real; at most
   NEWTON_ITERATIONS iterations of at most 14 step halvings each. 0, or -1 when it finds none */
static int newton(const double *F, const double *D, double *x)
{
    double max_F = 0.0, max_D = 0.0, scale, r[NE], A[NE * NE], LU[NE * NE], step[NE], x_new[NE], trial[NE], norm, t;
    int i, j, k, iteration;
    for (k = 0; k < NM; k++) max_F = fmax(max_F, fabs(F[k]));
    for (k = 0; k < NM * NE * NE; k++) max_D = fmax(max_D, fabs(D[k]));
    scale = sqrt(2.0 * max_F / fmax(max_D, 1e-300));
    if (scale == 0.0) scale = 1.0;
    for (i = 0; i < NE; i++) x[i] = X_E_SIGN * scale;
    for (iteration = 0; iteration < NEWTON_ITERATIONS; iteration++) {
        residual(F, D, x, r);
        for (k = 0; k < NM; k++)
            for (i = 0; i < NE; i++) {
                double s = 0.0;
                for (j = 0; j < NE; j++) s += D[(k * NE + i) * NE + j] * x[j];
                A[k * NE + i] = -s;
            }
        for (k = 0; k < NE * NE; k++)
            if (!isfinite(A[k])) return -1;
        if (condition(NE, A) > 1e14) return -1;
        memcpy(LU, A, sizeof LU);
        memcpy(step, r, sizeof step);
        if (solve(NE, LU, 1, step) != 0) return -1;
        t = 1.0;
        norm = norm2(NM, r);
        while (t > 1e-4) {
            for (i = 0; i < NE; i++) x_new[i] = x[i] - t * step[i];
            residual(F, D, x_new, trial);
            if (norm2(NM, trial) < norm) break;
            t /= 2;
        }
        memcpy(x, x_new, sizeof x_new);
        for (i = 0; i < NE; i++) trial[i] = t * step[i];
        if (norm2(NE, trial) <= 1e-15 * fmax(norm2(NE, x), 1e-300)) {
            residual(F, D, x, r);
            return norm2(NM, r) <= 1e-10 * fmax(norm2(NM, F), 1e-300) ? 0 : -1;
        }
    }
    return -1;
}

/* (q*, p*, x_e*, x_e*') of the jet, x_e* by Newton (components.laws.newton_reference) and, if dref is not NULL, its
   Jacobian in the jet (NR x NJ) by the implicit function theorem; NULL, or why it does not exist */
static const char *reference(const double *par, const double *gain, const double *jet, double *ref, double *dref)
{
    double force[1 + NM + NM * NE * NE], xs[2 * NE], rate[NE * NE + NE + NM], A[NE * NE];
    int i;
    emc_ctrl_force(par, gain, jet, force);
    if (!(force[0] > 0.0)) return OUTSIDE;
    memset(ref, 0, sizeof(double) * NR);
    for (i = 0; i < NM; i++) ref[i] = jet[i];
    if (!TRACKING && all_zero(NM, force + 1)) return NULL;   /* grad V(q_d) = 0: x_e_d = 0 (EMPlant.equilibrium) */
    if (newton(force + 1, force + 1 + NM, xs) != 0) return NEWTON_FAILED;
    for (i = 0; i < NE; i++) xs[NE + i] = 0.0;
    emc_ctrl_rate(par, gain, jet, xs, rate);
    memcpy(A, rate, sizeof A);
    memcpy(xs + NE, rate + NE * NE, sizeof(double) * NE);
    if (solve(NE, A, 1, xs + NE) != 0) return SINGULAR;
    memcpy(ref + NM, rate + NE * NE + NE, sizeof(double) * NM);
    memcpy(ref + 2 * NM, xs, sizeof xs);
#if TRACKING
    if (dref != NULL) {
        double sens[2 * NE * NJ + NE * NE + NM * NJ], dx[NE * NJ], dxd[NE * NJ];
        int j, k;
        emc_ctrl_sens(par, gain, jet, xs, sens);
        memcpy(dx, sens, sizeof dx);                                   /* d x_e* / d jet = A^-1 dR_1/d jet */
        memcpy(A, rate, sizeof A);
        if (solve(NE, A, NJ, dx) != 0) return SINGULAR;
        for (i = 0; i < NE; i++)                                       /* dR_2/d jet + dR_2/d x_e* (d x_e* / d jet) */
            for (j = 0; j < NJ; j++) {
                double s = sens[NE * NJ + i * NJ + j];
                for (k = 0; k < NE; k++) s += sens[2 * NE * NJ + i * NE + k] * dx[k * NJ + j];
                dxd[i * NJ + j] = s;
            }
        memcpy(A, rate, sizeof A);
        if (solve(NE, A, NJ, dxd) != 0) return SINGULAR;
        memset(dref, 0, sizeof(double) * NR * NJ);
        for (i = 0; i < NM; i++) dref[i * NJ + i] = 1.0;
        memcpy(dref + NM * NJ, sens + 2 * NE * NJ + NE * NE, sizeof(double) * NM * NJ);
        memcpy(dref + 2 * NM * NJ, dx, sizeof dx);
        for (i = 0; i < NE * NJ; i++) dref[(2 * NM + NE) * NJ + i] = -dxd[i];
    }
#else
    (void)dref;
#endif
    return NULL;
}
"""

_LEAST_REFERENCE = r"""
#define OVERFLOW "the force balance A(q*) w = -F* or a branch's cost is not finite at this jet (an overflow)"
#define NO_BRANCH "no branch of the operating point holds at this jet"
/* the determinant of an n x n matrix (numpy's det: LU with partial pivoting) */
static double determinant(int n, const double *M)
{
    double a[NE * NE], det = 1.0;
    int i, j, k;
    memcpy(a, M, sizeof(double) * (size_t)(n * n));
    for (k = 0; k < n; k++) {
        int pivot = k;
        for (i = k + 1; i < n; i++)
            if (fabs(a[i * n + k]) > fabs(a[pivot * n + k])) pivot = i;
        if (a[pivot * n + k] == 0.0) return 0.0;
        if (pivot != k) {
            for (j = 0; j < n; j++) { double t = a[k * n + j]; a[k * n + j] = a[pivot * n + j]; a[pivot * n + j] = t; }
            det = -det;
        }
        det *= a[k * n + k];
        for (i = k + 1; i < n; i++) {
            double f = a[i * n + k] / a[k * n + k];
            for (j = k; j < n; j++) a[i * n + j] -= f * a[k * n + j];
        }
    }
    return det;
}

/* (q*, p*, x_e*, x_e*') of the jet with the least-energy or least-input operating point (components.operating_point
   .solve: the vertex of least cost among the NB choices of n_m ports, the even share where several ports tie) and,
   if dref is not NULL, its Jacobian in the jet; NULL, or why it does not exist */
static const char *reference(const double *par, const double *gain, const double *jet, double *ref, double *dref)
{
    double s[1 + NM + NM * NE + NM + NE], cost[NB], out[NE + NR], best = INFINITY;
    const double *A = s + 1 + NM, *b = A + NM * NE, *psi = b + NM;
    int tied[NE], i, k, v, found = 0, count = 0, chosen = -1;
    emc_ctrl_select(par, gain, jet, s);
    if (!(s[0] > 0.0)) return OUTSIDE;
    if (!all_finite(NM + NM * NE + NM + NE, s + 1)) return OVERFLOW;   /* F*, A, b, the costs: operating_point.solve */
    if (!TRACKING && all_zero(NM, s + 1)) {        /* grad V(q_d) = 0: x_e_d = 0 (EMPlant.equilibrium) */
        memset(ref, 0, sizeof(double) * NR);
        for (i = 0; i < NM; i++) ref[i] = jet[i];
        return NULL;
    }
    for (v = 0; v < NB; v++) {
        double AB[NM * NM], w[NM], scale = 0.0;
        cost[v] = NAN;
        for (k = 0; k < NM; k++)
            for (i = 0; i < NM; i++) {
                AB[k * NM + i] = A[k * NE + BRANCH_PORTS[v][i]];
                scale = fmax(scale, fabs(AB[k * NM + i]));
            }
        if (fabs(determinant(NM, AB)) <= 1e-14 * pow(fmax(scale, 1e-300), NM)) continue;
        memcpy(w, b, sizeof w);
        if (solve(NM, AB, 1, w) != 0) continue;
        for (i = 0; i < NM && w[i] >= 0.0; i++) {}
        if (i < NM) continue;
        cost[v] = 0.0;
        for (i = 0; i < NM; i++) cost[v] += psi[BRANCH_PORTS[v][i]] * w[i];
        if (!isfinite(cost[v])) return OVERFLOW;      /* 0 x inf or an overflow: no cost to compare (issue 40) */
        if (!found || cost[v] < best) best = cost[v];
        found = 1;
    }
    if (!found) return INFEASIBLE;
    memset(tied, 0, sizeof tied);
    for (v = 0; v < NB; v++)
        if (cost[v] <= best + 1e-12 * fabs(best))
            for (i = 0; i < NM; i++) tied[BRANCH_PORTS[v][i]] = 1;
    for (i = 0; i < NE; i++) count += tied[i];
    if (count > NM)                                /* equal cost on several ports: share evenly where w > 0 */
        for (v = NB; v < NT && chosen < 0; v++) {
            if (BRANCH_SIZE[v] != count) continue;
            for (i = 0; i < count && tied[BRANCH_PORTS[v][i]]; i++) {}
            if (i < count) continue;
            STATE[v](par, gain, jet, out);
            for (i = 0; i < count && out[i] > 0.0; i++) {}
            if (i == count) chosen = v;
        }
    for (v = 0; v < NB && chosen < 0; v++)         /* the first vertex of least cost */
        if (cost[v] == best) {
            chosen = v;
            STATE[v](par, gain, jet, out);
        }
    if (chosen < 0 || chosen >= NT) return NO_BRANCH;   /* the tables are read at a checked index only */
    memcpy(ref, out + BRANCH_SIZE[chosen], sizeof(double) * NR);
#if TRACKING
    if (dref != NULL) DSTATE[chosen](par, gain, jet, dref);
#else
    (void)dref;
#endif
    return NULL;
}
"""

_CONTROLLER_LAW = r"""
/* the reference of every kind (closed form, Newton, least operating point) checked to be finite, with its Jacobian
   when asked: an overflow inside it is refused (NOT_FINITE), never passed on to u */
static const char *finite_reference(const double *par, const double *gain, const double *jet, double *ref, double *dref)
{
    const char *why = reference(par, gain, jet, ref, dref);
    if (why != NULL) return why;
    if (!all_finite(NR, ref) || (dref != NULL && !all_finite(NR * NJ, dref))) return NOT_FINITE;
    return NULL;
}
/* the feasible reference ref = (q*, p*, x_e*, x_e*') of Definition 1 at the inputs (2 n_m + 2 n_e values: eta_d of
   q_d for regulation, eta*(t) of the jet for tracking), for the design checks (emc_ctrl_design); NULL, or why it is
   not feasible (then ref is NaN) */
const char *emc_ctrl_reference(const double *par, const double *gain, const double *in, double *ref)
{
    double jet[NJ];
    const char *why;
    int i;
#if TRACKING
    memcpy(jet, in + NS, sizeof jet);
#else
    emc_ctrl_jet(par, gain, in, jet);
#endif
    why = finite_reference(par, gain, jet, ref, NULL);
    if (why != NULL)
        for (i = 0; i < NR; i++) ref[i] = NAN;
    return why;
}

/* u (EMC_N_OUTPUTS = n_e) at the inputs and, if du is not NULL, du/d inputs (n_e x EMC_N_CONTROLLER_INPUTS,
   row-major: the law's Jacobian, through the reference's by the chain rule); NULL, or why the reference is not
   feasible (Definition 1) */
const char *emc_ctrl_law(const double *par, const double *gain, const double *in, double *u, double *du)
{
    double jet[NJ], ref[NR], dref[NR * NJ], J[NE * (NS + NR)];
    const char *why;
    int i, j, k;
#if TRACKING
    memcpy(jet, in + NS, sizeof jet);
#else
    emc_ctrl_jet(par, gain, in, jet);
#endif
    why = finite_reference(par, gain, jet, ref, (TRACKING && du != NULL) ? dref : NULL);
    if (why != NULL) return why;
    emc_ctrl_u(par, gain, in, ref, u);
    if (du == NULL) return NULL;
    emc_ctrl_du(par, gain, in, ref, J);
    for (i = 0; i < NE; i++) {
        for (k = 0; k < NS; k++) du[i * NI + k] = J[i * (NS + NR) + k];
        for (j = 0; j < NI - NS; j++) {
            double s = 0.0;
            for (k = 0; k < NR; k++) s += J[i * (NS + NR) + NS + k] * dref[k * NJ + j];
            du[i * NI + NS + j] = s;
        }
    }
    return NULL;
}
"""


# ---- the design's conditions (components.certificates.design_checks) --------------------------------------
# (name, test, at_reference, numbers [(label, DesignMatrices field)], note printed when it fails), in the order
# and with the names of components.certificates.design_checks; tests/test_native_strict.py pins them to the twin's.
_POSITIVE, _NONNEGATIVE, _SCALED, _HURWITZ = "EMC_TEST_POSITIVE", "EMC_TEST_NONNEGATIVE", "EMC_TEST_SCALED", "EMC_TEST_HURWITZ"


def _design_check_rows(design: str) -> list[tuple[str, str, int, list[tuple[str, str]], str]]:
    name = re.sub(r"(\d)$", r" \1", design)                      # Theorem3 -> Theorem 3 (Controller.name)
    rows: list[tuple[str, str, int, list[tuple[str, str]], str]] = []
    if design == "Proposition1":
        rows.append(("Assumption 1", _POSITIVE, 0, [("min eig hess_q H(eta_d)", "hess_q_H"), ("min eig R_m", "R_m")],
                     "at the set-point"))
    if design in ("Proposition1", "Proposition2"):
        label = "eq. (phi12)" if design == "Proposition1" else "eq. (Phic22)"
        rows.append((f"{label}: hess H_d(eta_d) > 0", _SCALED, 0,
                     [("min eig of hess H_d(eta_d) scaled to a unit diagonal", "hess_H_d")], ""))
    if design == "Theorem2":
        rows.append(("Assumption 3: R_m > 0", _POSITIVE, 0, [("min eig R_m", "R_m")], ""))
    if design in ("Proposition2", "Theorem3"):
        which = "Assumption 2: hess phi(x_e_d) > 0" if design == "Proposition2" else "Assumption 4: hess phi(x_e*) > 0"
        rows.append((which, _POSITIVE, int(design == "Theorem3"), [("min eig hess phi", "hess_phi")], ""))
    strict_k = design == "Theorem3"
    rows.append((f"K_e = R_e_bar - R_e {'>' if strict_k else '>='} 0 ({name})", _POSITIVE if strict_k else _NONNEGATIVE,
                 0, [("min eig K_e", "K_e")], "the closed loop itself only needs R_e_bar > 0 (erratum 4)" if strict_k else ""))
    if design in ("Theorem2", "Theorem3"):
        rows.append(("Theorem 1 (i): F_d Hurwitz", _HURWITZ, 0, [("max real part of eig F_d", "F_d")], ""))
    return rows


def design_checks_available(desc: Description) -> bool:
    """Whether `design_checks_c_source` serves the controllers of `desc`: any plant whose order n = 2 n_m + n_e is
    at most EMC_DESIGN_MAX_ORDER = 16 (fmus/native/emc_design.h); emc_config.h's EMC_DESIGN_CHECKED."""
    return 2 * desc.n_m + desc.n_e <= 16


def design_checks_c_source(desc: Description, design: str, gain_parameters: Sequence) -> str:
    """C99 of the design checks a controller FMU makes at fmi2ExitInitializationMode (strict = 0: warned,
    strict = 1: refused; components.certificates.design_checks, fmus/controller.py), for emc_controller.c:

        void emc_ctrl_design(const double *par, const double *gain, const double *ref, double *out)
            the matrices of components.laws.design_matrices_at_reference at the reference ref = (q*, p*, x_e*,
            x_e*') that emc_ctrl_reference solves (eta_d, or eta*(t) of the jet), row-major, one after the other
        EMC_DESIGN_NAME, EMC_N_DESIGN_CHECKS, EMC_DESIGN_CHECKS[]: each check's name, test, numbers (offset
            and order of a matrix in `out`) and note, in the order of design_checks

    The matrices are sized from the description (n x n, n_m x n_m, n_e x n_e)."""
    from .laws import FAMILY, design_matrices_at_reference, law
    names = tuple(p.name for p in gain_parameters)
    D = design_matrices_at_reference(desc, design, _design_gains(desc, design, names))
    E = plant_expressions(desc)
    gains = tuple(sympy.Symbol(x, real=True) for x in names)
    w = CWriter(E, [("par", "P_", desc.parameter_symbols), ("gain", "K_", gains),
                    ("ref", "R_", law(desc, FAMILY[design]).reference)])
    rows = _design_check_rows(design)
    offsets: dict[str, tuple[int, int]] = {}
    values: list[sympy.Expr] = []
    for _, _, _, numbers, _ in rows:
        for _, field in numbers:
            if field not in offsets:
                M = getattr(D, field)
                offsets[field] = (len(values), M.shape[0])
                values += list(M)
    n = 2 * desc.n_m + desc.n_e
    if n > 16:                                      # EMC_DESIGN_MAX_ORDER (fmus/native/emc_design.h)
        raise ValueError(f"{desc.source}: n = {n} > 16: the native design checks take matrices up to order 16")
    if len(values) > 6 * n * n:
        raise ValueError(f"{desc.source}: {design}'s design matrices exceed emc_controller.c's buffer")
    table = []
    for check, test, at_reference, numbers, note in rows:
        if not 1 <= len(numbers) <= 2:                  # emc_design_check.number[2] (fmus/native/emc_controller.h)
            raise ValueError(f"{design}: the check {check!r} has {len(numbers)} numbers; the C table holds 1 or 2")
        entries = ", ".join(f"{{{c_string(label)}, {offsets[f][0]}, {offsets[f][1]}}}" for label, f in numbers)
        table.append(f"    {{{c_string(check)}, {test}, {at_reference}, {len(numbers)}, {{{entries}}}, {c_string(note)}}},")
    controller = re.sub(r"(\d)$", r" \1", design)
    return "\n".join([
        w.function("ctrl_design", values, f"{controller}'s design matrices at the reference "
                   "(components.laws.design_matrices_at_reference)"),
        "",
        f"const char *const EMC_DESIGN_NAME = {c_string(controller)};",
        f"const int EMC_N_DESIGN_CHECKS = {len(rows)};",
        "const emc_design_check EMC_DESIGN_CHECKS[] = {   /* components.certificates.design_checks */",
        *table, "};"])


