"""One rule for a design's conditions and early refusal of what cannot be built (issue 42, items 2 and 3).

Coupled coils with n_e > n_m: the ball between two electromagnets of examples/ with a mutual inductance between
its coils (a constant off-diagonal Psi_12) and a spring and a damper added, so that on today's main Proposition 1
and Theorem 2 "apply" (Assumptions 1 and 3 hold at the set-point) although no controller can fix its operating
point: components.operating_point needs diagonal Psi(q) and dPsi/dq_k, and the FMUs could not initialize.
"""
from __future__ import annotations

from pathlib import Path

from components.description import load
from components.plant_check import DESIGNS, HOLDS, check
from emcosim.cli import main

ROOT = Path(__file__).resolve().parents[1]
BALL = ROOT / "examples" / "two_magnet_ball" / "two_magnet_ball.toml"


def coupled_ball(tmp_path: Path) -> Path:
    """The ball with coupled coils (Psi = [[(c - q)/k + 1, 1/4], [1/4, q/k + 1]] > 0), a spring k_s about the
    middle and a damper d (R_m = d > 0), and the default operating point (the [operating_point] table removed)."""
    text = BALL.read_text()
    text = text.replace('Psi = [["(c - q)/k", "0"], ["0", "q/k"]]', 'Psi = [["(c - q)/k + 1", "1/4"], ["1/4", "q/k + 1"]]')
    text = text.replace('[operating_point]\nrule = "bias"\n', "").replace("x_2 = 0.5 ", "# x_2 = 0.5 ")
    text = text.replace('R_c = [2.25,', 'k_s = [400.0, "N/m", "spring", "> 0"]\nd = [2.0, "N.s/m", "damping", "> 0"]\n'
                        'R_c = [2.25,')
    text = text.replace('V   = "b*q"', 'V   = "b*q + k_s*(q - c/2)**2/2"').replace('R_m = "0"', 'R_m = "d"')
    assert "1/4" in text and "k_s" in text and "[operating_point]" not in text
    path = tmp_path / "coupled_ball.toml"
    path.write_text(text)
    return path


def test_coupled_coils_with_more_coils_than_positions_have_no_design(tmp_path):
    report = check(load(coupled_ball(tmp_path)))
    # the assumptions hold at the set-point: only the missing operating point stops the designs
    assert report.assumption(1).verdict == HOLDS and report.assumption(3).verdict == HOLDS
    assert report.designs == []
    assert [d.name for d in report.design_verdicts] == list(DESIGNS)
    for d in report.design_verdicts:
        assert d.reason.startswith("no operating point: n_e = 2 > n_m = 1 with coupled coils (Psi(q) not diagonal)")
    assert "no design can be built" in report.text()


def test_plant_build_builds_no_controller_of_coupled_coils(tmp_path, capsys):
    out = tmp_path / "fmus"
    assert main(["plant", "build", str(coupled_ball(tmp_path)), "--out", str(out)]) == 0
    assert sorted(p.name for p in out.iterdir()) == ["Reference.fmu", "TwoMagnetBall.fmu"]
    said = capsys.readouterr().out
    for design in DESIGNS:
        assert f"not built   TwoMagnetBall_{design}: no operating point" in said


def test_plant_scenario_names_the_missing_operating_point_not_the_reference(tmp_path, capsys):
    path = coupled_ball(tmp_path)
    code = main(["plant", "scenario", str(path), "--controller", "Theorem2", "--out", str(tmp_path / "scenario"),
                 "--fmu-dir", str(tmp_path / "fmus"), "--stop-time", "1", "--reference", "sinusoid:amplitude=0.001"])
    err = capsys.readouterr().err
    assert code != 0 and not (tmp_path / "scenario").exists()
    assert f"{path}: Theorem2 does not apply: no operating point" in err and "feasible" not in err


SOLENOID = ROOT / "examples" / "solenoid" / "solenoid.toml"
SOLENOID_ARGS = (ROOT / "examples" / "solenoid" / "scenario.args").read_text().split()
# W = 1: the Schur complement of eq. (phi12) needs W > ~100 /H (solenoid.toml; tests/test_native_strict.py)
PHI12 = "eq. (phi12): hess H_d(eta_d) > 0"


def _scenario(tmp_path, *gains):
    out = tmp_path / "scenario"
    gain_args = [a for g in gains for a in ("--gain", g)]
    return out, main(["plant", "scenario", str(SOLENOID), *SOLENOID_ARGS, *gain_args, "--out", str(out),
                      "--fmu-dir", str(tmp_path / "fmus")])


def test_a_weight_that_violates_phi12_is_refused_at_plant_scenario_as_the_ph_condition_is(tmp_path, capsys):
    out, code = _scenario(tmp_path, "W=1")
    err = capsys.readouterr().err
    assert code != 0 and not out.exists()
    assert f"Solenoid_Proposition1: the parameters violate Proposition 1's conditions: {PHI12}" in err
    assert err.rstrip().endswith("(strict = 1)")
    # eq. (pHcondition) has the same outcome: refused, nothing written (D_d far past sqrt(4 R_m R_e_bar))
    out, code = _scenario(tmp_path, "D_d=1e6")
    err = capsys.readouterr().err
    assert code != 0 and not out.exists() and "pHcondition" in err


def test_strict_0_writes_it_with_the_words_of_the_fmu_and_the_fmu_runs_anyway(tmp_path, capsys):
    out, code = _scenario(tmp_path, "W=1", "strict=0")
    err = capsys.readouterr().err
    assert code == 0
    warning = [line for line in err.splitlines() if line.startswith("emcosim: warning: ")]
    assert len(warning) == 1 and PHI12 in warning[0] and warning[0].endswith("; running anyway (strict = 0)")
    assert '<ssv:Parameter name="strict"><ssv:Integer value="0"/>' in (out / "controller.ssv").read_text()
    # the scenario written by default carries strict = 1: the FMU refuses what plant scenario refused
    out2, code = _scenario(tmp_path / "default")
    assert code == 0 and '<ssv:Parameter name="strict"><ssv:Integer value="1"/>' in (out2 / "controller.ssv").read_text()


def test_the_fmu_and_plant_scenario_say_it_in_one_wording():
    """The controller FMU's initialization (fmus/controller.py) and plant scenario share
    components.certificates.violation_text: no second wording."""
    text = (ROOT / "fmus" / "controller.py").read_text()
    assert "certificates.violation_text(" in text and "running anyway" not in text
