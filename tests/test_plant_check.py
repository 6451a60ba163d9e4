"""components.plant_check: which of Assumptions 1-4 hold for a plant description and which designs apply.

Truths used: the hand-written plants (components.maglev, components.mems, tests.plants_for_tests
TwoAxisLevitator), hand derivations in the comments, and the paper's statements on its two examples
(Section 7: the MEMS is regulated with Proposition 1 / tracked with Theorem 2, the maglev with Proposition 2 /
Theorem 3).
"""
from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np
import pytest

from components import plant_check
from components.description import load, parse
from components.maglev import Maglev
from components.mems import MEMS
from components.plant_check import FAILS, HOLDS, NOT_DECIDED, check
from components.references import Sinusoid
from tests.plants_for_tests import TwoAxisLevitator, VectorSinusoid

PLANTS = Path(__file__).resolve().parents[1] / "components" / "plants"
MAGLEV_TEXT = (PLANTS / "maglev.toml").read_text()

BAR = """
name = "Bar"
description = "a bar held by two electromagnets at distance l either side of its centre"
[variables]
q   = [["z", "m", "height of the centre"], ["theta", "rad", "tilt"]]
p   = [["p_z", "kg.m/s", "momentum"], ["p_theta", "kg.m2/s", "angular momentum"]]
x_e = [["x_1", "Wb", "flux of magnet 1"], ["x_2", "Wb", "flux of magnet 2"]]
u   = [["u_1", "V", "voltage 1"], ["u_2", "V", "voltage 2"]]
[parameters]
k = [0.64, "H.m", "inductance constant", "> 0"]
c = [0.005, "m", "height of the magnets", "> 0"]
l = [0.1, "m", "half distance of the magnets", "> 0"]
b = [0.8, "N", "weight", "> 0"]
m = [0.08, "kg", "mass", "> 0"]
J = [1e-4, "kg.m2", "moment of inertia", "> 0"]
R = [2.0, "Ohm", "coil resistance", "> 0"]
[model]
M   = [["m", "0"], ["0", "J"]]
V   = "b*z"
Psi = [["(c - z - l*theta)/k", "0"], ["0", "(c - z + l*theta)/k"]]
R_m = [["0", "0"], ["0", "0"]]
J_e = [["0", "0"], ["0", "0"]]
R_e = [["R", "0"], ["0", "R"]]
G_e = [["1", "0"], ["0", "1"]]
domain = ["z + l*theta < c", "z - l*theta < c"]
"""

# TwoAxisLevitator of tests/plants_for_tests.py as a description (damped: R_m = diag(0.1, 0.05))
TWO_AXIS = """
name = "TwoAxis"
description = "the tests' two-axis plant"
[variables]
q   = [["q1", "m", ""], ["q2", "m", ""]]
p   = [["p1", "kg.m/s", ""], ["p2", "kg.m/s", ""]]
x_e = [["x1", "Wb", ""], ["x2", "Wb", ""]]
u   = [["u1", "V", ""], ["u2", "V", ""]]
[parameters]
r2 = [0.05, "N.s/m", "damping of q2", ">= 0"]
[model]
M   = [["2.0", "0.3"], ["0.3", "1.0"]]
V   = "(3*q1^2 - 2*q1*q2 + 2*q2^2)/2 + q1 + 0.5*q2"
Psi = [["5 - q1 - 0.3*q2", "0"], ["0", "4 - 0.2*q1 - 0.8*q2"]]
R_m = [["0.1", "0"], ["0", "r2"]]
J_e = [["0", "0.5"], ["-0.5", "0"]]
R_e = [["1", "0"], ["0", "2"]]
G_e = [["1", "0.2"], ["0", "0.5"]]
domain = ["q1 + 0.3*q2 < 5", "0.2*q1 + 0.8*q2 < 4"]
"""


def maglev_variant(R_m: float, spring: bool) -> str:
    """The maglev file with another damping default and, optionally, a spring a q^2/2 in V."""
    text = MAGLEV_TEXT.replace('R_m = [0.0,', f'R_m = [{R_m!r},')
    assert text != MAGLEV_TEXT or R_m == 0.0
    if spring:
        text = text.replace('V   = "b*q"', 'V   = "b*q + a*q^2/2"')
        text = text.replace('[model]', 'a = [50.0, "N/m", "spring"]\n\n[model]', 1)
    return text


def verdicts(report) -> list[str]:
    return [a.verdict for a in report.assumptions]


def test_maglev_file():
    r = check(load(PLANTS / "maglev.toml"))
    a1, a2, a3, a4 = r.assumptions
    assert a1.verdict == FAILS
    r_m = next(t for t in a1.tests if t.condition == "R_m > 0")
    assert r_m.verdict == FAILS and "R_m = [[0.0]]" in r_m.detail
    assert a2.verdict == HOLDS
    # the structural tests are symbolic: Psi = (c - q)/k is affine, grad_q H_e = -x^2/(2k) = -Gamma grad phi
    assert [t.method for t in a2.tests[:2]] == ["symbolic", "symbolic"]
    assert a3.verdict == FAILS and a4.verdict == HOLDS
    assert r.designs == ["Proposition2", "Theorem3"]
    why = {d.name: d.reason for d in r.design_verdicts}
    assert "Assumption 1" in why["Proposition1"] and "R_m > 0" in why["Proposition1"]
    assert "Assumption 3" in why["Theorem2"]


def test_maglev_set_point_matches_the_hand_written_plant():
    q_d = 0.0025
    r = check(load(PLANTS / "maglev.toml"), q_d=q_d)
    assert r.setpoint.verdict == HOLDS
    truth = Maglev().equilibrium(np.array([q_d]))[2]            # x_e_d = sqrt(2 k b)
    assert r.x_e_d[0] == pytest.approx(truth, rel=1e-14)
    hess = next(t for t in r.assumption(2).tests if t.condition.startswith("hess phi"))
    assert hess.verdict == HOLDS and float(hess.detail.split()[-1]) == pytest.approx(2 * truth, rel=1e-5)


@pytest.mark.parametrize("q_d", [0.005, 0.006])
def test_maglev_set_point_at_or_beyond_the_magnet_is_not_assignable(q_d):
    r = check(load(PLANTS / "maglev.toml"), q_d=q_d)
    assert r.setpoint.verdict == FAILS
    assert r.x_e_d is None
    assert "Proposition2" not in r.designs
    assert "not assignable" in {d.name: d.reason for d in r.design_verdicts}["Proposition2"]
    below = check(load(PLANTS / "maglev.toml"), q_d=0.004999)
    assert below.setpoint.verdict == HOLDS and "Proposition2" in below.designs


def test_reference_needing_negative_force_is_infeasible():
    # maglev: -1/2 Psi' x_e*^2 = x_e*^2/(2k) = m q*'' + b needs q*'' > -b/m = -9.81 m/s^2;
    # a w^2 = 1e-3 x 200^2 = 40 m/s^2: infeasible where a w^2 sin(w t) > b/m
    desc = load(PLANTS / "maglev.toml")
    ref = Sinusoid(offset=0.0025, amplitude=1e-3, omega=200.0)
    r = check(desc, reference=ref, times=41)
    assert r.reference.verdict == FAILS
    assert "Theorem3" not in r.designs
    ts = np.linspace(0, 2 * math.pi / 200.0, 41)
    bad = ts[1e-3 * 200.0 ** 2 * np.sin(200.0 * ts) > 0.828 / 0.0844]
    assert f"none at {len(bad)} of 41 times" in r.reference.tests[1].detail
    slow = check(desc, reference=Sinusoid(offset=0.0025, amplitude=1e-3, omega=30.0))   # a w^2 = 0.9 m/s^2
    assert slow.reference.verdict == HOLDS and "Theorem3" in slow.designs


def test_reference_states_match_the_hand_written_plant():
    model = plant_check.Model(load(PLANTS / "maglev.toml"))
    ref = Sinusoid(offset=0.0025, amplitude=1e-3, omega=30.0)
    v, traj = plant_check.check_reference(model, ref, None, 9)
    assert v.verdict == HOLDS and len(traj.eta) == 9
    for t, eta in zip(traj.feasible_times, traj.eta):
        truth = Maglev().feasible_state(ref.jet(t))[0]
        np.testing.assert_allclose(eta, truth, rtol=1e-12)


def test_mems_file():
    q_d = 3e-5
    r = check(load(PLANTS / "mems.toml"), q_d=q_d)
    a1, a2, a3, a4 = r.assumptions
    assert a1.verdict == HOLDS
    c0, c1, a1_, a2_ = 15e-6, 35.6e-9, 0.46, 0.0973
    x_e_d = MEMS().equilibrium(np.array([q_d]))[2]
    assert r.x_e_d[0] == pytest.approx(x_e_d, rel=1e-12)
    by_hand = a1_ + 3 * a2_ * q_d ** 2 + x_e_d ** 2 / (c1 * (q_d + c0) ** 3)
    hess = next(t for t in a1.tests if t.condition.startswith("hess_q H"))
    assert hess.verdict == HOLDS and hess.method.startswith("exact")
    assert float(hess.detail.split()[-1]) == pytest.approx(by_hand, rel=1e-5)
    assert a2.verdict == FAILS and a2.tests[0].condition.startswith("Psi affine") and a2.tests[0].verdict == FAILS
    assert a3.verdict == HOLDS and a4.verdict == FAILS
    assert r.designs == ["Proposition1", "Theorem2"]


def test_mems_default_set_point_comes_from_the_file():
    r = check(load(PLANTS / "mems.toml"))
    assert r.q_d == [3e-5] and r.assumption(1).verdict == HOLDS


def test_mems_set_point_below_zero_force_is_not_assignable():
    # x_e_d^2 = 2 V'(q_d) c1 (q_d + c0)^2 < 0 for -c0 < q_d < 0: the electrostatic force only attracts
    r = check(load(PLANTS / "mems.toml"), q_d=-5e-6)
    assert r.setpoint.verdict == FAILS and "negative" in r.setpoint.tests[1].detail
    assert "Proposition1" not in r.designs


def test_maglev_with_damping_only_still_fails_assumption_1():
    # V = b q and Psi affine: hess_q H = V'' + x_e^2 Psi''/2 = 0 at every eta_d, whatever R_m
    r = check(parse(maglev_variant(0.5, spring=False)))
    a1 = r.assumption(1)
    assert a1.verdict == FAILS
    assert [t.verdict for t in a1.tests] == [HOLDS, FAILS]
    assert r.designs == ["Proposition2", "Theorem3"]


def test_maglev_with_damping_and_a_spring_gets_all_four():
    r = check(parse(maglev_variant(0.5, spring=True)), q_d=0.0025)
    assert verdicts(r) == [HOLDS] * 4
    assert r.designs == ["Proposition1", "Proposition2", "Theorem2", "Theorem3"]
    # x_e_d^2 = 2 k (b + a q_d)
    assert r.x_e_d[0] == pytest.approx(math.sqrt(2 * 0.64042 * (0.8280 + 50.0 * 0.0025)), rel=1e-14)
    # the parameters can be overridden: without damping Proposition 1 and Theorem 2 drop out
    undamped = check(parse(maglev_variant(0.5, spring=True)), q_d=0.0025, parameters={"R_m": 0.0})
    assert undamped.designs == ["Proposition2", "Theorem3"]


def test_bar_with_two_magnets_has_a_non_diagonal_gamma():
    desc = parse(BAR)
    G = np.array(desc.Gamma.subs(desc.defaults).evalf(), dtype=float)
    assert abs(G[1, 0]) > 0 and abs(G[0, 1]) > 0                      # Gamma = [[1, 1], [l, -l]] / (2k)
    r = check(desc, q_d=[0.002, 0.001])
    assert r.setpoint.verdict == HOLDS
    # grad_z H = b - (x1^2 + x2^2)/(2k) = 0, grad_theta H = l (x2^2 - x1^2)/(2k) = 0: x1 = x2 = sqrt(k b)
    np.testing.assert_allclose(r.x_e_d, [math.sqrt(0.64 * 0.8)] * 2, rtol=1e-14)
    assert r.assumption(2).verdict == HOLDS and r.assumption(1).verdict == FAILS
    assert r.designs == ["Proposition2", "Theorem3"]
    tilted = check(desc, q_d=[0.002, 0.04])                           # z + l theta = 0.006 > c
    assert tilted.setpoint.verdict == FAILS


def test_two_axis_plant_reference_matches_its_closed_form():
    desc = parse(TWO_AXIS)
    plant = TwoAxisLevitator(damped=True)
    ref = VectorSinusoid([0.1, 0.2], [0.05, 0.02], [3.0, 5.0], [0.0, 1.0])
    model = plant_check.Model(desc)
    v, traj = plant_check.check_reference(model, ref.jet, 2.0, 11)
    assert v.verdict == HOLDS
    for t, eta in zip(traj.feasible_times, traj.eta):
        np.testing.assert_allclose(eta, plant.feasible_state(ref.jet(t))[0], rtol=1e-12)
    r = check(desc, reference=ref.jet, horizon=2.0)
    # hess V = K > 0 constant, R_m > 0: Assumptions 1 and 3 hold; Psi affine with diagonal dPsi: 2 and 4
    assert verdicts(r) == [HOLDS] * 4
    assert check(desc, reference=ref.jet, horizon=2.0, parameters={"r2": 0.0}).designs == ["Proposition2", "Theorem3"]


def test_non_diagonal_coupling_is_solved_numerically_and_gamma_not_decided():
    # Psi = [[a, q], [q, a]]: grad_q H_e = x1 x2 = -V'(q) = -b has real solutions; dPsi/dq is not diagonal
    text = BAR.replace('q   = [["z", "m", "height of the centre"], ["theta", "rad", "tilt"]]', 'q = [["q", "m", ""]]')
    text = text.replace('p   = [["p_z", "kg.m/s", "momentum"], ["p_theta", "kg.m2/s", "angular momentum"]]',
                        'p = [["p", "kg.m/s", ""]]')
    text = text.split("[model]")[0] + """[model]
M = "m"
V = "b*q"
Psi = [["c", "q"], ["q", "c"]]
R_m = "0"
J_e = [["0", "0"], ["0", "0"]]
R_e = [["R", "0"], ["0", "R"]]
G_e = [["1", "0"], ["0", "1"]]
domain = ["q < c", "q > -c"]
"""
    r = check(parse(text), q_d=0.001)
    assert r.setpoint.verdict == HOLDS and "numerically" in r.setpoint.tests[1].method
    assert r.x_e_d[0] * r.x_e_d[1] == pytest.approx(-0.8, rel=1e-9)
    a2 = r.assumption(2)
    assert a2.tests[0].verdict == HOLDS and a2.verdict == NOT_DECIDED
    assert "Proposition2" not in r.designs


def test_without_set_point_the_checks_that_need_one_are_not_decided():
    text = (PLANTS / "mems.toml").read_text().replace("q_d = [3e-5]\n", "")
    r = check(parse(text))
    assert r.q_d is None and r.setpoint.verdict == NOT_DECIDED
    assert r.assumption(1).verdict == NOT_DECIDED and r.assumption(3).verdict == NOT_DECIDED
    assert "Proposition1" not in r.designs and "needs a set-point" in r.assumption(1).tests[1].method


def test_report_text_and_json():
    r = check(load(PLANTS / "maglev.toml"), reference=Sinusoid(offset=0.0025, amplitude=1e-3, omega=30.0))
    text = r.text()
    n_tests = sum(len(v.tests) for v in [r.setpoint, r.reference, *r.assumptions])
    assert text.count(" -- ") == n_tests
    assert "Theorem3     applies" in text and "Proposition1 does not apply" in text
    data = json.loads(r.to_json())
    assert data["applies"] == r.designs
    assert [a["verdict"] for a in data["assumptions"]] == verdicts(r)
    assert data["reference"]["verdict"] == HOLDS


def test_bad_input_is_named():
    desc = load(PLANTS / "maglev.toml")
    with pytest.raises(ValueError, match="unknown parameter"):
        check(desc, parameters={"nope": 1.0})
    with pytest.raises(ValueError, match="n_m = 1"):
        check(desc, q_d=[0.001, 0.002])
    with pytest.raises(ValueError, match="box"):
        check(desc, q_d=0.001, box={"q": (0.0, 0.001)})


def test_assumption_3_over_a_given_box_can_fail():
    mems = load(PLANTS / "mems.toml")                                   # q_d = 3e-5, x_e_d = 4.46e-11
    held = check(mems, box={"q": (1e-6, 5e-5), "p": (-1e-12, 1e-12), "x_e": (0.0, 1e-10)}, samples=8)
    assert held.assumption(3).verdict == HOLDS and "the given box" in held.box
    box = {"q": (1e-6, 2e-6), "p": (-1e-12, 1e-12), "x_e": (0.0, 1e-13)}
    away = check(mems, box=box, samples=8).assumption(3)               # S must contain eta* = eta_d
    assert away.verdict == NOT_DECIDED and away.tests[1].condition.startswith("S (the given box) contains")
    # a double well V = a2 q^4/4 - a1 q^2/2: hess_q H = -a1 + 3 a2 q^2 + x_e^2/(c1 (q + c0)^3) ~ -0.46 in the box
    well = parse((PLANTS / "mems.toml").read_text().replace('V   = "a1*q^2/2 + a2*q^4/4"', 'V = "a2*q^4/4 - a1*q^2/2"'))
    r = check(well, box=box, samples=8)
    a3 = r.assumption(3)
    assert a3.verdict == FAILS and a3.tests[-1].method.startswith("numerically")
    alpha = float(a3.tests[-1].detail.split("=")[1].split(",")[0])
    assert alpha == pytest.approx(-0.46, rel=1e-3)


def test_R_m_is_decided_symbolically_when_the_conditions_allow_it():
    # R_m = diag(0.1, r2): with r2 "> 0" both minors are positive for every admissible r2 (symbolic); with
    # ">= 0" sympy cannot decide for r2 = 0 and the check says it used the parameter values
    strict = check(parse(TWO_AXIS.replace('"damping of q2", ">= 0"', '"damping of q2", "> 0"')), q_d=[0.1, 0.2])
    loose = check(parse(TWO_AXIS), q_d=[0.1, 0.2])
    assert strict.assumption(1).tests[0].method == "symbolic for every admissible parameter value"
    assert loose.assumption(1).tests[0].method.startswith("not decided symbolically")
    assert strict.assumption(1).verdict == loose.assumption(1).verdict == HOLDS
    # hess_q H = K = [[3, -1], [-1, 2]] constant: for every eta_d
    assert "for every eta_d" in loose.assumption(1).tests[1].method


def test_variable_mass_reference_follows_lagrange():
    # M(q) = m (1 + (q/c)^2): Lagrange's equation d/dt(M q') - M' q'^2 / 2 = M q'' + M' q'^2 / 2 gives
    # x_e*^2 / (2k) = M(q*) q*'' + m q* q*'^2 / c^2 + R_m q*' + b
    text = maglev_variant(0.3, spring=False).replace('M   = "m"', 'M   = "m*(1 + (q/c)^2)"')
    model = plant_check.Model(parse(text))
    ref = Sinusoid(offset=0.0025, amplitude=1e-3, omega=30.0)
    v, traj = plant_check.check_reference(model, ref, None, 7)
    assert v.verdict == HOLDS
    k, c, b, m, R_m = 0.64042, 0.005, 0.8280, 0.0844, 0.3
    for t, eta in zip(traj.feasible_times, traj.eta):
        q, qd, qdd, _ = ref.values(t)
        M = m * (1 + (q / c) ** 2)
        x2 = 2 * k * (M * qdd + m * q * qd ** 2 / c ** 2 + R_m * qd + b)
        np.testing.assert_allclose(eta, [q, M * qd, math.sqrt(x2)], rtol=1e-12)


def test_two_coils_on_one_axis_share_the_force():
    # n_m = 1, n_e = 2, Psi = (c - q)/k I: (x1^2 + x2^2)/(2k) = b; the minimum-norm split x1 = x2 = sqrt(k b)
    # keeps hess phi = diag(2 x1, 2 x2) > 0 (a split with x2 = 0 would not)
    text = BAR.replace('q   = [["z", "m", "height of the centre"], ["theta", "rad", "tilt"]]', 'q = [["z", "m", ""]]')
    text = text.replace('p   = [["p_z", "kg.m/s", "momentum"], ["p_theta", "kg.m2/s", "angular momentum"]]',
                        'p = [["p", "kg.m/s", ""]]')
    text = text.split("[model]")[0] + """[model]
M = "m"
V = "b*z"
Psi = [["(c - z)/k", "0"], ["0", "(c - z)/k"]]
R_m = "0"
J_e = [["0", "0"], ["0", "0"]]
R_e = [["R", "0"], ["0", "R"]]
G_e = [["1", "0"], ["0", "1"]]
domain = ["z < c"]
"""
    r = check(parse(text), q_d=0.002)
    np.testing.assert_allclose(r.x_e_d, [math.sqrt(0.64 * 0.8)] * 2, rtol=1e-12)
    assert "not unique" in r.setpoint.tests[1].method
    assert r.assumption(2).verdict == HOLDS and r.designs == ["Proposition2", "Theorem3"]


class Stacked:
    """One generator per position, as emcosim.devices.scenario.StackedReference: .generators and .jet(t)."""

    def __init__(self, generators):
        self.generators = generators

    def jet(self, t):
        from components.ph_plant import Jet
        return Jet(*np.array([g.values(t) for g in self.generators]).T)


def test_bar_tracks_a_stacked_reference_over_the_longest_period():
    ref = Stacked([Sinusoid(offset=0.002, amplitude=5e-4, omega=10.0), Sinusoid(offset=0.0, amplitude=0.005, omega=5.0)])
    r = check(parse(BAR), q_d=[0.002, 0.0], reference=ref)
    assert f"[0, {2 * math.pi / 5:.6g}] s" in r.reference.name
    assert r.reference.verdict == HOLDS and r.assumption(4).verdict == HOLDS
    assert r.designs == ["Proposition2", "Theorem3"]
    assert [line.split(":")[0] for line in r.not_applicable()] == ["Proposition1", "Theorem2"]
    # a tilt the magnets cannot hold: theta* = 0.06 rad puts z + l theta = 0.008 > c
    tilted = check(parse(BAR), reference=Stacked([Sinusoid(offset=0.002, amplitude=0.0, omega=0.0),
                                                   Sinusoid(offset=0.06, amplitude=0.0, omega=0.0)]))
    assert tilted.reference.verdict == FAILS and "Theorem3" not in tilted.designs


def test_the_device_gets_the_designs_that_apply():
    from components.codegen import device

    desc = load(PLANTS / "maglev.toml")
    r = check(desc)
    assert sorted(device(desc, r.designs).designs) == ["Proposition2", "Theorem3"]
