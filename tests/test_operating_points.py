"""Operating points for n_e > n_m (issue 34, items 1 and 4): a rule fixes the free electrical coordinates, the same
rule gives x_e_d and x_e*(t) with x_e*'(t), the check tests the assumptions there and says which choice it
tested, and a reference along which the rule switches ports is not feasible.

The device is the ball between two electromagnets of examples/ (n_m = 1, n_e = 2). Independent truths, written
here from the paper's model: the force balance m q'' = -b + x_1^2/(2k) - x_2^2/(2k) (the p-row of eq. open-loop
elecmech), the stored energy H_e = (c - q) x_1^2/(2k) + q x_2^2/(2k) minimised by a scan, and x_e*' by central
differences of x_e*(t).
"""
from __future__ import annotations

import math
import re
from pathlib import Path

import numpy as np
import pytest

from components.description import DescriptionError, parse
from components.ph_plant import Jet
from components.plant_check import FAILS, HOLDS, check
from components.references import Sinusoid
from emcosim.cli import main
from emcosim.devices import registry
from emcosim.engine.results import read_csv

ROOT = Path(__file__).resolve().parents[1]
BALL = ROOT / "examples" / "two_magnet_ball" / "two_magnet_ball.toml"
m, b, c, k = 0.0844, 0.8280, 0.01, 0.64042


def _least_energy(tmp_path: Path) -> Path:
    path = tmp_path / "ball_least_energy.toml"
    path.write_text(BALL.read_text().replace('rule = "bias"', 'rule = "least_energy"').replace("x_2 = 0.5 ", "# x_2 "))
    return path


def test_least_energy_holds_the_ball_with_the_upper_coil_alone(tmp_path):
    desc, report, device = registry.load(_least_energy(tmp_path))
    q = 0.005
    x_2 = np.linspace(0.0, 1.0, 10001)                         # every split that holds the ball
    x_1 = np.sqrt(2 * k * b + x_2 ** 2)
    energy = (c - q) * x_1 ** 2 / (2 * k) + q * x_2 ** 2 / (2 * k)
    best = int(np.argmin(energy))
    eta = device.plant().equilibrium([q])
    assert eta[2:] == pytest.approx([x_1[best], x_2[best]], abs=1e-12) and x_2[best] == 0.0
    assert report.x_e_d == pytest.approx([math.sqrt(2 * k * b), 0.0], rel=1e-12)
    assert "least electrical energy" in report.operating_point
    # there hess phi = diag(2 x_e / s) is singular: the check tested that point and says Assumption 2 fails
    assert report.assumption(2).verdict == FAILS and report.designs == []


def test_a_bias_energizes_both_coils_and_proposition_2_applies():
    desc, report, device = registry.load(BALL)
    assert report.operating_point == "bias x_2 = 0.5"
    assert report.x_e_d == pytest.approx([math.sqrt(2 * k * b + 0.25), 0.5], rel=1e-12)
    assert report.assumption(2).verdict == HOLDS and report.designs == ["Proposition2", "Theorem3"]
    eta = device.plant().equilibrium([0.004])
    assert -b + eta[2] ** 2 / (2 * k) - eta[3] ** 2 / (2 * k) == pytest.approx(0.0, abs=1e-14)


@pytest.mark.parametrize("rule", ["bias", "least_energy", "least_input"])
def test_the_rule_gives_x_e_star_and_its_derivative_along_a_reference(rule, tmp_path):
    """Definition 1: the force balance at every time, and x_e*' = d x_e*/dt (central differences)."""
    path = BALL if rule == "bias" else _least_energy(tmp_path)
    if rule == "least_input":
        path.write_text(path.read_text().replace('rule = "least_energy"', 'rule = "least_input"'))
    plant = registry.load(path)[2].plant()
    ref = Sinusoid(offset=0.005, amplitude=0.001, omega=20.0)  # |q''| = 0.4 m/s2 < g: the upper coil stays on

    def state(t: float) -> tuple[np.ndarray, np.ndarray]:
        return plant.feasible_state(Jet(*(np.array([v]) for v in ref.values(t))))

    for t in (0.0, 0.05, 0.13, 0.29):
        q, qd, qdd, _ = ref.values(t)
        eta, x_dot = state(t)
        assert eta[1] == pytest.approx(m * qd, rel=1e-12)
        assert m * qdd == pytest.approx(-b + eta[2] ** 2 / (2 * k) - eta[3] ** 2 / (2 * k), rel=1e-10, abs=1e-12)
        h = 1e-5
        numeric = (state(t + h)[0][2:] - state(t - h)[0][2:]) / (2 * h)
        assert x_dot == pytest.approx(numeric, rel=1e-6, abs=1e-9)


def test_a_reference_that_switches_ports_is_not_feasible(tmp_path):
    """Least energy: the upper coil while m q'' + b > 0, the lower one when the ball must fall faster than g
    (amplitude 0.8 mm at 120 rad/s: |q''| = 11.5 m/s2). x_e*(t) is not differentiable where it switches."""
    desc = registry.load(_least_energy(tmp_path))[0]
    ref = Sinusoid(offset=0.005, amplitude=0.0008, omega=120.0)
    r = check(desc, reference=ref)
    assert r.reference.verdict == FAILS
    test = r.reference.tests[-1]
    assert test.verdict == FAILS and "switches from port(s) x_1 to x_2" in test.detail
    t_a, t_b = (float(v) for v in re.findall(r"t = ([0-9.e+-]+) s(?: and ([0-9.e+-]+) s)?", test.detail)[0])
    # independent: m q'' + b changes sign between the two times
    assert (m * ref.values(t_a)[2] + b) * (m * ref.values(t_b)[2] + b) < 0
    assert r.design_verdicts[3].applies is False and "infeasible" in r.design_verdicts[3].reason
    # the bias never switches: the same reference is feasible (as long as x_1^2 = 2k(m q'' + b) + x_2^2 > 0)
    assert check(registry.load(BALL)[0], reference=ref).reference.verdict == HOLDS


@pytest.mark.parametrize("table, message", [
    ('[operating_point]\nrule = "bias"\n', "a bias gives n_e - n_m = 1 coordinate(s), not 0"),
    ('[operating_point]\nrule = "bias"\nx_3 = 1.0\n', "[operating_point] x_3: not an electrical state"),
    ('[operating_point]\nrule = "cheapest"\n', "'cheapest' is not one of"),
    ('[operating_point]\nrule = "bias"\nx_2 = ["x_2", 2.0]\n', "[operating_point] x_2: "),
    ('[operating_point]\nrule = "least_energy"\nx_2 = 1.0\n', "takes no values"),
])
def test_a_wrong_operating_point_is_refused_naming_the_entry(table, message):
    text = BALL.read_text()
    start, end = text.index("[operating_point]"), text.index("[controller]")
    with pytest.raises(DescriptionError) as err:
        parse(text[:start] + table + "\n" + text[end:], "ball.toml")
    assert message in str(err.value)


def test_plant_fmu_starts_at_the_equilibrium_of_q_d_even_without_a_regulation_design(tmp_path, capsys):
    """docs/devices.md: a plant FMU starts at the equilibrium of [controller] q_d (p = 0). With least energy no
    design applies to the ball; the FMU still starts there (before: feasible_state raised and it fell back to
    eta = 0, outside the domain q > 0, and the build failed)."""
    out = tmp_path / "fmus"
    assert main(["plant", "build", str(_least_energy(tmp_path)), "--out", str(out)]) == 0, capsys.readouterr().err
    import zipfile
    xml = zipfile.ZipFile(out / "TwoMagnetBall.fmu").read("modelDescription.xml").decode()
    start = {n: float(v) for n, v in re.findall(r'name="(\w+)_0"[^>]*>\s*<Real[^>]*start="([^"]+)"', xml)}
    assert start == pytest.approx({"q": 0.005, "p": 0.0, "x_1": math.sqrt(2 * k * b), "x_2": 0.0}, rel=1e-12)


@pytest.mark.slow      # about 4 s: builds a plant
def test_the_command_line_chooses_the_operating_point(tmp_path, capsys):
    out = tmp_path / "r.json"
    assert main(["plant", "check", str(BALL), "--operating-point", "bias:x_2=x_1*0.4", "--json", str(out)]) == 0
    import json
    report = json.loads(out.read_text())
    x_1 = math.sqrt(2 * k * b / (1 - 0.4 ** 2))               # x_1^2 - (0.4 x_1)^2 = 2 k b
    assert report["x_e_d"] == pytest.approx([x_1, 0.4 * x_1], rel=1e-12)
    assert report["operating_point"] == "bias x_2 = 0.4 x_1"
    assert main(["plant", "check", str(BALL), "--operating-point", "least_energy"]) == 0
    text = capsys.readouterr().out
    assert "operating point (n_e > n_m): least electrical energy" in text and "Proposition2 does not apply" in text
    fmus = tmp_path / "fmus"
    assert main(["plant", "build", str(BALL), "--operating-point", "bias:x_2=0.8", "--out", str(fmus)]) == 0
    import zipfile
    fmu = zipfile.ZipFile(fmus / "TwoMagnetBall.fmu")
    assert "x_2 = 0.8" in fmu.read("resources/emcosim_description.toml").decode()
    start = dict(re.findall(r'name="(\w+)_0"[^>]*>\s*<Real[^>]*start="([^"]+)"', fmu.read("modelDescription.xml").decode()))
    assert float(start["x_2"]) == 0.8 and float(start["x_1"]) == pytest.approx(math.sqrt(2 * k * b + 0.64), rel=1e-12)
    assert BALL.read_text().count("x_2 = 0.5") == 1                # the user's file is untouched


@pytest.mark.parametrize("spec", ["bias:x_2", "bias:x_2=abc", "cheapest"])
def test_a_malformed_command_line_operating_point_is_refused_in_one_line(spec, tmp_path, capsys):
    assert main(["plant", "build", str(BALL), "--operating-point", spec, "--out", str(tmp_path / "f")]) == 1
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith("emcosim: error: ") and "[operating_point]" in err[0]
    assert not (tmp_path / "f").exists()


def test_plant_scenario_refuses_a_reference_along_which_the_rule_switches_ports(tmp_path, capsys):
    """A sprung, damped ball (Assumption 3 holds, Theorem 2 applies whatever the point) with the least-energy
    rule: the reference that pulls it down faster than g switches the energized coil, and `plant scenario`
    refuses it, naming the ports and the times (Definition 1 needs x_e*')."""
    path = tmp_path / "sprung.toml"
    text = _least_energy(tmp_path).read_text().replace('V   = "b*q"', 'V   = "b*q + 50*(q - 0.005)**2/2"')
    path.write_text(text.replace('R_m = "0"', 'R_m = "0.5"'))
    args = ["plant", "scenario", str(path), "--controller", "Theorem2", "--out", str(tmp_path / "s"),
            "--reference", "sinusoid:offset=0.005,amplitude=0.0008,omega=120", "--stop-time", "0.1",
            "--step-size", "0.001"]
    assert main(args) == 1
    err = capsys.readouterr().err.strip().splitlines()[-1]
    assert "not feasible with the operating-point rule" in err and "switches from port(s) x_1 to x_2" in err
    assert not (tmp_path / "s").exists()
    gentle = [a if not a.startswith("sinusoid") else "sinusoid:offset=0.005,amplitude=0.0008,omega=20" for a in args]
    assert main(gentle) == 0                                    # |q''| = 0.3 m/s2: the upper coil throughout


def test_an_operating_point_for_n_e_equal_n_m_is_refused_naming_the_users_file(tmp_path, capsys):
    solenoid = ROOT / "examples" / "solenoid" / "solenoid.toml"
    assert main(["plant", "build", str(solenoid), "--operating-point", "least_energy", "--out", str(tmp_path / "f")]) == 1
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith(f"emcosim: error: {solenoid} (--operating-point least_energy): ")
    assert "nothing to choose" in err[0] and not (tmp_path / "f").exists()


def _sprung(tmp_path: Path) -> Path:
    """The ball on a spring (50 N/m about 5 mm) with air damping 0.5 N s/m and the least-energy rule:
    Assumptions 1 and 3 hold whatever the operating point, so Proposition 1 and Theorem 2 apply."""
    path = tmp_path / "sprung.toml"
    text = _least_energy(tmp_path).read_text().replace('V   = "b*q"', 'V   = "b*q + 50*(q - 0.005)**2/2"')
    path.write_text(text.replace('R_m = "0"', 'R_m = "0.5"'))
    return path


@pytest.mark.slow
def test_with_least_energy_the_designs_that_apply_run_on_the_upper_coil_alone(tmp_path, capsys):
    path, fmus = _sprung(tmp_path), tmp_path / "fmus"
    assert main(["plant", "build", str(path), "--out", str(fmus)]) == 0
    assert {p.stem for p in fmus.glob("*_*.fmu")} == {"TwoMagnetBall_Proposition1", "TwoMagnetBall_Theorem2"}
    runs = {"Proposition1": ["--q0", "0.004", "--stop-time", "1.5"],
            "Theorem2": ["--reference", "sinusoid:offset=0.005,amplitude=0.001,omega=5", "--q0", "0.0045",
                         "--stop-time", "2"]}
    for design, extra in runs.items():
        folder = tmp_path / design
        assert main(["plant", "scenario", str(path), "--controller", design, "--out", str(folder), "--fmu-dir",
                     str(fmus), "--step-size", "2.5e-4", *extra]) == 0     # 1e-3: its error estimate 15 %
        out = tmp_path / f"{design}.csv"
        assert main(["run", str(folder), "--output", str(out), "--no-progress"]) == 0
        r = read_csv(out)          # the results' comment lines (the run's error estimate) skipped
        t, q = float(r["time"][-1]), float(r["plant.q"][-1])
        target = 0.005 if design == "Proposition1" else 0.005 + 0.001 * math.sin(5 * t)
        assert abs(q - target) < 0.02 * 0.001, (design, q, target)
        assert np.all(r["plant.x_2"] == 0.0)                          # the lower coil is never energized


TWO_COILS_ABOVE = BALL.read_text().replace('Psi = [["(c - q)/k", "0"], ["0", "q/k"]]',
                                           'Psi = [["(c - q)/k", "0"], ["0", "(c - q)/(2*k)"]]')


@pytest.mark.parametrize("rule", ["least_energy", "least_input"])
def test_least_energy_and_least_input_choose_by_their_costs(rule):
    """Two coils above the ball, the second with twice the inductance (Psi_22 = (c - q)/(2k); both pull up): per
    unit of force they store the same energy (a tie, shared at the least |w|), but the second needs less voltage
    (u_i = R Psi_ii x_i at rest). Both against a scan of the line x_1^2/(2k) + x_2^2/(4k) = b."""
    text = TWO_COILS_ABOVE
    start, end = text.index("[operating_point]"), text.index("[controller]")
    desc = parse(text[:start] + f'[operating_point]\nrule = "{rule}"\n\n' + text[end:], "two_coils.toml")
    r = check(desc, q_d=0.005)
    q, R = 0.005, 2.25
    w2 = np.linspace(0.0, 4 * k * b, 400001)             # x_2^2 from 0 to all of the force on coil 2
    w1 = 2 * k * b - w2 / 2                              # the force balance
    psi = np.array([(c - q) / k, (c - q) / (2 * k)])
    if rule == "least_energy":
        energy = psi[0] * w1 + psi[1] * w2
        assert np.ptp(energy) < 1e-12 * energy[0]        # a tie: every split stores the same energy
        best = int(np.argmin(w1 ** 2 + w2 ** 2))         # shared at the least |w|
        assert 0 < best < len(w2) - 1
    else:
        best = int(np.argmin((R * psi[0]) ** 2 * w1 + (R * psi[1]) ** 2 * w2))
        assert best == len(w2) - 1                        # coil 2 alone
    assert np.array(r.x_e_d) ** 2 == pytest.approx([w1[best], w2[best]], rel=1e-5, abs=1e-9)
