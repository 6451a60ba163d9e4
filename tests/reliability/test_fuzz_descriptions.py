"""Fuzzing plant descriptions (issue 31): random and hostile expressions and files through the loader
(components.description), the code generator (components.codegen) and `plant check` (components.plant_check).

Every case must end in a parsed description or a DescriptionError naming the file and the entry; none may run
code (each hostile payload would create a marker file), crash, take longer than its limit or answer silently
wrong:
- an accepted expression has the value an independent evaluation of the same text gives (mpmath at 60
  digits, from the generator's own Python spelling of the tree, never from the description's text), and
  every number in it is finite and normal as a double (the FMU computes in doubles);
- an accepted file generates a module whose code mentions no dangerous name outside string literals and
  whose loading creates no marker;
- `plant check` of random valid variants gives verdicts with finite numbers and the same report twice.
A seeded generator (SEED) makes the cases the same on every run; the counts go to the reliability tally.
"""
from __future__ import annotations

import ast
import math
import random
import time
from pathlib import Path

import mpmath
import pytest
import sympy

from components import codegen, description, plant_check
from components.description import DOUBLE_MIN, DescriptionError, parse
from tests.test_description import ISSUE_MAGLEV

pytestmark = pytest.mark.reliability

SEED = 31
N_VALUE = 3000          # expressions from the grammar, checked against an independent evaluation
N_EXTREME = 2000        # expressions with extreme numbers and exponents (refused, or finite as doubles)
N_HOSTILE_EXPR = 400    # expressions with code in them (always refused)
N_FILES = 500           # mutated files (names, units, text, numbers, shapes, types)
N_CHECKS = 30           # random valid variants through plant check
CASE_LIMIT = 2 * description.SYMBOLIC_SECONDS + 2.0     # seconds one case may take (a hang past its limit fails)

VALUES = {"q": "0.0013", "k": "0.64042", "R_e": "2.25", "c": "0.005", "b": "0.828", "m": "0.0844", "R_m": "0.5"}
NAMES = list(VALUES)
FUNCS = ["sqrt", "exp", "log", "sin", "cos", "tan", "sinh", "cosh", "tanh", "atan", "asin", "acos"]
HOSTILE = [
    "__import__('os').system('touch {m}')", "open('{m}', 'w')", "q.__class__", "(lambda: 1)()", "[q]", "{{q: 1}}",
    "q if q else q", "q; open('{m}', 'w')", "q\nopen('{m}', 'w')", "exec('1')", "eval('q')", "Symbol('x')",
    "Integer(1)", "f'{{q}}'", "'q'", "q @ q", "q % 2", "q // 2", "q == q", "q < 1", "q and q", "not q", "~q",
    "q[0]", "q.subs", "getattr(q, 'x')", "\\x71", "q\\\n+1", "q  # comment", "ｑ", "qé", "q & q", "q << 1",
    "1_000", "0x10", "0b1", "1j", "1e", ".", "(", ")", "q +", "**q", "q ** ** q", "sqrt", "sqrt()", "sqrt(q, q)",
    "exp(q)(q)", "pi(q)", "q(q)", "", " ", "\t", "\x00", "q\x00", "¹", "∞", "q = 1", "import os", "del q",
]


# ---- expressions ------------------------------------------------------------------------------------

def _parser() -> description._Parser:
    p = description._Parser("fuzz.toml")
    p.run(ISSUE_MAGLEV.replace('R_m = [0.0,', 'R_m = [0.5,'))
    return p


def _tree(rng: random.Random, depth: int, extreme: bool) -> tuple[str, str]:
    """(description text, the same tree in Python/mpmath spelling). Value trees use moderate numbers."""
    r = rng.random()
    if depth == 0 or r < 0.25:
        if rng.random() < 0.5:
            name = rng.choice(NAMES)
            return name, name
        if extreme and rng.random() < 0.5:
            x = rng.choice(["1e308", "1.7976931348623157e308", "2e308", "1e-307", "2.2250738585072014e-308", "1e-308",
                            "4.9e-324", "1e-400", "1e400", "0", "0.0", "00", "1" * 39, "1" * 41, "9" * 30, "0.5e-307",
                            "123456789012345678901234567890.5", "1e999999", "1e-999999"])
        else:
            x = rng.choice(["2", "3", "0.5", "1.25", "10", "7", "0.001", "1e3", "2.5e-2"])
        return x, f"mpf('{x}')"
    if r < 0.40:
        f = rng.choice(FUNCS if not extreme else FUNCS)
        a, b = _tree(rng, depth - 1, extreme)
        return f"{f}({a})", f"{f}({b})"
    if r < 0.55:
        a, b = _tree(rng, depth - 1, extreme)
        if extreme:
            e = rng.choice(["2", "3", "-1", "10", "999", "1000", "1001", "40", "0.5", "-0.5", "100", "1e3"])
        else:
            e = rng.choice(["2", "3", "-1", "-2", "0.5"])
        op = rng.choice(["**", "^"])
        return f"({a}){op}{e}", f"({b})**mpf('{e}')"
    if r < 0.6:
        a, b = _tree(rng, depth - 1, extreme)
        return f"-({a})", f"-({b})"
    op = rng.choice(["+", "-", "*", "/"])
    a1, b1 = _tree(rng, depth - 1, extreme)
    a2, b2 = _tree(rng, depth - 1, extreme)
    return f"({a1}) {op} ({a2})", f"({b1}) {op} ({b2})"


def _independent(spelling: str, digits: int = 60) -> complex | None:
    """The value of the generator's own spelling with mpmath at `digits` digits (None where it is undefined)."""
    with mpmath.workdps(digits):
        namespace = {f: getattr(mpmath, f) for f in FUNCS}
        namespace.update(mpf=mpmath.mpf, **{n: mpmath.mpf(v) for n, v in VALUES.items()})
        try:
            value = eval(spelling, {"__builtins__": {}}, namespace)      # the test's own text, never a file's
            return complex(value)
        except (ZeroDivisionError, ValueError, OverflowError, TypeError):
            return None


def _well_conditioned(spelling: str, expected: complex) -> bool:
    """The value does not depend on rounding at double precision (tan of 1e4 does: sympy keeps the literals'
    15 digits, so only well-conditioned values can be compared at 1e-12)."""
    rough = _independent(spelling, 15)
    return rough is not None and abs(rough - expected) <= 1e-13 * max(1.0, abs(expected))


def _numbers_are_doubles(e: sympy.Expr) -> bool:
    for a in sympy.preorder_traversal(e):
        if isinstance(a, (sympy.Float, sympy.Rational)) and a != 0:
            x = abs(float(a))
            if not (math.isfinite(x) and x >= DOUBLE_MIN):
                return False
    return True


def _timed(fn, *args):
    start = time.monotonic()
    try:
        return fn(*args), None, time.monotonic() - start
    except DescriptionError as exc:
        return None, exc, time.monotonic() - start


def _clean(exc: DescriptionError, entry: str) -> None:
    assert str(exc).startswith(f"fuzz.toml: [model] {entry}: "), str(exc)


def test_random_expressions_parse_to_their_value_or_are_refused(tally):
    rng = random.Random(SEED)
    p = _parser()
    allowed = set(p.par_sym) | set(p.q_sym)
    values = {s: sympy.Rational(VALUES[s.name]) for s in allowed}
    problems, slowest, compared = [], 0.0, 0
    for i in range(N_VALUE):
        text, spelling = _tree(rng, rng.randint(1, 4), extreme=False)
        result, exc, seconds = _timed(p.expr, "model", "V", text, allowed)
        slowest = max(slowest, seconds)
        try:
            assert seconds < CASE_LIMIT, f"{seconds:.1f} s"
            if exc is not None:
                _clean(exc, "V")
                tally.add("fuzz_descriptions", "expressions", "clean_error")
                continue
            assert _numbers_are_doubles(result), f"a number that is no double in {result}"
            expected = _independent(spelling)
            if expected is not None and math.isfinite(abs(expected)) and _well_conditioned(spelling, expected):
                with mpmath.workdps(60):
                    got = complex(sympy.N(result.subs(values), 60))
                assert abs(got - expected) <= 1e-12 * max(1.0, abs(expected)), f"{got} != {expected}"
                compared += 1
            tally.add("fuzz_descriptions", "expressions", "correct")
        except (AssertionError, TypeError, ValueError) as e:
            problems.append(f"{text!r}: {e}")
    tally.measurements["fuzz_descriptions_expressions"] = {"cases": N_VALUE, "values_compared": compared,
                                                           "slowest_seconds": round(slowest, 2)}
    assert not problems, f"{len(problems)} of {N_VALUE}:\n" + "\n".join(problems[:20])


def test_extreme_numbers_and_exponents_are_refused_or_finite_as_doubles(tally):
    rng = random.Random(SEED + 1)
    p = _parser()
    allowed = set(p.par_sym) | set(p.q_sym)
    problems, slowest, refused = [], 0.0, 0
    for i in range(N_EXTREME):
        text, _ = _tree(rng, rng.randint(1, 5), extreme=True)
        result, exc, seconds = _timed(p.expr, "model", "V", text, allowed)
        slowest = max(slowest, seconds)
        try:
            assert seconds < CASE_LIMIT, f"{seconds:.1f} s"
            if exc is not None:
                _clean(exc, "V")
                refused += 1
                tally.add("fuzz_descriptions", "extreme expressions", "clean_error")
                continue
            assert _numbers_are_doubles(result), f"a number that is no double in {result}"
            for node in sympy.preorder_traversal(result):
                if isinstance(node, sympy.Pow) and node.exp.is_number:
                    assert abs(node.exp) <= description.MAX_EXPONENT, f"exponent {node.exp}"
            tally.add("fuzz_descriptions", "extreme expressions", "correct")
        except (AssertionError, TypeError, ValueError) as e:
            problems.append(f"{text!r}: {e}")
    tally.measurements["fuzz_descriptions_extreme"] = {"cases": N_EXTREME, "refused": refused,
                                                       "slowest_seconds": round(slowest, 2)}
    assert not problems, f"{len(problems)} of {N_EXTREME}:\n" + "\n".join(problems[:20])


def test_expressions_with_code_are_refused_and_run_nothing(tmp_path, tally):
    rng = random.Random(SEED + 2)
    p = _parser()
    allowed = set(p.par_sym) | set(p.q_sym)
    marker = tmp_path / "MARK"
    problems = []
    cases = [h.format(m=marker) for h in HOSTILE]
    while len(cases) < N_HOSTILE_EXPR:              # the hostile pieces inside random valid expressions
        text, _ = _tree(rng, 2, extreme=False)
        piece = rng.choice(HOSTILE).format(m=marker)
        cases.append(rng.choice([f"{text} + {piece}", f"{piece} * ({text})", f"{text}{piece}", f"({piece})"]))
    for text in cases:
        result, exc, seconds = _timed(p.expr, "model", "V", text, allowed)
        try:
            assert seconds < CASE_LIMIT
            if exc is not None:
                _clean(exc, "V")
            else:                                    # a valid expression around a piece such as "**q": data only
                assert result.free_symbols <= allowed, f"accepted as {result}"
                assert all(type(f).__name__ in FUNCS for f in result.atoms(sympy.Function)), f"accepted as {result}"
            tally.add("fuzz_descriptions", "hostile expressions", "clean_error" if exc else "correct")
        except (AssertionError, TypeError, ValueError) as e:
            problems.append(f"{text!r}: {e}")
    assert not marker.exists(), "a payload ran"
    assert not problems, f"{len(problems)} of {len(cases)}:\n" + "\n".join(problems[:20])


# ---- files ------------------------------------------------------------------------------------------

BASE = ISSUE_MAGLEV
FIELD_VALUES = {
    "name": ['"Maglev"', '"device"', '"int"', '"Reference"', '"time"', '"x y"', '"Mag_lev"', '""', "1", '"A' + "a" * 40 + '"',
             '"Maglev2"', '"printf"', '"main"'],
    "description": ['"plain"', '"x\\"\\"\\"; open({m!r}, \\"w\\"); \\"\\"\\"y"', '"a\\nb"', '"# x"', '"\\\\"',
                    "'''x'''", '"' + "d" * 600 + '"', "1", '"\\u0085"', '"<tag attr=\\"&\\">"'],
    "variable": ['"q"', '"time"', '"while"', '"y1"', '"H"', '"q_d"', '"x_e"', '"_q"', '"Q"', '"x_e_0"', '"q_0"', '"exp"',
                 '"q_star"', '"double"'],
    "unit": ['"m"', '"m\\"); open(1)"', '"kg.m/s"', '""', '"m/s2"', '"a b"', '"\\n"', '"' + "m" * 50 + '"'],
    "text": ['"position"', '"x\\"\\"\\"; open({m!r}, \\"w\\")"', '"\\r"', '"# c"', '"{{}}"', '"%s"', "3"],
    "default": ["0.64042", "1e-320", "1e308", "inf", "nan", "-1", "0", "true", '"1"', "1e-300"],
    "expr": ['"b*q"', '"b*q + 1e-320"', '"((9**1000)**1000)**1000"', '"b*q*(((q+1)**1000)**1000)"', '"1e999999"',
             '"exp(exp(exp(1000)))"', '"b*q/(c - 0.005)"', '"__import__(1)"', '"b*q + k*q**2"', "3", '"q^2*b"',
             '"log(c - q)*b"', '"sqrt(-1)"', '"b*q + 0*x_e"'],
}


def _mutate(rng: random.Random, marker: Path) -> str:
    text = BASE
    for _ in range(rng.randint(1, 3)):
        kind = rng.choice(list(FIELD_VALUES))
        value = rng.choice(FIELD_VALUES[kind]).replace("{m!r}", repr(str(marker)).replace('"', '\\"'))
        if kind == "name":
            text = text.replace('name = "Maglev"', f"name = {value}")
        elif kind == "description":
            text = text.replace('description = "Magnetic levitation system (paper Section 7.2)"', f"description = {value}")
        elif kind == "variable":
            text = text.replace('["q",   "m"', f'[{value},   "m"', 1)
        elif kind == "unit":
            text = text.replace('"Ohm",   "coil resistance"', f'{value},   "coil resistance"')
        elif kind == "text":
            text = text.replace('"mass of the ball"', value)
        elif kind == "default":
            text = text.replace("k   = [0.64042", f"k   = [{value}")
        else:
            key = rng.choice(["V", "M", "Psi"])
            old = {"V": 'V   = "b*q"', "M": 'M   = "m"', "Psi": 'Psi = "(c - q)/k"'}[key]
            text = text.replace(old, f"{key} = {value}")
    return text


def test_mutated_files_are_parsed_or_refused_by_entry_and_generate_no_code(tmp_path, tally):
    rng = random.Random(SEED + 3)
    marker = tmp_path / "MARK"
    problems, accepted = [], 0
    dangerous = {"open", "exec", "eval", "__import__", "compile", "system"}
    for i in range(N_FILES):
        text = _mutate(rng, marker)
        start = time.monotonic()
        try:
            try:
                desc = parse(text, "fuzz.toml")
            except DescriptionError as exc:
                assert str(exc).startswith("fuzz.toml: ["), str(exc)
                assert time.monotonic() - start < 3 * CASE_LIMIT
                tally.add("fuzz_descriptions", "files", "clean_error")
                continue
            source = codegen.module_source(desc)
            tree = ast.parse(source)
            names = {n.id for n in ast.walk(tree) if isinstance(n, ast.Name)}
            assert not names & dangerous, f"code names {names & dangerous}"
            codegen.load_module(desc)
            accepted += 1
            tally.add("fuzz_descriptions", "files", "correct")
        except (AssertionError, Exception) as e:       # noqa: BLE001 - any other exception is a finding
            problems.append(f"case {i}: {type(e).__name__}: {e}\n{text[:300]}")
    assert not marker.exists(), "a payload ran"
    tally.measurements["fuzz_descriptions_files"] = {"cases": N_FILES, "accepted": accepted}
    assert not problems, f"{len(problems)} of {N_FILES}:\n" + "\n".join(problems[:10])


def _variant(rng: random.Random) -> str:
    """A valid maglev-like description with random parameters and a random extra stiffness and mass law."""
    text = BASE.replace("R_m = [0.0,", f"R_m = [{rng.choice(['0.0', '0.1', '2.0'])},")
    text = text.replace('V   = "b*q"', f'V   = "b*q + {rng.choice(["0", "50", "-20", "1e4"])}*q**2/2"')
    text = text.replace('M   = "m"', f'M   = "m*(1 + {rng.choice(["0", "1", "100"])}*q**2)"')
    text = text.replace("k   = [0.64042", f"k   = [{rng.uniform(0.1, 2):.5g}")
    return text + f"\n[controller]\nq_d = [{rng.choice(['0.0025', '0.001', '0.0049', '0.006', '-0.01'])}]\n"


def _finite_numbers(report: plant_check.Report) -> list[str]:
    bad = []
    for v in [report.setpoint, *report.assumptions]:
        for t in v.tests:
            if t.verdict != plant_check.NOT_DECIDED and any(w in t.detail.lower() for w in ("nan", " inf", "-inf")):
                bad.append(f"{v.name}: {t.condition} {t.verdict} with {t.detail}")
    return bad


def test_plant_check_of_random_variants_gives_finite_repeatable_verdicts(tally):
    rng = random.Random(SEED + 4)
    problems = []
    for i in range(N_CHECKS):
        text = _variant(rng)
        try:
            desc = parse(text, "fuzz.toml")
            first = plant_check.check(desc)
            again = plant_check.check(desc)
            assert first.to_dict() == again.to_dict(), "two checks differ"
            assert not _finite_numbers(first), _finite_numbers(first)
            tally.add("fuzz_descriptions", "plant check", "correct")
        except DescriptionError as exc:
            assert str(exc).startswith("fuzz.toml: [")
            tally.add("fuzz_descriptions", "plant check", "clean_error")
        except (AssertionError, Exception) as e:       # noqa: BLE001 - any other exception is a finding
            problems.append(f"case {i}: {type(e).__name__}: {e}")
    assert not problems, "\n".join(problems[:10])
