"""Plant descriptions: the issue's file builds as written, and every wrong description is refused by name."""
import numpy as np
import pytest
import sympy

from components.description import DescriptionError, load, parse
from tests.hand_written_plants import BAR_TOML

# the file of issue 25, verbatim
ISSUE_MAGLEV = '''# the paper's magnetic levitation system (Section 7.2)
name = "Maglev"
description = "Magnetic levitation system (paper Section 7.2)"

[variables]      # each: [name, unit, description], in order; q: positions, p: momenta, x_e: electrical states, u: inputs
q   = [["q",   "m",      "position of the ball (magnet at q = c)"]]
p   = [["p",   "kg.m/s", "momentum of the ball"]]
x_e = [["x_e", "Wb",     "flux linkage of the coil"]]
u   = [["u",   "V",      "coil voltage"]]

[parameters]     # name = [default, unit, description]
k   = [0.64042, "H.m",   "inductance constant: inductance is k / (c - q)"]
R_e = [2.25,    "Ohm",   "coil resistance"]
c   = [0.005,   "m",     "position of the magnet (q < c)"]
b   = [0.8280,  "N",     "weight m g of the ball"]
m   = [0.0844,  "kg",    "mass of the ball"]
R_m = [0.0,     "N.s/m", "mechanical damping"]

[model]          # sympy expressions in variable and parameter names; a matrix is a list of rows
M   = "m"
V   = "b*q"
Psi = "(c - q)/k"
R_m = "R_m"
J_e = "0"
R_e = "R_e"
G_e = "1"
domain = ["q < c"]
'''


def test_issue_file_builds_as_written():
    d = parse(ISSUE_MAGLEV, "issue25.toml")
    q, x = d.q_symbols[0], d.x_e_symbols[0]
    k, c, b = (sympy.Symbol(n, real=True) for n in ("k", "c", "b"))
    assert (d.n_m, d.n_e) == (1, 1)
    assert sympy.simplify(d.V - b * q) == 0
    assert sympy.simplify(d.Psi[0, 0] - (c - q) / k) == 0
    assert d.parameters["k"].default == 0.64042 and d.parameters["k"].condition == "any"
    assert sympy.simplify(d.domain_margins[0] - (c - q)) == 0
    # Section 7.2: Gamma = 1/(2k), phi = x_e^3/3
    assert d.gamma_source == "derived"
    assert sympy.simplify(d.Gamma[0, 0] - 1 / (2 * k)) == 0 and sympy.simplify(d.phi - x ** 3 / 3) == 0
    # k has no condition: the sign of Psi is not decided symbolically, so it is sampled (and said)
    assert any(n.startswith("Psi") and "sample points" in n for n in d.notes)


def test_package_files_decide_psi_symbolically():
    for name in ("maglev", "mems"):
        d = load(f"components/plants/{name}.toml")
        assert any(n.startswith("Psi") and "symbolically" in n for n in d.notes), d.notes
    assert load("components/plants/mems.toml").Gamma is None     # Psi = 1/(c1 (q + c0)) is not affine


def test_two_by_two_description():
    d = parse(BAR_TOML, "bar.toml")
    assert (d.n_m, d.n_e) == (2, 2) and d.gamma_source == "derived, scaled"
    k, l_ = sympy.Symbol("k", positive=True), sympy.Symbol("l", positive=True)
    # Section 7.2's Gamma_0 = [[1, 1], [l, -l]] / (2k), rescaled per port so that Gamma^T q_d = x_e_d: at
    # q_d = (0.005, 0.01) both coils carry x_e_d = sqrt(k b) (z-row: (w_1 + w_2)/(2k) = b; theta-row: w_1 = w_2)
    expected = sympy.Matrix([[1, 1], [l_, -l_]]) / (2 * k)
    ratio = sympy.simplify(d.Gamma.multiply_elementwise(expected.applyfunc(lambda e: 1 / e)))
    assert ratio[0, 0] == ratio[1, 0] and ratio[0, 1] == ratio[1, 1] and ratio[0, 0].is_number
    G = np.array(d.Gamma.subs(d.defaults).evalf(), dtype=float)
    assert G.T @ np.array([0.005, 0.01]) == pytest.approx([np.sqrt(0.5 * 1.962)] * 2, rel=1e-5)
    assert any(n.startswith("Psi") and "symbolically" in n for n in d.notes)


def _replace(text, old, new):
    assert old in text, old
    return text.replace(old, new)


BAD = [
    ("TOML syntax", lambda t: t + "\n[model\n", r"\[file\] TOML: syntax"),
    ("unknown symbol", lambda t: _replace(t, 'V   = "b*q"', 'V   = "g*q"'), r"\[model\] V: unknown symbol 'g'"),
    ("python escape", lambda t: _replace(t, 'V   = "b*q"', 'V   = "__import__(\'os\')"'), r"\[model\] V: "),
    ("attribute", lambda t: _replace(t, 'V   = "b*q"', 'V   = "b.real"'), r"\[model\] V: "),
    ("lambda", lambda t: _replace(t, 'V   = "b*q"', 'V   = "lambda: 1"'), r"\[model\] V: "),
    ("power tower", lambda t: _replace(t, 'V   = "b*q"', 'V   = "b*q*9**9**9"'), r"\[model\] V: .*exponent"),
    ("complex number", lambda t: _replace(t, 'V   = "b*q"', 'V   = "b*q + 1j"'), r"\[model\] V: number"),
    ("state in constant", lambda t: _replace(t, 'R_e = "R_e"', 'R_e = "R_e + q"'), r"\[model\] R_e: 'q' may not appear"),
    ("x_e in V", lambda t: _replace(t, 'V   = "b*q"', 'V   = "b*q*x_e"'), r"\[model\] V: 'x_e' may not appear"),
    ("wrong shape", lambda t: _replace(t, 'Psi = "(c - q)/k"', 'Psi = [["1", "0"]]'), r"\[model\] Psi: must be 1 x 1"),
    ("missing key", lambda t: _replace(t, 'G_e = "1"\n', ''), r"\[model\] G_e: missing"),
    ("extra key", lambda t: _replace(t, 'G_e = "1"\n', 'G_e = "1"\nH = "1"\n'), r"\[model\] H: unknown key"),
    ("indefinite R_m", lambda t: _replace(t, 'R_m = "R_m"', 'R_m = "-1"'), r"\[model\] R_m: is not positive semi-definite"),
    ("negative R_e", lambda t: _replace(t, 'R_e = "R_e"', 'R_e = "-R_e"'), r"\[model\] R_e: is not positive semi"),
    ("J_e not skew", lambda t: _replace(t, 'J_e = "0"', 'J_e = "1"'), r"\[model\] J_e: .* not skew"),
    ("G_e singular", lambda t: _replace(t, 'G_e = "1"', 'G_e = "0"'), r"\[model\] G_e: .* singular"),
    ("M not positive", lambda t: _replace(t, 'M   = "m"', 'M   = "-m"'), r"\[model\] M: violates M\(q\) > 0"),
    ("Psi not positive", lambda t: _replace(t, 'Psi = "(c - q)/k"', 'Psi = "(q - c)/k"'), r"\[model\] Psi: violates Psi"),
    ("non-strict domain", lambda t: _replace(t, '["q < c"]', '["q <= c"]'), r"\[model\] domain\[0\]: .*strict"),
    ("domain without q", lambda t: _replace(t, '["q < c"]', '["0 < c"]'), r"\[model\] domain\[0\]: .*positions q"),
    ("duplicate name", lambda t: _replace(t, 'm   = [0.0844', 'q   = [0.0844'), r"\[parameters\] q: name 'q' is used twice"),
    ("function name", lambda t: _replace(t, 'm   = [0.0844', 'exp = [0.0844'), r"\[parameters\] exp: .* function"),
    ("bad condition", lambda t: _replace(t, '"mass of the ball"]', '"mass of the ball", "< 0"]'),
     r"\[parameters\] m: condition '< 0'"),
    ("default violates condition", lambda t: _replace(t, '"mass of the ball"]', '"mass of the ball", ">= 0"]').replace(
        "0.0844", "-0.0844"), r"\[parameters\] m: default: .*violates m >= 0"),
    ("bad variable name", lambda t: _replace(t, '[["x_e", "Wb"', '[["x-e", "Wb"'), r"\[variables\] x_e\[0\]: name 'x-e'"),
    ("momenta count", lambda t: _replace(t, 'p   = [["p",   "kg.m/s", "momentum of the ball"]]',
                                         'p   = [["p", "kg.m/s", "a"], ["p2", "kg.m/s", "b"]]'), r"\[variables\] p: 2 momenta"),
    ("bad device name", lambda t: _replace(t, 'name = "Maglev"', 'name = "Mag lev"'), r"\[top level\] name:"),
    ("Gamma without phi", lambda t: _replace(t, 'domain = ["q < c"]', 'domain = ["q < c"]\nGamma = "1/(2*k)"'),
     r"\[model\] phi: Gamma and phi"),
    ("wrong Gamma", lambda t: _replace(t, 'domain = ["q < c"]', 'domain = ["q < c"]\nGamma = "1/k"\nphi = "x_e^3/3"'),
     r"\[model\] Gamma: grad_q H_e = -Gamma grad phi"),
    ("bad x_e_sign", lambda t: _replace(t, 'domain = ["q < c"]', 'domain = ["q < c"]\nx_e_sign = 2'), r"\[model\] x_e_sign"),
    ("unknown controller key", lambda t: t + '\n[controller]\nK = 1.0\n', r"\[controller\] K: unknown key"),
    ("controller symbol", lambda t: t + '\n[controller]\nR_e_bar = "1/rbar"\n', r"\[controller\] R_e_bar: unknown symbol"),
]


@pytest.mark.parametrize("what,edit,match", BAD, ids=[b[0] for b in BAD])
def test_wrong_descriptions_name_the_entry(what, edit, match):
    with pytest.raises(DescriptionError, match=r"^bad\.toml: " + match):
        parse(edit(ISSUE_MAGLEV), "bad.toml")


def test_given_gamma_phi_are_used():
    text = _replace(ISSUE_MAGLEV, 'domain = ["q < c"]', 'domain = ["q < c"]\nGamma = "1/(6*k)"\nphi = "x_e^3"')
    d = parse(text)
    assert d.gamma_source == "given" and sympy.simplify(d.phi - d.x_e_symbols[0] ** 3) == 0


def test_two_by_two_errors():
    with pytest.raises(DescriptionError, match=r"\[model\] R_m: .* not symmetric"):
        parse(_replace(BAR_TOML, 'R_m = [["d_z", "0"], ["0", "d_theta"]]', 'R_m = [["d_z", "1"], ["0", "d_theta"]]'))
    with pytest.raises(DescriptionError, match=r"\[model\] M: must be a 2 x 2"):
        parse(_replace(BAR_TOML, 'M   = [["m", "0"], ["0", "J"]]', 'M   = "m"'))
    with pytest.raises(DescriptionError, match=r"\[model\] Psi: violates"):
        parse(_replace(BAR_TOML, '"(c - z + l*theta)/k"', '"(z - c)/k"'))


def test_missing_file():
    with pytest.raises(DescriptionError, match=r"nope\.toml: \[file\]"):
        load("nope.toml")
