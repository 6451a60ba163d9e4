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
from typing import Sequence

import sympy
from sympy.printing.c import C99CodePrinter

from .description import Description
from .parameters import HUGE, TINY
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
        lines = [f"/* {doc} */", f"void emc_{name}({arguments}, double *out)", "{"]
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


def model_c_source(desc: Description) -> str:
    """The C99 source of the model functions of `desc` (module docstring)."""
    E = plant_expressions(desc)
    w = CWriter(E)
    n = 2 * desc.n_m + desc.n_e
    head = [f"/* Generated by components.c_codegen from {desc.source}; do not edit. */",
            f"/* {desc.description}: the model functions of eq. (open-loop elecmech) in C99. */",
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
    head = [f"/* Generated by components.c_codegen from {desc.source}; do not edit. */",
            f"/* {desc.description}: the control laws of components.laws in C99. */", "#include <math.h>", ""]
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


def controller_c_source(desc: Description, design: str, gain_parameters: Sequence) -> str:
    """C99 of a one-degree-of-freedom controller FMU's law (components.laws.design_law), with the signature
    void emc_ctrl_<name>(const double *par, const double *gain, const double *in, double *out):

        ctrl_u           u (n_e = 1), eq. (c1) / (u1-track) or eq. (u2) / (tracker2)
        ctrl_du          du / d in (the inputs q, p, x_e and, tracking, the jet)
        ctrl_reference   (margin of q* to the domain's boundary, 2 F* / g of Definition 1)
        ctrl_conditions  (R_e_bar, k_c, R_m - D_d^2 / (4 R_e_bar), R_m)

    and int emc_check_gains(const double *gain): the gain parameters' conditions."""
    from .laws import design_law
    names = tuple(p.name for p in gain_parameters)
    L = design_law(desc, design, names)
    E = plant_expressions(desc)
    w = CWriter(E, [("par", "P_", desc.parameter_symbols), ("gain", "K_", L.gains), ("in", "I_", L.inputs)])
    functions = [
        w.function("ctrl_u", [L.u], f"u of {design} (components.laws)"),
        w.function("ctrl_du", list(L.jacobian), "du / d(inputs), symbolic"),
        w.function("ctrl_reference", [L.reference_margin, L.reference_ratio],
                   "Definition 1's feasibility: (margin of q* to the domain's boundary, 2 F* / g)"),
        w.function("ctrl_conditions", [L.R_e_bar, L.k_c, L.ph_margin, desc.R_m[0, 0]],
                   "(R_e_bar, k_c, R_m - D_d^2 / (4 R_e_bar), R_m): components.closed_loop's checks"),
        _check_values("check_gains", gain_parameters, "gain parameter"),
        design_checks_c_source(desc, design, gain_parameters),
    ]
    head = [f"/* Generated by components.c_codegen from {desc.source}: the {design} law; do not edit. */",
            "#include <math.h>", '#include "emc_controller.h"', ""]
    return "\n".join(head) + "\n" + "\n\n".join(functions) + "\n"


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
    """Whether `design_checks_c_source` serves the controllers of `desc` (components.laws.design_matrices: the
    one-degree-of-freedom reference in closed form); emc_config.h's EMC_DESIGN_CHECKED."""
    return desc.n_m == 1 and desc.n_e == 1 and desc.constant_mass     # n = 3 <= EMC_DESIGN_MAX_ORDER (emc_design.h)


def design_checks_c_source(desc: Description, design: str, gain_parameters: Sequence) -> str:
    """C99 of the design checks a controller FMU makes at fmi2ExitInitializationMode (strict = 0: warned,
    strict = 1: refused; components.certificates.design_checks, fmus/controller.py), for emc_controller.c:

        void emc_ctrl_design(const double *par, const double *gain, const double *in, double *out)
            the matrices of components.laws.design_matrices at the target, row-major, one after the other
        EMC_DESIGN_NAME, EMC_N_DESIGN_CHECKS, EMC_DESIGN_CHECKS[]: each check's name, test, numbers (offset
            and order of a matrix in `out`) and note, in the order of design_checks

    The matrices are sized from the description (n x n, n_m x n_m, n_e x n_e)."""
    from .laws import design_law, design_matrices
    names = tuple(p.name for p in gain_parameters)
    L = design_law(desc, design, names)
    D = design_matrices(desc, design, names)
    E = plant_expressions(desc)
    w = CWriter(E, [("par", "P_", desc.parameter_symbols), ("gain", "K_", L.gains), ("in", "I_", L.inputs)])
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
        entries = ", ".join(f"{{{_c_string(label)}, {offsets[f][0]}, {offsets[f][1]}}}" for label, f in numbers)
        table.append(f"    {{{_c_string(check)}, {test}, {at_reference}, {len(numbers)}, {{{entries}}}, {_c_string(note)}}},")
    controller = re.sub(r"(\d)$", r" \1", design)
    return "\n".join([
        w.function("ctrl_design", values, f"{controller}'s design matrices at the target (components.laws.design_matrices)"),
        "",
        f"const char *const EMC_DESIGN_NAME = {_c_string(controller)};",
        f"const int EMC_N_DESIGN_CHECKS = {len(rows)};",
        "const emc_design_check EMC_DESIGN_CHECKS[] = {   /* components.certificates.design_checks */",
        *table, "};"])


def _c_string(text: str) -> str:
    return '"' + text.replace("\\", "\\\\").replace('"', '\\"') + '"'
