"""Code generation: a plant description becomes a plain Python module (no sympy at run time).

`module_source(desc)` differentiates the description's M, V, Psi (and phi) with sympy once, shares common
subexpressions (sympy.cse) and prints the functions as Python arithmetic; math functions go through
components.described's dispatchers (math for floats, cmath for complex numbers), so every function takes
complex arguments and the complex-step checks keep working. `plant_class(desc)` executes that source.

    python -m components.codegen            # regenerate components/plants/<name>_model.py from the *.toml
    python -m components.codegen --check    # exit 1 if a committed module is stale

The generated class subclasses components.described.DescribedOneDOF (n_m = n_e = 1, constant M: scalar
V_s, dV, d2V, psi, dpsi, d2psi) or components.described.DescribedPlant (any n: numpy arrays).

A description is data, never code (issues 31, 40): the source is printed only from parsed sympy expressions and
from names that pass components.identifiers.identifier_problem (checked again here); every comment, docstring
and string literal passes components.source_text (checked identifiers, numbers, the description's sha256, fixed
words). The free text (the description, units, descriptions, domain text) travels as data: one literal of
hexadecimal digits (components.source_text.text_data) decoded at import into `_TEXT`; the file's path not at all.
"""
from __future__ import annotations

import argparse
import re
import sys
import types
from pathlib import Path
from typing import Iterable, Sequence

import numpy as np
import sympy
from sympy.printing.precedence import precedence
from sympy.printing.str import StrPrinter

from .description import FUNCTIONS, Description, load
from .device import Device
from .identifiers import identifier_problem
from .source_text import py_comment, py_docstring, py_string, text_data
from .symbolic import plant_expressions

PLANTS = Path(__file__).resolve().parent / "plants"
SYMBOL = re.compile(r"(_self\._p_)?[A-Za-z_][A-Za-z0-9_]*\Z")


def _check_names(desc: Description) -> None:
    """Every name that becomes an identifier of the generated source (components.identifiers)."""
    names = [("device", desc.name)] + [("name", v.name) for k in ("q", "p", "x_e", "u") for v in getattr(desc, k)]
    names += [("name", n) for n in (*desc.parameters, *desc.gain_parameters)]
    for kind, name in names:
        problem = identifier_problem(name, kind)
        if problem:
            raise ValueError(f"{desc.source}: {kind} {problem}: no code is generated from it")


class _Printer(StrPrinter):
    """Python arithmetic: floats as repr, rationals as (p/q), functions through the dispatchers _f."""

    def _print_Function(self, expr):
        name = type(expr).__name__
        if name not in FUNCTIONS:
            raise ValueError(f"function {name} cannot be generated")
        return f"_{name}({', '.join(self._print(a) for a in expr.args)})"

    def _print_Abs(self, expr):
        return f"_fabs({self._print(expr.args[0])})"        # analytic for a complex step (described.fabs)

    def _print_Float(self, expr):
        return repr(float(expr))

    def _print_Integer(self, expr):
        # a float literal: float arithmetic with an int operand goes through int.__truediv__ / __mul__,
        # which return NotImplemented, before float's reflected method (benchmarks/bench_laws.py: the MEMS's
        # dpsi -1/(...) 1.11x and d2psi 2/(...) 1.10x the hand-written 1.0/(...); with float literals 1.00x)
        return repr(float(expr))

    def _print_Rational(self, expr):
        return f"({expr.p}/{expr.q})"

    def _print_Mul(self, expr):
        c, rest = expr.as_coeff_Mul()
        if isinstance(c, sympy.Rational) and c.q > 1 and c.q & (c.q - 1) == 0 and rest != 1:
            # a coefficient with a power-of-two denominator: one exact multiplication (0.5*x, not x/2)
            text = self._print(rest)
            return f"{float(c)!r}*" + (f"({text})" if isinstance(rest, sympy.Add) else text)
        return super()._print_Mul(expr)

    def _print_Pi(self, expr):
        return "_pi"

    def _print_Symbol(self, expr):
        if not SYMBOL.match(expr.name):               # names are checked by the parser; never print other text
            raise ValueError(f"symbol {expr.name!r} cannot be generated")
        return expr.name

    def _print_Pow(self, expr, rational=False):
        base, e = expr.as_base_exp()
        if e == sympy.S.Half:
            return f"_sqrt({self._print(base)})"
        if e == -sympy.S.Half:
            return f"(1.0/_sqrt({self._print(base)}))"
        if e.is_Integer and e > 0:                  # an int exponent: x**2 (float ** int is float's fast path)
            return f"{self.parenthesize(base, precedence(expr), strict=False)}**{int(e)}"
        if e.is_Integer:
            return f"1.0/{self.parenthesize(base, precedence(expr), strict=False)}**{-int(e)}" if e != -1 else \
                f"1.0/{self.parenthesize(base, precedence(expr), strict=False)}"
        return super()._print_Pow(expr, rational)


def _code(expr) -> str:
    return _Printer({"order": "none"}).doprint(expr)


class _Writer:
    """Prints functions of one description; parameters read as _self._p_<name>."""

    def __init__(self, desc: Description):
        self.desc = desc
        self.par = {s: sympy.Symbol(f"_self._p_{s.name}", real=True) for s in desc.parameter_symbols}

    def body(self, outputs: Sequence[sympy.Expr], rename: dict, zero_like: str | None) -> tuple[list[str], list[str]]:
        """cse'd assignment lines and the printed outputs (constants get `+ 0.0 * zero_like`, so that the
        result has the argument's type)."""
        subs = {**self.par, **rename}
        exprs = [sympy.sympify(e).subs(subs) for e in outputs]
        temps, reduced = sympy.cse(exprs, symbols=sympy.numbered_symbols("_t"), order="none")
        lines = [f"{t} = {_code(v)}" for t, v in temps]
        out = []
        args = set(rename.values())
        for e, orig in zip(reduced, exprs):
            text = _code(e)
            if zero_like is not None and not (orig.free_symbols & args):
                text = f"{text} + 0.0 * {zero_like}" if e != 0 else f"0.0 * {zero_like}"
            out.append(text)
        return lines, out

    def function(self, name: str, args: str, outputs: Sequence, rename: dict, zero_like: str | None,
                 shape: tuple[int, ...] | None, doc: str, unpack: Iterable[str] = ()) -> str:
        lines, values = self.body(list(outputs), rename, zero_like)
        code = [f"    def {name}(_self, {args}):", f"        {py_docstring(doc)}", *[f"        {u}" for u in unpack],
                *[f"        {line}" for line in lines]]
        if shape is None:
            code.append(f"        return {values[0]}")
        else:
            code.append(f"        return _np.array({_nest(values, shape)})")
        return "\n".join(code)


def _nest(values: Sequence[str], shape: tuple[int, ...]) -> str:
    if len(shape) == 1:
        return "[" + ", ".join(values) + "]"
    step = int(np.prod(shape[1:]))
    return "[" + ", ".join(_nest(values[i * step:(i + 1) * step], shape[1:]) for i in range(shape[0])) + "]"


def _flat(*arrays) -> list:
    return [e for a in arrays for e in sympy.flatten(a)]


def _matrix_literal(A: sympy.Matrix, writer: _Writer) -> str:
    values = [_code(sympy.sympify(e).subs(writer.par)) for e in A]
    return f"_np.array({_nest(values, A.shape)}, dtype=float)"


def _imports(body: str, one: bool) -> list[str]:
    """The run-time imports of a generated module: its base class, the dispatchers its text uses, the records."""
    used = {n for n in (*FUNCTIONS, "fabs") if re.search(rf"\b_{n}\b", body)}
    names = ["DescribedOneDOF" if one else "DescribedPlant", *used, "make_device"]
    names = sorted(names, key=lambda n: (not n[0].isupper(), n.lower()))
    lines = [f"from components.described import {n} as _{n}" for n in names]
    return lines + ["from components.device import VariableSpec as _VariableSpec",
                    "from components.parameters import Parameter as _Parameter",
                    "from components.source_text import texts as _texts"]


def is_one_dof(desc: Description) -> bool:
    return desc.n_m == 1 and desc.n_e == 1 and desc.constant_mass


def _texts(desc: Description) -> dict[str, object]:
    """The description's free text by key (what `_TEXT` holds in the generated module): "description", "domain",
    and [unit, description] of "parameter <name>", "gain <name>", "<kind> <name>" (kind q, p, x_e, u)."""
    from .description import gain_table
    out: dict[str, object] = {"description": desc.description, "domain": list(desc.domain_text)}
    out.update({f"parameter {p.name}": [p.unit, p.description] for p in desc.parameters.values()})
    out.update({f"gain {p.name}": [p.unit, p.description] for p in gain_table(desc)[2].values()})
    for kind in ("q", "p", "x_e", "u"):
        out.update({f"{kind} {v.name}": [v.unit, v.description] for v in getattr(desc, kind)})
    return out


def _parameter(p, key: str) -> str:
    """A _Parameter of the generated module: name, default and condition printed, unit and description data."""
    return (f"    _Parameter({py_string(p.name)}, {float(p.default)!r}, *_TEXT[{py_string(key)}], "
            f"{py_string(p.condition)}),")


def _names(names: Iterable[str]) -> str:
    """A tuple literal of checked names."""
    return "(" + "".join(f"{py_string(n)}, " for n in names) + ")"


def module_source(desc: Description, source_name: str | None = None) -> str:
    """The Python source of the model module of `desc` (plant class, parameters, variables, device()).
    `source_name` (the file's name) is not printed (issue 40: no path in generated source); kept for callers."""
    _check_names(desc)
    w = _Writer(desc)
    name = desc.name
    lines = [py_comment(f"Generated by components.codegen from the description with sha256 {desc.sha256}; "
                        "do not edit (python -m components.codegen)."),
             py_comment("ruff: noqa: E501"),
             py_docstring(f"The model functions of the plant {name}, generated by components.codegen."),
             "from __future__ import annotations", "",
             "import numpy as _np", "", "<IMPORTS>", "",
             f"_TEXT = _texts({text_data(_texts(desc))})",
             "PARAMETERS = {p.name: p for p in ["]
    for p in desc.parameters.values():
        lines.append(_parameter(p, f"parameter {p.name}"))
    lines.append("]}")
    lines.append("VARIABLES = {")
    for kind in ("q", "p", "x_e", "u"):
        specs = ", ".join(f"_VariableSpec({py_string(v.name)}, *_TEXT[{py_string(f'{kind} {v.name}')}])"
                          for v in getattr(desc, kind))
        lines.append(f"    {py_string(kind)}: ({specs},),")
    lines.append("}")
    lines += ["", ""]
    one = is_one_dof(desc)
    base = "_DescribedOneDOF" if one else "_DescribedPlant"
    lines.append(f"class {name}({base}):")
    lines.append(f"    {py_docstring(f'The plant {name}; its description is the attribute name.')}")
    lines.append("")
    lines.append('    name = _TEXT["description"]')
    lines.append(f"    DEVICE_NAME = {py_string(name)}")
    lines.append(f"    n_m = {desc.n_m}")
    lines.append(f"    n_e = {desc.n_e}")
    lines.append("    PARAMETERS = PARAMETERS")
    lines.append("    VARIABLES = VARIABLES")
    lines.append('    DOMAIN = tuple(_TEXT["domain"])')
    dom_pars = [_names(s.name for s in desc.parameter_symbols if s in g.free_symbols) for g in desc.domain_margins]
    lines.append(f"    DOMAIN_PARAMETERS = ({''.join(f'{d}, ' for d in dom_pars)})")
    lines.append(f"    x_e_sign = {desc.x_e_sign!r}")
    if desc.operating_point is not None:                       # n_e > n_m: components.operating_point.Rule
        kind, values, ratios, given = desc.operating_point.as_tuple()
        numbers = (tuple((int(i), float(v)) for i, v in values), tuple((int(i), int(j), float(r)) for i, j, r in ratios))
        lines.append(f"    OPERATING_POINT = ({py_string(kind)}, {numbers[0]!r}, {numbers[1]!r}, {bool(given)!r})")
    if desc.gamma_source == "derived, scaled":               # Gamma^T q in the unit of x_e: z in J/u, k_c in u^2/J
        lines.append("    GAMMA_IN_DEVICE_UNITS = True")
    lines.append(f"    constant_mass = {desc.constant_mass!r}")
    lines.append("")
    lines.append(_setup(desc, w, one))
    lines.append("")
    lines += _model_functions(desc, w, one)
    lines += [""] + (_laws_source(desc, w) if one else _vector_laws_source(desc, w))
    while lines[-1] == "":
        lines.pop()
    lines += ["", ""]
    lines += _device_source(desc, w)
    text = re.sub(r"\n{3,}(?=    )", "\n\n", "\n".join(lines) + "\n")      # one blank line between methods
    text = re.sub(r"\n{4,}", "\n\n\n", text)
    return text.replace("<IMPORTS>", "\n".join(_imports(text, one)))


def _setup(desc: Description, w: _Writer, one: bool) -> str:
    code = ["    def _setup(_self):", '        """The constant matrices of eq. (open-loop elecmech) from the parameters."""']
    for key in ("R_m", "J_e", "R_e", "G_e"):
        code.append(f"        _self.{key} = {_matrix_literal(getattr(desc, key), w)}")
    if desc.Gamma is not None:
        code.append(f"        _self.Gamma = {_matrix_literal(desc.Gamma, w)}   # Assumptions 2/4 ({desc.gamma_source})")
    if desc.constant_mass:
        M = desc.M.subs(w.par)
        code.append(f"        _M = {_matrix_literal(desc.M, w)}")
        code.append("        _self._M_inv = _np.linalg.inv(_M)")
        if one:
            code.append(f"        _self.m = {_code(M[0, 0])}")
    if one:
        q = desc.q_symbols[0]
        linear = True
        for g in desc.domain_margins:
            poly = sympy.Poly(g, q) if g.is_polynomial(q) else None
            if poly is None or poly.degree() != 1:
                linear = False
                break
            a, b = poly.all_coeffs()           # a q + b > 0
            code.append(f"        _a, _b = {_code(a.subs(w.par))}, {_code(b.subs(w.par))}")
            code.append("        if _a > 0:")
            code.append("            _self.q_min = max(_self.q_min, -_b / _a)")
            code.append("        else:")
            code.append("            _self.q_max = min(_self.q_max, -_b / _a)")
        if not linear:
            code.append("        _self.linear_domain = False")
    return "\n".join(code)


def _model_functions(desc: Description, w: _Writer, one: bool) -> list[str]:
    qs = desc.q_symbols
    xs = desc.x_e_symbols
    m, e = desc.n_m, desc.n_e
    out: list[str] = []
    if one:
        q = qs[0]
        r = {q: sympy.Symbol("q")}
        E = plant_expressions(desc)                 # the derivatives, taken once (components.symbolic)
        for name, expr, doc in (("V_s", E.V, "Potential energy V(q) [J]."), ("dV", E.grad_V[0], "V'(q)."),
                                ("d2V", E.hess_V[0, 0], "V''(q)."),
                                ("psi", E.Psi[0, 0], "Psi(q) of eq. (elec energy)."), ("dpsi", E.dPsi[0][0, 0], "Psi'(q)."),
                                ("d2psi", E.d2Psi[0][0][0, 0], "Psi''(q).")):
            out.append(w.function(name, "q", [expr], r, "q", None, doc))
            out.append("")
        out.append(_margins(desc, w, {q: sympy.Symbol("_q0")}, ["(_q0,) = q"]))
        out.append("")
        if desc.Gamma is not None:
            x = xs[0]
            rx = {x: sympy.Symbol("x_e")}
            phi = desc.phi
            for name, expr, doc in (("phi_s", phi, "phi of Assumptions 2/4 (eq. assHereg)."),
                                    ("dphi", phi.diff(x), "phi'(x_e)."), ("d2phi", phi.diff(x, 2), "phi''(x_e).")):
                out.append(w.function(name, "x_e", [expr], rx, "x_e", None, doc))
                out.append("")
            out.append("    def phi(_self, x_e):\n        return _self.phi_s(x_e[0])\n")
            out.append("    def grad_phi(_self, x_e):\n        return _np.array([_self.dphi(x_e[0])])\n")
            out.append("    def hess_phi(_self, x_e):\n        return _np.array([[_self.d2phi(x_e[0])]])")
        return out
    # general n: functions of the array q (entries unpacked under generated names _q0, _q1, ...)
    qn = {s: sympy.Symbol(f"_q{i}") for i, s in enumerate(qs)}
    unpack_q = [f"({', '.join(f'_q{i}' for i in range(m))},) = q"]
    z = "_q0"

    def fn(name, outputs, shape, doc, rename=qn, unpack=unpack_q, args="q", zero=z):
        out.append(w.function(name, args, outputs, rename, zero, shape, doc, unpack))
        out.append("")
    if desc.constant_mass:
        out.append('    def M_inv(_self, q):\n        """M^-1 (constant)."""\n        return _self._M_inv\n')
    else:
        Minv = desc.M.inv() if m <= 3 else None
        if Minv is None:
            raise ValueError(f"{desc.source}: [model] M: depends on q with n_m = {m} > 3 (no symbolic inverse generated)")
        Minv = Minv.applyfunc(sympy.simplify)
        dMinv = [Minv.diff(qk) for qk in qs]
        d2Minv = [[Minv.diff(qk, ql) for ql in qs] for qk in qs]
        fn("M_inv", _flat(Minv), (m, m), "M(q)^-1.")
        fn("dM_inv", _flat(*[list(D) for D in dMinv]), (m, m, m), "d M^-1 / d q_k (axis 0).")
        fn("d2M_inv", [x for row in d2Minv for D in row for x in D], (m, m, m, m), "d^2 M^-1 / d q_k d q_l.")
    E = plant_expressions(desc)                     # the derivatives, taken once (components.symbolic)
    V = E.V
    fn("V", [V], None, "Potential energy V(q) [J].")
    fn("grad_V", list(E.grad_V), (m,), "grad V(q).")
    fn("hess_V", list(E.hess_V), (m, m), "Hessian of V.")
    fn("Psi", list(E.Psi), (e, e), "Psi(q) of eq. (elec energy).")
    fn("dPsi", [x for D in E.dPsi for x in D], (m, e, e), "d Psi / d q_k (axis 0).")
    fn("d2Psi", [x for row in E.d2Psi for D in row for x in D], (m, m, e, e), "d^2 Psi / d q_k d q_l.")
    out.append(_margins(desc, w, qn, unpack_q))
    out.append("")
    # F* and dF*/dt of Definition 1 (p-row of eq. open-loop elecmech along the jet)
    qd = sympy.symbols(f"_qd0:{m}")
    qdd = sympy.symbols(f"_qdd0:{m}")
    qddd = sympy.symbols(f"_qddd0:{m}")
    t = sympy.Symbol("_time")
    path = {qk: sympy.Function(f"_path{k}")(t) for k, qk in enumerate(qs)}
    M_t = desc.M.subs(path)
    qv = sympy.Matrix([path[qk] for qk in qs])
    qdot = qv.diff(t)
    p_t = M_t * qdot
    grad_V = sympy.Matrix([V.diff(qk) for qk in qs]).subs(path)
    # -grad_q H_e = p' + R_m q' + grad V + 1/2 p^T dM^-1/dq_k p with p = M q', p' = M q'' + M' q'
    F = M_t * qv.diff(t, 2) + M_t.diff(t) * qdot + desc.R_m * qdot + grad_V
    if not desc.constant_mass:
        Minv = desc.M.inv()
        F = F + sympy.Matrix([(p_t.T * Minv.diff(qk).subs(path) * p_t)[0, 0] / 2 for qk in qs])
    F_dot = F.diff(t)
    back = [(path[qs[k]].diff(t, order), sym[k]) for order, sym in ((3, qddd), (2, qdd), (1, qd)) for k in range(m)]
    back += [(path[qs[k]], qn[qs[k]]) for k in range(m)]

    def unpath(expr):
        for old, new in back:
            expr = expr.subs(old, new)
        return expr
    Fs = [unpath(x) for x in F]
    Fds = [unpath(x) for x in F_dot]
    lines, values = w.body(Fs + Fds, {}, None)
    names = ", ".join(f"_q{i}" for i in range(m))
    body = ["    def force_jet(_self, q, qd, qdd, qddd):",
            '        """(F*, dF*/dt) of Definition 1: F* = M q*\'\' + M\' q*\' + R_m q*\' + grad V + 1/2 p*^T dM^-1/dq p*."""',
            f"        ({names},) = q", f"        ({', '.join(map(str, qd))},) = qd",
            f"        ({', '.join(map(str, qdd))},) = qdd", f"        ({', '.join(map(str, qddd))},) = qddd",
            *[f"        {line}" for line in lines],
            f"        return _np.array([{', '.join(values[:m])}]), _np.array([{', '.join(values[m:])}])", ""]
    out += body
    if desc.Gamma is not None:
        xn = {s: sympy.Symbol(f"_x{i}") for i, s in enumerate(xs)}
        unpack_x = [f"({', '.join(f'_x{i}' for i in range(e))},) = x_e"]
        phi = desc.phi
        fn("phi", [phi], None, "phi(x_e) of Assumptions 2/4 (eq. assHereg).", xn, unpack_x, "x_e", "_x0")
        fn("grad_phi", [phi.diff(x) for x in xs], (e,), "grad phi(x_e).", xn, unpack_x, "x_e", "_x0")
        fn("hess_phi", [phi.diff(a, b) for a in xs for b in xs], (e, e), "Hessian of phi.", xn, unpack_x, "x_e", "_x0")
    return out


# ---- the control laws (components.laws), printed as Python -------------------------------------------------
# the generated law functions' arguments: the state, the feasible reference (q*, p*, x_e*, x_e*') and the jet
# (q*, q*', q*'', q*''') of a one-degree-of-freedom plant
LAW_STATE = ("q", "p", "x_e")
LAW_REFERENCE = ("q_star", "p_star", "x_e_star", "x_e_star_dot")
LAW_JET = ("q_star", "q_star_dot", "q_star_ddot", "q_star_dddot")
INFEASIBLE = "_self.infeasible_reference(q_star)"


def _hoist(exprs: Sequence[sympy.Expr], variables: set, prefix: str) -> tuple[list[tuple[sympy.Symbol, sympy.Expr]], list]:
    """Loop-invariant code motion: every largest subexpression of `exprs` free of `variables` (the factors or
    terms of a product or sum together) becomes a symbol prefix<k>; returns ([(symbol, expression)], exprs)."""
    constants: dict[sympy.Expr, sympy.Symbol] = {}

    def constant(e):
        if e.is_Number or e.is_NumberSymbol:        # a literal stays; a parameter (_self._p_c) becomes a local
            return e
        if e not in constants:
            constants[e] = sympy.Symbol(f"{prefix}{len(constants)}")
        return constants[e]

    def walk(e):
        if not (e.free_symbols & variables):
            return constant(e)
        if e.is_Add or e.is_Mul:
            fixed = [a for a in e.args if not (a.free_symbols & variables)]
            moving = [walk(a) for a in e.args if a.free_symbols & variables]
            return e.func(*([constant(e.func(*fixed))] if fixed else []), *moving)
        if e.is_Atom:
            return e
        return e.func(*[walk(a) for a in e.args])
    out = [walk(sympy.sympify(e)) for e in exprs]
    return [(s, e) for e, s in constants.items()], out


def _radicands(exprs: Sequence[sympy.Expr]) -> list[sympy.Expr]:
    """The bases of the square roots in `exprs` (x_e* = s sqrt(2 F* / g) of Definition 1): real only when positive."""
    found: list[sympy.Expr] = []
    for e in exprs:
        for a in sympy.preorder_traversal(e):
            if a.is_Pow and a.exp.is_Rational and a.exp.q == 2 and a.base not in found:
                found.append(a.base)
    return found


def _guarded_body(outputs: Sequence[sympy.Expr], temp: str, moving: set) -> tuple[list[str], list[str]]:
    """cse'd lines of `outputs` in which every square root's radicand r_k that depends on the arguments `moving`
    is computed first, as _r<k>, and checked (`if not _r<k>.real > 0: INFEASIBLE`, which raises); then the rest.
    Returns (lines, outputs)."""
    roots = [r for r in _radicands(outputs) if r.free_symbols & moving]
    guards = {r: sympy.Symbol(f"_r{k}") for k, r in enumerate(roots)}
    guarded = [sympy.sympify(e).xreplace(guards) for e in outputs]
    temps, reduced = sympy.cse([*roots, *guarded], symbols=sympy.numbered_symbols(temp), order="none")
    late = set(guards.values())
    before, after = [], []
    for t, v in temps:
        if v.free_symbols & late:
            late.add(t)
            after.append(f"{t} = {_code(v)}")
        else:
            before.append(f"{t} = {_code(v)}")
    checks = []
    for g, e in zip(guards.values(), reduced):
        checks += [f"{g} = {_code(e)}", f"if not {g}.real > 0:", f"    {INFEASIBLE}"]
    return before + checks + after, [_code(e) for e in reduced[len(roots):]]


def _law_names(desc: Description) -> dict:
    """The description's q, p, x_e and reference symbols -> the generated functions' argument names."""
    from .laws import _reference_symbols, jet_symbols
    E = plant_expressions(desc)
    names = dict(zip((E.q[0], E.p[0], E.x_e[0]), map(sympy.Symbol, LAW_STATE)))
    names.update(zip((s[0] for s in _reference_symbols(desc)), map(sympy.Symbol, LAW_REFERENCE)))
    names.update(zip(jet_symbols(desc), map(sympy.Symbol, LAW_JET)))
    return names


def _domain_check(q_min: str, q_max: str, indent: str) -> list[str]:
    """q* inside the domain (check_state raises the DomainError), as OneDOFPlant.feasible_state needs."""
    return [f"{indent}if not {q_min} < q_star.real < {q_max}:",
            f"{indent}    _self.check_state(_np.array([q_star, 0.0, 0.0]))"]


def _factory(w: _Writer, head: str, doc: str, u: sympy.Expr, moving: Sequence[str], prologue: Sequence[str] = (),
             inner_prologue: Sequence[str] = ()) -> list[str]:
    """A method `head` that computes every part of u free of the arguments `moving` once and returns
    _u(*moving), which computes the rest (square roots guarded: _guarded_body)."""
    variables = {sympy.Symbol(n) for n in moving}
    constants, (inner,) = _hoist([u], variables, "_c")
    outer_lines, outer_values = w.body([e for _, e in constants], {}, None) if constants else ([], [])
    lines, (value,) = _guarded_body([inner], "_s", variables)
    return [f"    def {head}:", f"        {py_docstring(doc)}", *[f"        {line}" for line in outer_lines],
            *[f"        {s} = {v}" for (s, _), v in zip(constants, outer_values)], *prologue, "",
            f"        def _u({', '.join(moving)}):", *inner_prologue, *[f"            {line}" for line in lines],
            f"            return {value}", "", "        return _u", ""]


def _laws_source(desc: Description, w: _Writer) -> list[str]:
    """feasible_scalar (Definition 1) and, per law family, the factories law_<family>_at (a constant reference:
    regulation) and law_<family>_tracking (along the reference's jet), printed from components.laws."""
    from .laws import feasible_reference, law, tracking_law
    names = _law_names(desc)
    rename = {**names, **w.par}
    jet, subs = feasible_reference(desc)
    reference = [subs[s].xreplace(rename) for s in sorted(subs, key=list(names).index)]
    lines, values = _guarded_body(reference, "_t", {sympy.Symbol(n) for n in LAW_JET})
    out = [f"    def feasible_scalar(_self, {', '.join(LAW_JET)}):",
           "        \"\"\"(q*, p*, x_e*, x_e*') of the reference jet (q*, q*', q*'', q*'''): Definition 1 in closed form "
           "(components.laws.feasible_reference).\"\"\"",
           *_domain_check("_self.q_min", "_self.q_max", "        "), *[f"        {line}" for line in lines],
           f"        return ({', '.join(values)})", ""]
    for family in ["c1"] + (["u2"] if desc.Gamma is not None else []):
        stated = law(desc, family)
        gains = ", ".join(s.name for s in stated.gains)
        out += _factory(w, f"law_{family}_at(_self, {gains}, {', '.join(LAW_REFERENCE)})",
                        f"u(q, p, x_e) of {stated.equations} at a constant reference (q*, p*, x_e*, x_e*'), "
                        "from components.laws.law.", stated.u[0].xreplace(rename), LAW_STATE)
        stated = tracking_law(desc, family)
        out += _factory(w, f"law_{family}_tracking(_self, {gains})",
                        f"u(q, p, x_e, q*, q*', q*'', q*''') of {stated.equations}, from components.laws.tracking_law.",
                        stated.u[0].xreplace(rename), LAW_STATE + LAW_JET,
                        ["        _q_min, _q_max = _self.q_min, _self.q_max"],
                        _domain_check("_q_min", "_q_max", "            "))
    return out


def _vector_factory(w: _Writer, head: str, doc: str, u: Sequence[sympy.Expr], setup: Sequence[str], args: str,
                    unpack: Sequence[str], moving: set) -> list[str]:
    """A method `head` that computes every part of the entries of u free of `moving` once and returns
    _u(args), which computes the rest and returns u as an array (n_e)."""
    constants, inner = _hoist(u, moving, "_c")
    outer_lines, outer_values = w.body([e for _, e in constants], {}, None) if constants else ([], [])
    temps, reduced = sympy.cse(inner, symbols=sympy.numbered_symbols("_s"), order="none")
    return [f"    def {head}:", f"        {py_docstring(doc)}", *[f"        {line}" for line in setup],
            *[f"        {line}" for line in outer_lines],
            *[f"        {s} = {v}" for (s, _), v in zip(constants, outer_values)], "",
            f"        def _u({args}):", *[f"            {line}" for line in unpack],
            *[f"            {t} = {_code(v)}" for t, v in temps],
            f"            return _np.array([{', '.join(_code(e) for e in reduced)}])", "", "        return _u", ""]


def _unpack(names: Sequence[sympy.Symbol], source: str) -> str:
    return f"({', '.join(s.name for s in names)},) = {source}"


def _vector_laws_source(desc: Description, w: _Writer) -> list[str]:
    """Per law family of components.laws, for a plant of any n_m, n_e (n_e <= 3: the law's symbolic inverses):
    law_<family>_at(R_e_bar, D_d, W or k_c, eta*, x_e*') -> u(eta) (regulation: all but the state once) and
    law_<family>_ref(R_e_bar, D_d, W or k_c) -> u(eta, eta*, x_e*') (tracking: the feasible reference of
    Definition 1 given, DescribedPlant.feasible_state)."""
    from .laws import _reference_symbols, law
    if desc.n_e > 3:
        return []
    E = plant_expressions(desc)
    n, e = 2 * desc.n_m + desc.n_e, desc.n_e
    q_s, p_s, x_s, xd_s = _reference_symbols(desc)
    state = [sympy.Symbol(f"_e{i}") for i in range(n)]
    star = [sympy.Symbol(f"_y{i}") for i in range(n)]
    rate = [sympy.Symbol(f"_yd{i}") for i in range(e)]
    rename = {**dict(zip(E.eta, state)), **dict(zip((*q_s, *p_s, *x_s), star)), **dict(zip(xd_s, rate)), **w.par}
    unpack_state = _unpack(state, "_np.asarray(eta).tolist()")
    unpack_star = [_unpack(star, "_np.ravel(eta_star).tolist()"), _unpack(rate, "_np.ravel(x_e_star_dot).tolist()")]
    out: list[str] = []
    for family in ["c1"] + (["u2"] if desc.Gamma is not None else []):
        stated = law(desc, family)
        gains = [sympy.Symbol(f"_g{i}") for i in range(len(stated.gains))]
        u = [x.xreplace({**rename, **dict(zip(stated.gains, gains))}) for x in stated.u]
        third = "W" if family == "c1" else "k_c"
        setup = [_unpack(gains, f"(*_np.ravel(R_e_bar).tolist(), *_np.ravel(D_d).tolist(), *_np.ravel({third}).tolist())")]
        out += _vector_factory(w, f"law_{family}_at(_self, R_e_bar, D_d, {third}, eta_star, x_e_star_dot)",
                               f"u(eta) of {stated.equations} at a constant feasible reference (eta*, x_e*'), from "
                               "components.laws.law.", u, setup + unpack_star, "eta", [unpack_state], set(state))
        out += _vector_factory(w, f"law_{family}_ref(_self, R_e_bar, D_d, {third})",
                               f"u(eta, eta*, x_e*') of {stated.equations}, from components.laws.law.", u, setup,
                               "eta, eta_star, x_e_star_dot", [unpack_state, *unpack_star], {*state, *star, *rate})
    return out


def _margins(desc: Description, w: _Writer, rename: dict, unpack: list[str]) -> str:
    """margins(q): the domain margins g_j(q) (positive inside), a tuple."""
    if not desc.domain_margins:
        return '    def margins(_self, q):\n        """No domain inequalities."""\n        return ()\n'
    lines, values = w.body(list(desc.domain_margins), rename, None)
    return "\n".join(["    def margins(_self, q):", '        """Domain margins g_j(q) > 0."""', *[f"        {u}" for u in unpack],
                      *[f"        {line}" for line in lines], f"        return ({', '.join(values)},)", ""])


def _device_source(desc: Description, w: _Writer) -> list[str]:
    """GAIN_DEFAULTS, GAIN_FORMS, GAIN_PARAMETERS and device(designs) from the [controller] table."""
    from .description import gain_table  # the [controller] table resolved (defaults, forms)
    defaults, forms, gain_parameters = gain_table(desc)
    lines = ["GAIN_PARAMETERS: dict[str, _Parameter] = {p.name: p for p in ["]
    for p in gain_parameters.values():
        lines.append(_parameter(p, f"gain {p.name}"))
    lines.append("]}")
    if not gain_parameters:
        lines = ["GAIN_PARAMETERS: dict[str, _Parameter] = {}"]
    rows = ", ".join(f"{py_string(g)}: {[[float(x) for x in row] for row in v]!r}" for g, v in defaults.items())
    lines.append(f"GAIN_DEFAULTS: dict[str, list[list[float]]] = {{{rows}}}")
    lines.append("")
    for gain, (expr, names) in forms.items():
        symbols = {sympy.Symbol(n, real=True): sympy.Symbol(n) for n in names}
        values = [_code(sympy.sympify(x).subs(symbols)) for x in expr]
        lines += ["", f"def _form_{gain}({', '.join(names)}):",
                  f"    {py_docstring(f'{gain} of the [controller] table of the description.')}",
                  f"    return _np.array({_nest(values, expr.shape)}, dtype=float)"]
    lines.append("")
    entries = ", ".join(f"{py_string(g)}: (_form_{g}, {_names(n)})" for g, (_, n) in forms.items())
    lines.append("GAIN_FORMS: dict[str, tuple] = {" + entries + "}")
    lines += ["", "",
              "def device(designs=None):",
              "    " + py_docstring(f"The Device of {desc.name}: its plant and the designs (default: all four) "
                               "with their gains."),
              f"    return _make_device({desc.name}, GAIN_DEFAULTS, GAIN_FORMS, GAIN_PARAMETERS, designs)"]
    return lines


def load_module(desc: Description, source: str | None = None) -> types.ModuleType:
    """Execute the generated source of `desc` (or `source`, module_source(desc) made elsewhere: a worker
    process, components.bounded) as a fresh module."""
    _check_names(desc)
    module = types.ModuleType(f"components.plants._described_{desc.name}")
    code = compile(module_source(desc) if source is None else source, f"<generated for {desc.name}>", "exec")
    exec(code, module.__dict__)
    return module


def device(desc: Description, designs: Sequence[str] | None = None, source: str | None = None) -> Device:
    """The components.device.Device of a description: its generated plant class and the controllers of
    `designs` (the designs that apply, e.g. from components.plant_check; default: all four) with their
    gains under the paper's names (q_d, R_e_bar, D_d, k_c; entries q_d_1, R_e_bar_1_2, ... where n > 1).
    `source`: module_source(desc), if already made."""
    return load_module(desc, source).device(designs)



def plant_class(desc: Description) -> type:
    """The generated plant class of `desc` (DescribedOneDOF or DescribedPlant subclass)."""
    return getattr(load_module(desc), desc.name)


def model_path(toml: Path) -> Path:
    return toml.with_name(f"{toml.stem}_model.py")


def generate(folder: Path = PLANTS) -> dict[Path, str]:
    """The generated module text of every *.toml in `folder` (components/plants)."""
    out = {}
    for toml in sorted(folder.glob("*.toml")):
        rel = toml.relative_to(folder.parents[1]) if folder == PLANTS else toml
        out[model_path(toml)] = module_source(load(toml), str(rel))
    return out


def stale(folder: Path = PLANTS) -> list[Path]:
    """The committed model modules that differ from what their description generates."""
    return [path for path, text in generate(folder).items()
            if not path.exists() or path.read_text(encoding="utf-8") != text]


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description="Generate components/plants/<name>_model.py from the descriptions.")
    ap.add_argument("--check", action="store_true", help="exit 1 if a committed module is stale")
    args = ap.parse_args(argv)
    if args.check:
        bad = stale()
        for path in bad:
            print(f"stale: {path}", file=sys.stderr)
        return 1 if bad else 0
    for path, text in generate().items():
        path.write_text(text, encoding="utf-8")
        print(f"wrote {path}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
