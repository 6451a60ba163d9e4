"""A plant description: one weakly coupled EM device (eq. open-loop elecmech) read from a TOML file.

The file names the variables (q, p, x_e, u with units and descriptions), the physical parameters
(default, unit, description, condition) and the model as sympy expressions in those names:
M(q), V(q), Psi(q) (eq. elec energy), the constant matrices R_m, J_e, R_e, G_e, the admissible domain
(strict inequalities in q) and, optionally, Gamma and phi of Assumptions 2/4 (eq. assHereg). The format
and the checks made here are documented in docs/plant-description.md.

Expressions are never evaluated as Python: each is tokenized and may hold only known variable and
parameter names, the functions of FUNCTIONS, numbers, + - * / ** ^ and parentheses; it is then parsed by
sympy with an explicit namespace and no builtins. Every bad input raises DescriptionError naming the file,
the table and the entry.

A description is data, never code (issue 31): names obey components.identifiers.identifier_problem, free
text components.identifiers.text_problem, and the work a file can cause is bounded: MAX_DIMENSION,
MAX_EXPRESSION characters and MAX_NODES nodes per expression, exponents (also nested ones, multiplied) up
to MAX_EXPONENT, every constant finite and not subnormal as a double, and the symbolic checks limited to
SYMBOLIC_SECONDS each (components.bounded.time_limit; past it the sampled test decides, and `notes` says so).
"""
from __future__ import annotations

import hashlib
import io
import math
import re
import tokenize
import tomllib
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Mapping, Sequence

import numpy as np
import sympy
from sympy.parsing.sympy_parser import parse_expr

from .bounded import time_limit
from .device import VariableSpec
from .identifiers import NAME, identifier_problem, text_problem, unit_problem
from .parameters import Parameter

FUNCTIONS: dict[str, Any] = {
    "sqrt": sympy.sqrt, "exp": sympy.exp, "log": sympy.log, "sin": sympy.sin, "cos": sympy.cos,
    "tan": sympy.tan, "sinh": sympy.sinh, "cosh": sympy.cosh, "tanh": sympy.tanh, "atan": sympy.atan,
    "asin": sympy.asin, "acos": sympy.acos, "pi": sympy.pi,
}
CONDITIONS = ("> 0", ">= 0", "any")
MODEL_REQUIRED = ("M", "V", "Psi", "R_m", "J_e", "R_e", "G_e")
MODEL_OPTIONAL = ("domain", "Gamma", "phi", "x_e_sign", "u_max")
VARIABLE_KINDS = ("q", "p", "x_e", "u")
TOP_KEYS = {"name", "description", "variables", "parameters", "model", "controller", "operating_point"}
CONTROLLER_GAINS = ("q_d", "R_e_bar", "D_d", "k_c", "W")
NUMBER = re.compile(r"(\d+\.?\d*|\.\d+)([eE][+-]?\d+)?\Z")
OPERATORS = {"+", "-", "*", "/", "**", "^", "(", ")"}
EXPRESSION_CHARACTERS = re.compile(r"[A-Za-z0-9_+\-*/^(). \t\n]*\Z")
"""The characters an expression may hold (a backslash, a quote, a control character never)."""
MAX_EXPONENT = 1000
"""Largest constant exponent accepted in an expression; nested powers multiply: ((q+1)**40)**40 is 1600."""
MAX_DIMENSION = 8
"""Largest n_m and n_e (the generated code holds n_m^2 n_e^2 second derivatives of Psi)."""
MAX_FILE = 1_000_000
"""Largest description file (bytes)."""
MAX_PARAMETERS = 200
"""Most parameters of a table ([parameters], [controller.parameters])."""
MAX_EXPRESSION = 2000
"""Longest expression string (characters)."""
MAX_NODES = 500
"""Most sympy nodes of one parsed expression."""
MAX_LITERAL = 40
"""Longest number literal (characters)."""
SYMBOLIC_SECONDS = 5.0
"""Time limit of one symbolic decision (a Sylvester criterion, a sign on the domain); past it the property is
checked at sample points and the note says that the limit was reached."""
DOUBLE_MIN = 2.2250738585072014e-308
"""The smallest normal double: a nonzero constant below it would be 0 or subnormal in the FMU's arithmetic."""
SAMPLE_POINTS = 200
"""Points of the domain at which a property sympy cannot decide is checked (docs/plant-description.md)."""


class DescriptionError(ValueError):
    """A wrong plant description; the message starts with `<file>: [<table>] <entry>: `."""


class _NotADouble(ValueError):
    """A constant of an expression that the FMU's double arithmetic cannot hold (see _constant)."""


def _double_problem(value: float | int, nonzero: bool | None = None) -> str | None:
    """Why a number is not a usable double (None: it is): infinite or NaN, beyond the double range, or nonzero
    but below DOUBLE_MIN (0 or subnormal in the FMU while sympy calls it positive). `nonzero`: whether the
    exact value (a literal's digits) is nonzero, if `value` is its rounded double."""
    try:
        x = float(value)
    except OverflowError:
        return "is beyond the range of a double (|x| < 1.8e308)"
    if not math.isfinite(x):
        return "is not finite as a double (|x| < 1.8e308)"
    if nonzero is None:
        nonzero = value != 0
    if x != 0 and abs(x) < DOUBLE_MIN or (x == 0 and nonzero):
        return f"is nonzero but below {DOUBLE_MIN:.4g} in magnitude: 0 or subnormal as a double"
    return None


def _exponent_problem(node: Any, outer: float) -> str | None:
    """An exponent beyond MAX_EXPONENT, counting nested powers as their product (the degree they build)."""
    if isinstance(node, sympy.Pow) and node.exp.is_number:
        try:
            e = abs(float(node.exp)) if not node.exp.free_symbols else math.inf
        except (TypeError, ValueError, OverflowError):
            e = math.inf
        total = outer * max(e, 1.0)
        if not total <= MAX_EXPONENT:
            return f"an exponent {_text(node.exp)} (with the powers around it {total:.6g}) beyond +-{MAX_EXPONENT}"
        return _exponent_problem(node.base, total) or _exponent_problem(node.exp, 1.0)
    for a in node.args:
        problem = _exponent_problem(a, outer)
        if problem:
            return problem
    return None


def _text(node: Any) -> str:
    """A sympy node for a message (str, not format(): Float.__format__ fails on some tiny Floats)."""
    text = str(node)
    return text if len(text) <= 80 else text[:77] + "..."


_MATH = {"sqrt": math.sqrt, "exp": math.exp, "log": math.log, "sin": math.sin, "cos": math.cos, "tan": math.tan,
         "sinh": math.sinh, "cosh": math.cosh, "tanh": math.tanh, "atan": math.atan, "asin": math.asin,
         "acos": math.acos}


def _constant(node: Any) -> float | None:
    """The value as a double of a constant (sub)expression of an unevaluated tree, None for one with symbols;
    every constant subexpression is checked: _NotADouble if one is not finite, not real, or nonzero in exact
    arithmetic but 0 or subnormal as a double (exp(-1000), 1e-200*1e-200)."""
    if isinstance(node, sympy.Symbol):
        return None
    if isinstance(node, (sympy.Integer, sympy.Rational)):
        try:
            x = node.p / node.q
        except OverflowError:
            raise _NotADouble(f"the constant {_text(node)} is beyond the range of a double") from None
        nonzero = node.p != 0
    elif isinstance(node, sympy.Float):
        x, nonzero = float(node), node != 0
    elif node is sympy.pi:
        return math.pi
    else:
        args = [_constant(a) for a in node.args]
        if any(a is None for a in args) or not args:
            return None
        name = type(node).__name__
        try:
            if isinstance(node, sympy.Add):
                x, nonzero = math.fsum(args), False        # a sum may cancel to 0 exactly
            elif isinstance(node, sympy.Mul):
                x, nonzero = math.prod(args), all(a != 0 for a in args)
            elif isinstance(node, sympy.Pow):
                x, nonzero = args[0] ** args[1], args[0] != 0
            elif name in _MATH:
                x, nonzero = _MATH[name](args[0]), name in ("exp", "cosh")
            else:
                return None
        except (OverflowError, ZeroDivisionError, ValueError) as e:
            raise _NotADouble(f"the constant {_text(node)} is not a finite real double ({type(e).__name__})") from None
        if isinstance(x, complex):
            raise _NotADouble(f"the constant {_text(node)} is not real")
        if x == 0 and not nonzero:
            return 0.0
    if not math.isfinite(x):
        raise _NotADouble(f"the constant {_text(node)} is not finite as a double")
    if (x != 0 and abs(x) < DOUBLE_MIN) or (x == 0 and nonzero):
        raise _NotADouble(f"the constant {_text(node)} is nonzero but 0 or subnormal as a double (below {DOUBLE_MIN:.4g})")
    return x


@dataclass(frozen=True)
class Description:
    """A parsed, checked plant description (eq. open-loop elecmech with H_e = x_e^T Psi(q) x_e / 2).

    Sympy objects in the symbols q_symbols, p_symbols, x_e_symbols, u_symbols, parameter_symbols.
    domain_margins[j] > 0 is the j-th inequality of `domain` (each `g(q) > 0`). Gamma / phi of
    Assumptions 2/4 are "given" in the file, "derived" (Psi affine in q with diagonal dPsi/dq_k) or None.
    `notes` says how each property was decided (symbolically, or at which sample points).
    """

    name: str
    description: str
    source: str
    q: tuple[VariableSpec, ...]
    p: tuple[VariableSpec, ...]
    x_e: tuple[VariableSpec, ...]
    u: tuple[VariableSpec, ...]
    parameters: dict[str, Parameter]
    M: sympy.Matrix
    V: sympy.Expr
    Psi: sympy.Matrix
    R_m: sympy.Matrix
    J_e: sympy.Matrix
    R_e: sympy.Matrix
    G_e: sympy.Matrix
    domain: tuple[Any, ...]
    domain_margins: tuple[sympy.Expr, ...]
    domain_text: tuple[str, ...]
    Gamma: sympy.Matrix | None
    phi: sympy.Expr | None
    gamma_source: str | None
    x_e_sign: float
    q_symbols: tuple[sympy.Symbol, ...]
    p_symbols: tuple[sympy.Symbol, ...]
    x_e_symbols: tuple[sympy.Symbol, ...]
    u_symbols: tuple[sympy.Symbol, ...]
    parameter_symbols: tuple[sympy.Symbol, ...]
    controller: dict = field(default_factory=dict)
    notes: tuple[str, ...] = ()
    gains: dict[str, sympy.Matrix] = field(default_factory=dict)
    """The [controller] table's gains as matrices (q_d a column), in the [controller.parameters] symbols."""
    gain_parameters: dict[str, Parameter] = field(default_factory=dict)
    u_max: tuple[float, ...] | None = None
    operating_point: Any = None
    """The [operating_point] rule (components.operating_point.Rule) for n_e > n_m; None: the default, the least
    electrical energy."""
    """The actuator's range |u_i| <= u_max_i, in the units of u (optional; `plant check` compares the inputs the
    designs command at the start with it)."""
    sha256: str = ""
    """The SHA-256 of the file's text (UTF-8): what generated source says it was made from (components.source_text:
    never the file's path or text)."""

    @property
    def n_m(self) -> int:
        return len(self.q)

    @property
    def n_e(self) -> int:
        return len(self.x_e)

    @property
    def defaults(self) -> dict[sympy.Symbol, float]:
        """The parameter symbols at their default values."""
        return {s: self.parameters[s.name].default for s in self.parameter_symbols}

    @property
    def constant_mass(self) -> bool:
        return not (self.M.free_symbols & set(self.q_symbols))


def load(path: str | Path) -> Description:
    """Read and check the description file at `path`."""
    path = Path(path)
    try:
        with path.open("rb") as f:
            data = f.read(MAX_FILE + 1)
    except OSError as e:
        raise DescriptionError(f"{path}: [file] {path.name}: cannot be read ({e.strerror})") from None
    if len(data) > MAX_FILE:
        raise DescriptionError(f"{path}: [file] {path.name}: larger than {MAX_FILE} bytes (MAX_FILE)")
    try:
        text = data.decode("utf-8")
    except UnicodeDecodeError as e:
        raise DescriptionError(f"{path}: [file] {path.name}: not UTF-8 text ({e.reason} at byte {e.start})") from None
    return parse(text, str(path))


def parse(text: str, source: str = "<string>") -> Description:
    """Parse and check a description given as TOML text (`source` names it in errors)."""
    return _Parser(source).run(text)


class _Parser:
    def __init__(self, source: str):
        self.source = source
        self.notes: list[str] = []

    def error(self, table: str, entry: str, message: str) -> DescriptionError:
        return DescriptionError(f"{self.source}: [{table}] {entry}: {message}")

    # ---- the file -----------------------------------------------------------------------------------
    def run(self, text: str) -> Description:
        if len(text) > MAX_FILE:
            raise self.error("file", "TOML", f"larger than {MAX_FILE} characters (MAX_FILE)")
        try:
            data = tomllib.loads(text)
        except tomllib.TOMLDecodeError as e:
            raise self.error("file", "TOML", f"syntax error: {e}") from None
        extra = set(data) - TOP_KEYS
        if extra:
            raise self.error("top level", sorted(extra)[0], f"unknown key; the keys are {sorted(TOP_KEYS)}")
        for key in ("name", "description", "variables", "parameters", "model"):
            if key not in data:
                raise self.error("top level", key, "missing")
        name = data["name"]
        problem = identifier_problem(name, "device")
        if problem:
            raise self.error("top level", "name", f"{problem} (the device's name names its FMUs)")
        problem = text_problem(data["description"])
        if problem:
            raise self.error("top level", "description", f"must be a string of text: it {problem}"
                             if isinstance(data["description"], str) else "must be a string")
        variables = self.variables(data["variables"])
        parameters = self.parameters(data["parameters"], "parameters", set(variables["names"]))
        self.symbols: dict[str, sympy.Symbol] = {}
        for kind in VARIABLE_KINDS:
            for v in variables[kind]:
                self.symbols[v.name] = sympy.Symbol(v.name, real=True)
        for p in parameters.values():
            assumption = {"> 0": {"positive": True}, ">= 0": {"nonnegative": True}}.get(p.condition, {"real": True})
            self.symbols[p.name] = sympy.Symbol(p.name, **assumption)
        self.parameters_ = parameters
        self.q_sym = tuple(self.symbols[v.name] for v in variables["q"])
        self.x_sym = tuple(self.symbols[v.name] for v in variables["x_e"])
        self.par_sym = tuple(self.symbols[n] for n in parameters)
        self.defaults = {self.symbols[n]: p.default for n, p in parameters.items()}
        self.n_m, self.n_e = len(variables["q"]), len(variables["x_e"])
        model = self.model(data["model"])
        controller = data.get("controller", {})
        if not isinstance(controller, dict):
            raise self.error("controller", "controller", "must be a table")
        self.controller_table(controller, set(variables["names"]) | set(parameters))
        self.rule = self.operating_point_table(data.get("operating_point"), variables["x_e"], model)
        if model["gamma_source"] == "derived":
            model["Gamma"], model["phi"], model["gamma_source"] = self.scaled_factorization(model)
        return Description(
            name=name, description=data["description"], source=self.source,
            q=variables["q"], p=variables["p"], x_e=variables["x_e"], u=variables["u"], parameters=parameters,
            **model, q_symbols=self.q_sym, p_symbols=tuple(self.symbols[v.name] for v in variables["p"]),
            x_e_symbols=self.x_sym, u_symbols=tuple(self.symbols[v.name] for v in variables["u"]),
            parameter_symbols=self.par_sym, controller=controller, notes=tuple(self.notes),
            gains=self.gain_matrices, gain_parameters=self.gain_parameters, operating_point=self.rule,
            sha256=hashlib.sha256(text.encode("utf-8")).hexdigest())

    def variables(self, table: Any) -> dict[str, Any]:
        if not isinstance(table, dict):
            raise self.error("variables", "variables", "must be a table")
        extra = set(table) - set(VARIABLE_KINDS)
        if extra:
            raise self.error("variables", sorted(extra)[0], f"unknown key; the keys are {list(VARIABLE_KINDS)}")
        out: dict[str, Any] = {"names": []}
        for kind in VARIABLE_KINDS:
            if kind not in table:
                raise self.error("variables", kind, "missing")
            entries = table[kind]
            if not isinstance(entries, list) or not entries:
                raise self.error("variables", kind, "must be a non-empty list of [name, unit, description]")
            specs = []
            for i, e in enumerate(entries):
                if not (isinstance(e, list) and len(e) == 3 and all(isinstance(s, str) for s in e)):
                    raise self.error("variables", f"{kind}[{i}]", f"{e!r} is not [name, unit, description] (strings)")
                self.check_name("variables", f"{kind}[{i}]", e[0], out["names"])
                self.check_text("variables", f"{kind}[{i}]", e[1], e[2])
                out["names"].append(e[0])
                specs.append(VariableSpec(*e))
            out[kind] = tuple(specs)
        if len(out["p"]) != len(out["q"]):
            raise self.error("variables", "p", f"{len(out['p'])} momenta for {len(out['q'])} positions q (n_m each)")
        if len(out["u"]) != len(out["x_e"]):
            raise self.error("variables", "u", f"{len(out['u'])} inputs for {len(out['x_e'])} electrical states (n_e each)")
        for kind in ("q", "x_e"):
            if len(out[kind]) > MAX_DIMENSION:
                raise self.error("variables", kind, f"{len(out[kind])} entries: at most {MAX_DIMENSION} (MAX_DIMENSION)")
        derived = [f"{v.name}_0" for k in ("q", "p", "x_e") for v in out[k]]
        derived += [f"{v.name}_star{s}" for v in out["q"] for s in ("", "_dot", "_ddot", "_dddot")]
        self.derived_names = set(derived)
        clash = sorted(set(derived) & set(out["names"]))
        if clash:
            raise self.error("variables", clash[0], "is a name the FMUs derive from another variable (<state>_0, "
                                                    "<q>_star...); choose another")
        return out

    def check_name(self, table: str, entry: str, name: str, taken) -> None:
        if name in FUNCTIONS:
            raise self.error(table, entry, f"name {name!r} is a function of the expressions; choose another")
        problem = identifier_problem(name)
        if problem:
            raise self.error(table, entry, f"name {problem}")
        if name in taken:
            raise self.error(table, entry, f"name {name!r} is used twice (variables and parameters share one namespace)")

    def check_text(self, table: str, entry: str, unit: Any, text: Any) -> None:
        """A unit (components.identifiers.unit_problem) and a description (text_problem): data only."""
        problem = unit_problem(unit)
        if problem:
            raise self.error(table, entry, f"unit {problem}")
        problem = text_problem(text)
        if problem:
            raise self.error(table, entry, f"description {problem}")

    def parameters(self, table: Any, where: str, taken: set[str]) -> dict[str, Parameter]:
        if not isinstance(table, dict):
            raise self.error(where, where, "must be a table")
        if len(table) > MAX_PARAMETERS:
            raise self.error(where, where, f"{len(table)} parameters: at most {MAX_PARAMETERS} (MAX_PARAMETERS)")
        out: dict[str, Parameter] = {}
        for name, e in table.items():
            self.check_name(where, name, name, taken | set(out))
            if name in getattr(self, "derived_names", ()):
                raise self.error(where, name, f"name {name!r} is a name the FMUs derive from a variable (<state>_0, "
                                              "<q>_star...); choose another")
            if not (isinstance(e, list) and len(e) in (3, 4)):
                raise self.error(where, name, f"{e!r} is not [default, unit, description] or [default, unit, description, "
                                              "condition]")
            default, unit, text = e[:3]
            condition = e[3] if len(e) == 4 else "any"
            if isinstance(default, bool) or not isinstance(default, (int, float)):
                raise self.error(where, name, f"default {default!r} is not a number")
            if not isinstance(unit, str) or not unit or not isinstance(text, str):
                raise self.error(where, name, "unit and description must be strings (unit \"1\" if dimensionless)")
            self.check_text(where, name, unit, text)
            if condition not in CONDITIONS:
                raise self.error(where, name, f"condition {condition!r} is not one of {list(CONDITIONS)}")
            p = Parameter(name, float(default), unit, text, condition)
            try:
                p.check(p.default)
            except ValueError as err:
                raise self.error(where, name, f"default: {err}") from None
            out[name] = p
        return out

    # ---- expressions ----------------------------------------------------------------------------------
    def expr(self, table: str, entry: str, value: Any, allowed: set[sympy.Symbol]) -> sympy.Expr:
        """One expression: a number or a string of names, numbers, + - * / ** ^ and parentheses."""
        if isinstance(value, bool) or not isinstance(value, (str, int, float)):
            raise self.error(table, entry, f"{value!r} is not an expression (a string or a number)")
        if not isinstance(value, str):
            problem = _double_problem(value)
            if problem:
                raise self.error(table, entry, f"{value!r} {problem}")
            return sympy.Float(value) if isinstance(value, float) else sympy.Integer(value)
        if not EXPRESSION_CHARACTERS.match(value):
            bad = next(ch for ch in value if not EXPRESSION_CHARACTERS.match(ch))
            raise self.error(table, entry, f"{value[:60]!r}: the character {bad!r} is not allowed (names, numbers, "
                                           "+ - * / ** ^, parentheses and spaces only)")
        if len(value) > MAX_EXPRESSION:
            raise self.error(table, entry, f"the expression has {len(value)} characters; at most {MAX_EXPRESSION}")
        try:
            tokens = list(tokenize.generate_tokens(io.StringIO(value).readline))
        except (tokenize.TokenError, IndentationError, SyntaxError) as e:
            raise self.error(table, entry, f"{value!r} is not an expression ({e})") from None
        pieces = []
        for t in tokens:
            if t.type in (tokenize.NEWLINE, tokenize.NL, tokenize.ENDMARKER, tokenize.INDENT, tokenize.DEDENT):
                continue
            if t.type == tokenize.NAME:
                if t.string in FUNCTIONS:
                    pieces.append(t.string)
                    continue
                if t.string not in self.symbols:
                    raise self.error(table, entry, f"unknown symbol {t.string!r} in {value!r} (known: variables "
                                                   f"{[s for s in self.symbols if s not in self.parameters_]}, parameters "
                                                   f"{list(self.parameters_)}, functions {list(FUNCTIONS)})")
                if self.symbols[t.string] not in allowed:
                    raise self.error(table, entry, f"{t.string!r} may not appear in {value!r}: "
                                                   f"{self.allowed_text(allowed)}")
                pieces.append(t.string)
            elif t.type == tokenize.NUMBER:
                if not NUMBER.match(t.string):
                    raise self.error(table, entry, f"number {t.string!r} in {value!r} is not a decimal number")
                if len(t.string) > MAX_LITERAL:
                    raise self.error(table, entry, f"number {t.string[:20]}... has more than {MAX_LITERAL} characters")
                mantissa = t.string.lower().split("e")[0]
                problem = _double_problem(float(t.string), nonzero=any(c in "123456789" for c in mantissa))
                if problem:
                    raise self.error(table, entry, f"number {t.string} in {value!r} {problem}")
                pieces.append(t.string)
            elif t.type == tokenize.OP and t.string in OPERATORS:
                pieces.append("**" if t.string == "^" else t.string)
            else:
                raise self.error(table, entry, f"{t.string!r} in {value!r} is not allowed (names, numbers, "
                                               "+ - * / ** ^ and parentheses only)")
        if not pieces:
            raise self.error(table, entry, "empty expression")
        if len(pieces) > MAX_NODES:
            raise self.error(table, entry, f"{value[:40]!r}... has {len(pieces)} terms and operations; at most {MAX_NODES}")
        local = {**{k: v for k, v in FUNCTIONS.items()}, **self.symbols}
        glob = {"__builtins__": {}, "Integer": sympy.Integer, "Float": sympy.Float, "Rational": sympy.Rational,
                "Add": sympy.Add, "Mul": sympy.Mul, "Pow": sympy.Pow,
                "Symbol": sympy.Symbol}
        try:
            tree = parse_expr(" ".join(pieces), local_dict=local, global_dict=glob, evaluate=False)
        except Exception as e:  # sympy reports malformed input with several exception types
            raise self.error(table, entry, f"{value!r} is not an expression ({type(e).__name__})") from None
        if not isinstance(tree, sympy.Expr):
            raise self.error(table, entry, f"{value!r} is not an expression")
        nodes = sum(1 for _ in sympy.preorder_traversal(tree))
        if nodes > MAX_NODES:
            raise self.error(table, entry, f"{value!r} has {nodes} terms and operations; at most {MAX_NODES}")
        problem = _exponent_problem(tree, 1)             # 9**9**9, ((q+1)**1000)**1000: forever to evaluate
        if problem is None:
            try:
                _constant(tree)                          # exp(exp(exp(1000))), 9**1000: not a double
            except _NotADouble as e:
                problem = str(e)
        if problem:
            raise self.error(table, entry, f"{value!r}: {problem}")
        result = None
        with time_limit(SYMBOLIC_SECONDS) as limit:
            result = tree.doit()
        if limit.expired:
            raise self.error(table, entry, f"{value!r} takes longer than {SYMBOLIC_SECONDS:g} s to evaluate")
        if not isinstance(result, sympy.Expr) or result.has(sympy.zoo, sympy.nan, sympy.oo, sympy.I):
            raise self.error(table, entry, f"{value!r} is not a finite real expression")
        for node in sympy.preorder_traversal(result):
            if isinstance(node, sympy.Pow) and node.exp.is_number and not abs(node.exp) <= MAX_EXPONENT:
                raise self.error(table, entry, f"{value!r}: the power {_text(node)} has an exponent beyond +-{MAX_EXPONENT}")
        try:
            _constant(result)                  # sympy's form too: exp(q + 1000) becomes 1.97e434*exp(q)
        except _NotADouble as e:
            raise self.error(table, entry, f"{value!r} (evaluated: {str(result)[:80]}): {e}") from None
        return result

    def allowed_text(self, allowed: set[sympy.Symbol]) -> str:
        kinds = []
        if set(self.q_sym) & allowed:
            kinds.append("positions q")
        if set(self.x_sym) & allowed:
            kinds.append("electrical states x_e")
        kinds.append("parameters")
        return "it may depend on " + " and ".join(kinds) + " only"

    def matrix(self, table: str, entry: str, value: Any, shape: tuple[int, int], allowed: set[sympy.Symbol]) -> sympy.Matrix:
        """A matrix as a list of rows (a single expression when it is 1 x 1)."""
        rows_n, cols_n = shape
        if not isinstance(value, list):
            if shape != (1, 1):
                raise self.error(table, entry, f"must be a {rows_n} x {cols_n} matrix (a list of {rows_n} rows); "
                                               "a single expression is allowed only for 1 x 1")
            return sympy.Matrix([[self.expr(table, entry, value, allowed)]])
        if len(value) != rows_n or not all(isinstance(r, list) and len(r) == cols_n for r in value):
            got = (f"{len(value)} rows of lengths {[len(r) if isinstance(r, list) else '-' for r in value]}")
            raise self.error(table, entry, f"must be {rows_n} x {cols_n} (n_m = {self.n_m}, n_e = {self.n_e}); got {got}")
        return sympy.Matrix([[self.expr(table, f"{entry}[{i}][{j}]", x, allowed) for j, x in enumerate(r)]
                             for i, r in enumerate(value)])

    def numeric(self, A: sympy.Matrix) -> np.ndarray:
        return np.array(A.subs(self.defaults).evalf(), dtype=float)

    # ---- the model ------------------------------------------------------------------------------------
    def model(self, table: Any) -> dict[str, Any]:
        if not isinstance(table, dict):
            raise self.error("model", "model", "must be a table")
        extra = set(table) - set(MODEL_REQUIRED) - set(MODEL_OPTIONAL)
        if extra:
            raise self.error("model", sorted(extra)[0], f"unknown key; the keys are {list(MODEL_REQUIRED + MODEL_OPTIONAL)}")
        for key in MODEL_REQUIRED:
            if key not in table:
                raise self.error("model", key, "missing")
        m, e = self.n_m, self.n_e
        par, q = set(self.par_sym), set(self.q_sym)
        M = self.matrix("model", "M", table["M"], (m, m), par | q)
        V = self.expr("model", "V", table["V"], par | q)
        Psi = self.matrix("model", "Psi", table["Psi"], (e, e), par | q)
        R_m = self.matrix("model", "R_m", table["R_m"], (m, m), par)
        J_e = self.matrix("model", "J_e", table["J_e"], (e, e), par)
        R_e = self.matrix("model", "R_e", table["R_e"], (e, e), par)
        G_e = self.matrix("model", "G_e", table["G_e"], (e, e), par)
        domain, margins, texts = self.domain(table.get("domain", []))
        self.margins = margins
        for entry, value in (("M", M), ("V", V), ("Psi", Psi), ("R_m", R_m), ("J_e", J_e), ("R_e", R_e), ("G_e", G_e),
                             *((f"domain[{i}]", g) for i, g in enumerate(margins))):
            self.finite_at_defaults(entry, value)
        self.constant_checks(R_m, J_e, R_e, G_e)
        self.symmetric("M", M)
        self.positive_definite("M", M, "M(q) > 0 (mass-inertia matrix)")
        self.symmetric("Psi", Psi)
        self.positive_definite("Psi", Psi, "Psi(q) > 0 on the domain (inverse capacitance / inductance, eq. elec energy)")
        Gamma, phi, source = self.gamma_phi(table, Psi)
        sign = table.get("x_e_sign", 1)
        if isinstance(sign, bool) or sign not in (1, -1):
            raise self.error("model", "x_e_sign", f"{sign!r} must be 1 or -1 (the root x_e* of Definition 1 the reference uses)")
        return dict(M=M, V=V, Psi=Psi, R_m=R_m, J_e=J_e, R_e=R_e, G_e=G_e, domain=domain, domain_margins=margins,
                    domain_text=texts, Gamma=Gamma, phi=phi, gamma_source=source, x_e_sign=float(sign),
                    u_max=self.u_max(table.get("u_max")))

    def u_max(self, value: Any) -> tuple[float, ...] | None:
        """The actuator's range: a number per input (a single number for n_e = 1), each finite and > 0."""
        if value is None:
            return None
        values = value if isinstance(value, list) else [value]
        if len(values) != self.n_e or not all(isinstance(v, (int, float)) and not isinstance(v, bool)
                                              and math.isfinite(v) and v > 0 for v in values):
            raise self.error("model", "u_max", f"{value!r} must be {self.n_e} finite number(s) > 0, one per input "
                                               "(the range |u_i| <= u_max_i)")
        return tuple(float(v) for v in values)

    def finite_at_defaults(self, entry: str, value: Any) -> None:
        """No pole (division by zero) and no non-real value at the default parameter values."""
        at = value.subs(self.defaults)
        if at.has(sympy.zoo, sympy.nan, sympy.oo, sympy.I):
            where = ", ".join(f"{s} = {v:.6g}" for s, v in self.defaults.items() if s in value.free_symbols)
            raise self.error("model", entry, f"is not finite at the default parameter values ({where}): "
                                             f"{value} becomes {at} (a pole?)")

    def domain(self, entries: Any) -> tuple[tuple, tuple, tuple]:
        if not isinstance(entries, list) or not all(isinstance(s, str) for s in entries):
            raise self.error("model", "domain", "must be a list of strict inequalities such as \"q < c\"")
        rels, margins = [], []
        allowed = set(self.par_sym) | set(self.q_sym)
        for i, s in enumerate(entries):
            entry = f"domain[{i}]"
            if any(op in s for op in ("<=", ">=", "==", "!=", "=")):
                raise self.error("model", entry, f"{s!r} must be a strict inequality (< or >)")
            parts = re.split(r"([<>])", s)
            if len(parts) != 3:
                raise self.error("model", entry, f"{s!r} must be one strict inequality a < b or a > b")
            lhs = self.expr("model", entry, parts[0], allowed)
            rhs = self.expr("model", entry, parts[2], allowed)
            g = sympy.expand(rhs - lhs if parts[1] == "<" else lhs - rhs)
            if not g.free_symbols & set(self.q_sym):
                raise self.error("model", entry, f"{s!r} does not depend on the positions q")
            rels.append(sympy.StrictGreaterThan(g, 0))
            margins.append(g)
        return tuple(rels), tuple(margins), tuple(entries)

    def constant_checks(self, R_m, J_e, R_e, G_e) -> None:
        scale = lambda A: max(1.0, float(np.max(np.abs(A))))  # noqa: E731
        if not self.is_zero_matrix(R_m - R_m.T, "R_m"):
            raise self.error("model", "R_m", f"{R_m.tolist()} is not symmetric (mechanical damping)")
        lam = np.linalg.eigvalsh(self.numeric(R_m))
        if np.min(lam) < -1e-12 * scale(lam):
            raise self.error("model", "R_m", f"is not positive semi-definite at the default parameters "
                                             f"(smallest eigenvalue {np.min(lam):.6g}; mechanical damping R_m >= 0)")
        if not self.is_zero_matrix(J_e + J_e.T, "J_e"):
            raise self.error("model", "J_e", f"{J_e.tolist()} is not skew-symmetric (J_e = -J_e^T)")
        if not self.is_zero_matrix(R_e - R_e.T, "R_e"):
            raise self.error("model", "R_e", f"{R_e.tolist()} is not symmetric (electrical damping)")
        lam = np.linalg.eigvalsh(self.numeric(R_e))
        if np.min(lam) < -1e-12 * scale(lam):
            raise self.error("model", "R_e", f"is not positive semi-definite at the default parameters "
                                             f"(smallest eigenvalue {np.min(lam):.6g}; electrical damping R_e >= 0)")
        G = self.numeric(G_e)
        sv = np.linalg.svd(G, compute_uv=False)
        if not sv[-1] > 1e-12 * sv[0]:
            raise self.error("model", "G_e", f"{G.tolist()} is singular at the default parameters "
                                             "(the input matrix G_e must be invertible)")

    def is_zero_matrix(self, A: sympy.Matrix, entry: str = "model") -> bool:
        """Every entry simplifies to 0 (within SYMBOLIC_SECONDS, else a DescriptionError at `entry`)."""
        result = False
        with time_limit(SYMBOLIC_SECONDS) as limit:
            result = all(a == 0 or sympy.simplify(a) == 0 for a in A)
        if limit.expired:
            raise self.error("model", entry, f"the symbolic identity check took longer than {SYMBOLIC_SECONDS:g} s "
                                             "(SYMBOLIC_SECONDS); simplify the expressions")
        return result

    def symmetric(self, entry: str, A: sympy.Matrix) -> None:
        if not self.is_zero_matrix(A - A.T, entry):
            raise self.error("model", entry, f"{A.tolist()} is not symmetric")

    def positive_definite(self, entry: str, A: sympy.Matrix, what: str) -> None:
        """A > 0 on the domain: Sylvester's criterion decided by sympy under the domain's inequalities,
        otherwise at sample points of the domain at the default parameters (noted in `notes`)."""
        minors: list[sympy.Expr] = []
        decided: list[bool | None] = []
        with time_limit(SYMBOLIC_SECONDS) as limit:
            for k in range(1, A.shape[0] + 1):
                minors.append(A[:k, :k].det())
                decided.append(self.sign_on_domain(minors[-1]))
                if decided[-1] is False:
                    raise self.error("model", entry, f"violates {what}: the leading minor {k} "
                                                     f"{minors[-1]} is not positive on the domain")
        if not limit.expired and all(d is True for d in decided):
            self.notes.append(f"{entry}: {what}: decided symbolically")
            return
        stopped = (f"the symbolic check (Sylvester's criterion) stopped at its time limit of {SYMBOLIC_SECONDS:g} s "
                   f"after {len(decided)} of {A.shape[0]} minors; " if limit.expired else "")
        points = self.sample_points()
        if not points:
            raise self.error("model", entry, f"cannot check {what}: no sample point inside the domain "
                                             f"{list(self.margins)} at the default parameters")
        f = sympy.lambdify(self.q_sym, A.subs(self.defaults), "numpy")
        for qv in points:
            with np.errstate(all="ignore"):
                a = np.array(f(*qv), dtype=float).reshape(A.shape)
            if not np.all(np.isfinite(a)):
                where = ", ".join(f"{s} = {v:.6g}" for s, v in zip(self.q_sym, qv))
                raise self.error("model", entry, f"cannot check {what}: not finite at {where} (default parameters)")
            lam = np.linalg.eigvalsh(0.5 * (a + a.T))
            if not np.min(lam) > 0:
                where = ", ".join(f"{s} = {v:.6g}" for s, v in zip(self.q_sym, qv))
                raise self.error("model", entry, f"violates {what} at {where} (default parameters; smallest "
                                                 f"eigenvalue {np.min(lam):.6g})")
        self.notes.append(f"{entry}: {what}: {stopped or 'not decided by sympy; '}checked at {len(points)} sample "
                          "points of the domain at the default parameters")

    def sign_on_domain(self, expr: sympy.Expr) -> bool | None:
        """True / False when sympy decides expr > 0 for every q in the domain and every admissible parameter."""
        expr = sympy.simplify(expr)
        if not expr.free_symbols & set(self.q_sym):
            value = expr.is_positive
            if value is None:
                return None
            return bool(value)
        subs: dict = {}
        used: set = set()
        for j, g in enumerate(self.margins):
            g = sympy.expand(g.subs(subs))
            for qk in self.q_sym:
                if qk in used or qk not in g.free_symbols:
                    continue
                poly = sympy.Poly(g, qk) if g.is_polynomial(qk) else None
                if poly is None or poly.degree() != 1 or poly.LC().free_symbols & set(self.q_sym):
                    continue
                s = sympy.Symbol(f"_margin{j}", positive=True)
                solution = sympy.solve(sympy.Eq(g, s), qk)
                if len(solution) != 1:
                    continue
                subs = {k: v.subs(qk, solution[0]) for k, v in subs.items()}
                subs[qk] = solution[0]
                used.add(qk)
                break
        if set(self.q_sym) - used:
            return None
        e = sympy.factor(sympy.simplify(expr.subs(subs)))
        value = e.is_positive
        return None if value is None else bool(value)

    def sample_points(self) -> list[tuple[float, ...]]:
        """Up to SAMPLE_POINTS positions inside the domain (default parameters): q = 0 and Gaussian points
        scaled by 1e-6 ... 1e2, fixed seed."""
        rng = np.random.default_rng(25)
        margins = [sympy.lambdify(self.q_sym, g.subs(self.defaults), "math") for g in self.margins]
        candidates = [np.zeros(self.n_m)]
        for scale in np.logspace(-6, 2, 17):
            candidates += list(scale * rng.standard_normal((24, self.n_m)))
        inside = []
        for qv in candidates:
            try:
                if all(float(g(*qv)) > 0 for g in margins):
                    inside.append(tuple(float(v) for v in qv))
            except (ZeroDivisionError, ValueError, OverflowError):
                continue
            if len(inside) >= SAMPLE_POINTS:
                break
        return inside

    def gamma_phi(self, table: Mapping, Psi: sympy.Matrix) -> tuple:
        """Gamma and phi of Assumptions 2/4 (grad_q H_e = -Gamma grad phi(x_e), eq. assHereg): given, or derived
        when Psi is affine in q and every dPsi/dq_k is diagonal, else None."""
        par, x = set(self.par_sym), set(self.x_sym)
        H_e = (sympy.Matrix(self.x_sym).T * Psi * sympy.Matrix(self.x_sym))[0, 0] / 2       # eq. (elec energy)
        grad_q = sympy.Matrix([sympy.diff(H_e, qk) for qk in self.q_sym])
        if ("Gamma" in table) != ("phi" in table):
            missing = "phi" if "Gamma" in table else "Gamma"
            raise self.error("model", missing, "Gamma and phi are given together or not at all")
        if "Gamma" in table:
            Gamma = self.matrix("model", "Gamma", table["Gamma"], (self.n_m, self.n_e), par)
            phi = self.expr("model", "phi", table["phi"], par | x)
            grad_phi = sympy.Matrix([sympy.diff(phi, xi) for xi in self.x_sym])
            if not self.is_zero_matrix(grad_q + Gamma * grad_phi, "Gamma"):
                raise self.error("model", "Gamma", "grad_q H_e = -Gamma grad phi(x_e) (Assumption 2, eq. assHereg) does "
                                                   f"not hold: grad_q H_e = {list(grad_q)}")
            self.notes.append("Gamma, phi: given; grad_q H_e = -Gamma grad phi checked symbolically")
            return Gamma, phi, "given"
        dPsi = [Psi.diff(qk) for qk in self.q_sym]
        affine = all(self.is_zero_matrix(D.diff(ql), "Psi") for D in dPsi for ql in self.q_sym)
        diagonal = all(D[i, j] == 0 or sympy.simplify(D[i, j]) == 0
                       for D in dPsi for i in range(self.n_e) for j in range(self.n_e) if i != j)
        if not (affine and diagonal):
            self.notes.append("Gamma, phi: not derived (Psi is not affine in q with diagonal dPsi/dq_k)")
            return None, None, None
        Gamma = sympy.Matrix(self.n_m, self.n_e, lambda k, i: sympy.simplify(-dPsi[k][i, i] / 2))   # Sec. 7.2
        phi = sum((xi ** 3 / 3 for xi in self.x_sym), sympy.Integer(0))                           # Sec. 7.2
        grad_phi = sympy.Matrix([xi ** 2 for xi in self.x_sym])
        assert self.is_zero_matrix(grad_q + Gamma * grad_phi, "Psi")   # eq. (assHereg), by construction
        self.notes.append("Gamma, phi: derived (Psi affine in q, diagonal dPsi/dq_k): Gamma[k][i] = -dPsi_ii/dq_k / 2, "
                          "phi = sum x_e_i^3 / 3")
        return Gamma, phi, "derived"

    def scaled_factorization(self, model: dict) -> tuple:
        """The derived Gamma, phi in the device's scale (docs/plant-description.md, docs/derivations.md section 12):
        Gamma = Gamma_0 S, phi = sum_i x_e_i^3 / (3 s_i), S = diag(s), with s_i = |x_e_d_i| / |(Gamma_0^T q_d)_i|
        at the operating point (q_d of [controller], x_e_d of the set E there, at the default parameters), so that
        Gamma^T q_d and x_e_d have the same magnitude, port by port. Gamma grad phi = Gamma_0 grad phi_0: eq.
        (assHereg) holds for every S. A port whose s_i is undefined keeps s_i = 1 (the paper's Section 7.2)."""
        Gamma0, phi0 = model["Gamma"], model["phi"]
        point = self.operating_point(model)
        if isinstance(point, str):
            self.notes.append(f"Gamma, phi: not scaled ({point}): the paper's Section 7.2 form")
            return Gamma0, phi0, "derived"
        q_d, x_e_d = point
        g0 = np.array(Gamma0.subs(self.defaults).evalf(), dtype=float).T @ q_d
        scales = []
        for i in range(self.n_e):
            ok = abs(g0[i]) > 0 and abs(x_e_d[i]) > 0 and math.isfinite(abs(x_e_d[i]) / abs(g0[i]))
            scales.append(sympy.Rational(f"{abs(x_e_d[i]) / abs(g0[i]):.6g}") if ok else sympy.Integer(1))
        Gamma = Gamma0 * sympy.diag(*scales)
        phi = sum((xi ** 3 / (3 * s_i) for xi, s_i in zip(self.x_sym, scales)), sympy.Integer(0))
        self.notes.append("Gamma, phi: scaled to the operating point q_d = " + _list(q_d) + ", x_e_d = " + _list(x_e_d)
                          + ": s = " + _list([float(v) for v in scales]) + " (Gamma = Gamma_0 diag(s), "
                          "phi = sum x_e_i^3 / (3 s_i), Gamma^T q_d = |x_e_d| port by port)")
        return Gamma, phi, "derived, scaled"

    def operating_point(self, model: dict) -> tuple[np.ndarray, np.ndarray] | str:
        """(q_d, x_e_d) at the default parameters for the scaling of Gamma, phi: q_d the [controller] q_d (numbers),
        x_e_d_i = sqrt(w_i) with A(q_d) w = -grad V(q_d), A_ki = dPsi_ii/dq_k / 2 (the p-row at rest, eq.
        open-loop elecmech); a reason (str) where there is none."""
        q_gain = self.gain_matrices.get("q_d")
        if q_gain is None or q_gain.free_symbols:
            return "no [controller] q_d given as numbers"
        q_d = np.array(q_gain.evalf(), dtype=float).reshape(-1)
        at = {**self.defaults, **dict(zip(self.q_sym, q_d))}
        dPsi = [model["Psi"].diff(qk) for qk in self.q_sym]
        A = np.array([[float(dPsi[k][i, i].subs(at)) / 2 for i in range(self.n_e)] for k in range(self.n_m)])
        b = -np.array([float(sympy.diff(model["V"], qk).subs(at)) for qk in self.q_sym])
        if self.n_e > self.n_m:                       # the operating-point rule fixes the free coordinates
            from .operating_point import NoOperatingPoint, Rule, solve, weights
            Psi = np.array(model["Psi"].subs(at).evalf(), dtype=float)
            rule = self.rule or Rule(given=False)
            R_e, J_e, G_e = (self.numeric(model[k]) for k in ("R_e", "J_e", "G_e"))
            try:
                x, _ = solve(rule, A, b, weights(rule, np.diag(Psi), R_e, J_e, G_e), 1.0)
            except NoOperatingPoint as exc:
                return f"no operating point at q_d: {exc}"
            return q_d, np.abs(x)
        if self.n_e != self.n_m or abs(np.linalg.det(A)) == 0:
            return "x_e_d is not fixed by the force balance at q_d (n_e < n_m or A(q_d) singular)"
        w = np.linalg.solve(A, b)
        if not np.all(w > 0):
            return f"x_e_d^2 = {_list(w)} at q_d has an entry <= 0"
        return q_d, np.sqrt(w)

    def operating_point_table(self, table: Any, x_e: Sequence[VariableSpec], model: dict) -> Any:
        """[operating_point]: rule = "least_energy" | "bias"; for a bias, n_e - n_m entries <x_e name> = value or
        [<x_e name>, ratio] (components.operating_point.Rule). Only for n_e > n_m with diagonal Psi, dPsi/dq_k."""
        from .operating_point import RULES, Rule
        if table is None:
            return None
        if not isinstance(table, dict):
            raise self.error("operating_point", "operating_point", "must be a table")
        if self.n_e <= self.n_m:
            raise self.error("operating_point", "rule", f"n_e = {self.n_e} <= n_m = {self.n_m}: the force balance fixes "
                                                        "x_e (where it has a solution); there is nothing to choose")
        dPsi = [model["Psi"].diff(qk) for qk in self.q_sym]
        if not all(self.is_zero_matrix(D - sympy.diag(*D.diagonal())) for D in [*dPsi, model["Psi"]]):
            raise self.error("operating_point", "rule", "needs Psi(q) and every dPsi/dq_k diagonal (the force balance "
                                                        "linear in x_e_i^2, components.operating_point)")
        kind = table.get("rule")
        if kind not in RULES:
            raise self.error("operating_point", "rule", f"{kind!r} is not one of {list(RULES)}")
        names = [v.name for v in x_e]
        entries = {k: v for k, v in table.items() if k != "rule"}
        unknown = sorted(set(entries) - set(names))
        if unknown:
            raise self.error("operating_point", unknown[0], f"not an electrical state; they are {names}")
        if kind in ("least_energy", "least_input"):
            if entries:
                raise self.error("operating_point", sorted(entries)[0], f"the rule {kind} takes no values")
            if kind == "least_input" and not all(self.is_zero_matrix(M - sympy.diag(*M.diagonal()))
                                                 for M in (model["R_e"], model["J_e"], model["G_e"])):
                raise self.error("operating_point", "rule", "least_input needs diagonal R_e, J_e (= 0) and G_e (the "
                                                            "input at rest linear in x_e_i^2)")
            return Rule(kind)
        if len(entries) != self.n_e - self.n_m:
            raise self.error("operating_point", "rule", f"a bias gives n_e - n_m = {self.n_e - self.n_m} coordinate(s), "
                                                        f"not {len(entries)}")
        values, ratios = [], []
        for name, v in entries.items():
            i = names.index(name)
            if isinstance(v, (int, float)) and not isinstance(v, bool) and math.isfinite(v):
                values.append((i, float(v)))
            elif (isinstance(v, list) and len(v) == 2 and v[0] in names and v[0] not in entries
                  and isinstance(v[1], (int, float)) and not isinstance(v[1], bool) and math.isfinite(v[1]) and v[1] != 0):
                ratios.append((i, names.index(v[0]), float(v[1])))
            else:
                raise self.error("operating_point", name, f"{v!r} must be a finite value or [<x_e name>, ratio] with a "
                                                          "solved coordinate and a ratio != 0")
        return Rule("bias", tuple(values), tuple(ratios))

    # ---- [controller] --------------------------------------------------------------------------------
    def controller_table(self, table: dict, taken: set[str]) -> None:
        """Syntax of the [controller] table (gain defaults; values are checked when a Device is built)."""
        extra = set(table) - set(CONTROLLER_GAINS) - {"parameters"}
        if extra:
            raise self.error("controller", sorted(extra)[0], f"unknown key; the keys are {list(CONTROLLER_GAINS)} "
                                                            "and the table parameters")
        gain_params = self.parameters(table.get("parameters", {}), "controller.parameters", taken)
        self.gain_parameters = gain_params
        gain_symbols = {n: sympy.Symbol(n, real=True) for n in gain_params}
        saved = self.symbols
        self.symbols = {**saved, **gain_symbols}
        self.gain_matrices: dict[str, sympy.Matrix] = {}
        try:
            shapes = {"q_d": (self.n_m, 1), "R_e_bar": (self.n_e, self.n_e), "D_d": (self.n_e, self.n_m),
                      "k_c": (self.n_e, self.n_e), "W": (self.n_e, self.n_e)}
            for gain in CONTROLLER_GAINS:
                if gain in table:
                    value = table[gain]
                    if gain == "q_d" and isinstance(value, list) and all(not isinstance(v, list) for v in value):
                        value = [[v] for v in value]
                    self.gain_matrices[gain] = self.matrix("controller", gain, value, shapes[gain],
                                                           set(gain_symbols.values()))
        finally:
            self.symbols = saved


def gain_table(desc: Description) -> tuple[dict[str, list[list[float]]], dict[str, tuple[sympy.Matrix, tuple[str, ...]]],
                                            dict[str, Parameter]]:
    """The controller gains of `desc`: (defaults, forms, gain parameters).

    defaults[gain]  a matrix (list of rows; q_d a column) of the gains given as numbers, or the defaults:
                    q_d = 0, D_d = 0, k_c = I, R_e_bar = 2 R_e (at the default parameters) when R_e > 0,
                    else I;
    forms[gain]     (matrix in the [controller.parameters] symbols, their names) for a plant-specific form
                    (MEMS: R_e_bar = 1/rbar_e).
    """
    m, e = desc.n_m, desc.n_e
    R_e = np.array(desc.R_e.subs(desc.defaults).evalf(), dtype=float)
    positive = bool(np.min(np.linalg.eigvalsh(R_e)) > 0)
    fallback = {"q_d": np.zeros((m, 1)), "D_d": np.zeros((e, m)), "k_c": np.eye(e),
                "R_e_bar": 2.0 * R_e if positive else np.eye(e)}
    defaults: dict[str, list[list[float]]] = {}
    forms: dict[str, tuple[sympy.Matrix, tuple[str, ...]]] = {}
    for gain in CONTROLLER_GAINS:
        A = desc.gains.get(gain)
        if A is None and gain == "W":               # no gain W: Phi_1 / Theta_1 with W = I, as in the paper
            continue
        if A is not None and A.free_symbols:
            names = tuple(n for n in desc.gain_parameters if sympy.Symbol(n, real=True) in A.free_symbols)
            forms[gain] = (A, names)
            continue
        value = np.array(A.evalf(), dtype=float) if A is not None else fallback[gain]
        defaults[gain] = [[float(x) for x in row] for row in value]
    used = {n for _, names in forms.values() for n in names}
    return defaults, forms, {n: p for n, p in desc.gain_parameters.items() if n in used}


def _list(values: Any) -> str:
    return "(" + ", ".join(f"{float(v):.6g}" for v in values) + ")"


def with_operating_point(text: str, spec: str, source: str = "<string>") -> str:
    """The description `text` with its [operating_point] table replaced by `spec` (the command line's choice):
    "least_energy", or "bias:NAME=VALUE,..." where VALUE is a number or OTHER*RATIO (x_2=0.5, x_2=x_1*0.4).
    A DescriptionError names a malformed spec; the result is checked when it is parsed."""
    kind, _, rest = spec.partition(":")
    kind = kind.strip()
    lines = ["[operating_point]", f"rule = {kind!r}".replace("'", '"')]
    for item in filter(None, (part.strip() for part in rest.split(","))):
        name, eq, value = (v.strip() for v in item.partition("="))
        other, star, ratio = value.partition("*")
        if not (eq and NAME.match(name)):
            raise DescriptionError(f"{source}: [operating_point] {item}: not NAME=VALUE or NAME=OTHER*RATIO")
        try:
            entry = f'["{other.strip()}", {float(ratio)!r}]' if star else repr(float(value))
        except ValueError:
            raise DescriptionError(f"{source}: [operating_point] {item}: not NAME=VALUE or NAME=OTHER*RATIO") from None
        if star and not NAME.match(other.strip()):
            raise DescriptionError(f"{source}: [operating_point] {item}: not NAME=OTHER*RATIO")
        lines.append(f"{name} = {entry}")
    kept, skipping = [], False
    for line in text.splitlines():
        header = line.strip()
        if header.startswith("["):
            skipping = header.split("#")[0].strip() == "[operating_point]"
        if not skipping:
            kept.append(line)
    if re.search(r"^\s*operating_point\s*=", "\n".join(kept), re.MULTILINE):
        raise DescriptionError(f"{source}: [operating_point] operating_point: given inline in the file; write it as a "
                               "table to override it from the command line")
    return "\n".join(kept) + "\n\n" + "\n".join(lines) + "\n"
