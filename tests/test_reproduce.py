"""`emcosim reproduce`: every figure and both reports are written, and the report's numbers are those
of the monolithic reference (components.monolithic) of the same scenarios, computed here
independently of the co-simulation (never compared with a stored copy of a report)."""
from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from emcosim.engine.ssd import read_scenario
from emcosim.paper import report
from emcosim.paper.reference_check import monolithic, samples_for
from emcosim.paper.reproduce import DECISION_RUNS, PAPER_CASES, decision_role, run_paper_scenarios

ROOT = Path(__file__).resolve().parents[1]
FIGURES = ["fig1_mems_regulation", "fig2_mems_tracking", "fig3_maglev_tracking", "fig4_maglev_error_norms"]
VERDICTS = (report.HOLDS, report.FAILS, report.UNDECIDED)


def test_reproduce_writes_every_figure_and_both_reports(fmu_dir, tmp_path, capsys):
    """A quick look (every scenario cut to 2 ms) through the command line, two worker processes: the
    reports say the runs were shortened and decide nothing that needs the full horizon."""
    from emcosim.cli import main
    assert main(["reproduce", "--out", str(tmp_path), "--fmu-dir", str(fmu_dir), "--stop-time", "2e-3",
                 "--jobs", "2"]) == 0
    for stem in FIGURES:
        for ext in ("png", "svg"):
            assert (tmp_path / f"{stem}.{ext}").stat().st_size > 10_000, f"{stem}.{ext}"

    def strict(constant):
        raise ValueError(f"not strict JSON: {constant}")
    metrics = json.loads((tmp_path / "metrics.json").read_text(), parse_constant=strict)
    assert set(metrics) == set(PAPER_CASES.values())
    assert all(m["horizon_s"] == 2e-3 for m in metrics.values())
    report_ = json.loads((tmp_path / "claims.json").read_text(), parse_constant=strict)
    assert report_["banner"].startswith("Shortened runs: 10 of 10 scenarios")
    claims = report_["claims"]
    assert len(claims) == 14 and all(c["test"] and c["numbers"] and c["verdict"] in VERDICTS for c in claims)
    simulated = [c for c in claims if "Theorem 1" not in c["text"] and "overdamped" not in c["text"]]
    assert all(c["verdict"] != "holds" or "sign changes" in c["reason"] for c in simulated)   # only what 2 ms shows
    text = (tmp_path / "claims.md").read_text()
    assert "Shortened runs" in text.split("\n")[2] and "Choices the paper does not make" in text
    assert "erratum 7" in text and "| maglev_tracking_D0_R0.82 | 0.002 | 40 |" in text
    k_e = [line for line in (tmp_path / "metrics.md").read_text().splitlines() if "K_e = R_e_bar - R_e > 0" in line]
    assert sorted(line.split(" | ")[0] for line in k_e) == ["| maglev_tracking_D-1_R0.82", "| maglev_tracking_D0_R0.82"]
    err = capsys.readouterr().err
    assert all(f"{name}:" in err for name in PAPER_CASES.values())          # a line for every scenario


def monolithic_run(name: str, role: str, stop_time: float) -> report.Run:
    """The report.Run of a scenario from the monolithic closed loop, sampled at every communication
    point (the co-simulation's grid), so that sampled metrics compare like with like."""
    from emcosim.paper.reproduce import resolving_step

    s = read_scenario(ROOT / "scenarios" / name)
    r = monolithic(s, stop_time=stop_time, n_samples=samples_for(stop_time, resolving_step(s), 10 ** 6))
    plant = "MEMS" if name.startswith("mems") else "Maglev"
    return report.Run(name, plant, role, r.t, r.eta[:, 0], r.eta[:, 1], r.eta[:, 2], r.u[:, 0], r.eta_star,
                      horizon=stop_time)


@pytest.mark.parametrize("roles, stop_time", [(("mems_reg_0", "mems_reg_1"), 0.01),
                                              (("maglev_1", "maglev_4"), 4.0)], ids=["MEMS", "maglev"])
def test_report_numbers_are_those_of_the_monolithic_reference(roles, stop_time, fmu_dir):
    names = {role: PAPER_CASES[role] for role in roles}
    cosim, _ = run_paper_scenarios(names, stop_time=stop_time, fmu_dir=fmu_dir, jobs=1)
    for role, name in names.items():
        a = report.run_metrics(cosim[role])
        b = report.run_metrics(monolithic_run(name, role, stop_time))
        assert a.oscillations == b.oscillations, (name, a, b)
        assert a.overshoot == pytest.approx(b.overshoot, abs=1.0), (name, a, b)      # percentage points
        assert a.ise == pytest.approx(b.ise, rel=0.01), (name, a, b)
        assert a.max_abs_u == pytest.approx(b.max_abs_u, rel=0.01), (name, a, b)
        assert a.initial_error == b.initial_error
        # within the co-simulation's accuracy: 1e-3 of the largest target position (docs/scenarios.md)
        assert abs(a.final_error - b.final_error) < 1e-3 * np.max(np.abs(cosim[role].eta_star[:, 0])), (name, a, b)
        if np.isfinite(b.settling_time_2pct):
            assert a.settling_time_2pct == pytest.approx(b.settling_time_2pct, rel=0.05), (name, a, b)


@pytest.mark.slow      # about 4 s
def test_claims_verdicts_are_those_of_the_monolithic_reference(fmu_dir):
    """The MEMS regulation claims judged on the co-simulation and on the monolithic closed loop, both
    over 10 ms taken as the horizon: D_d = 0 oscillates and decays at the same fitted rate, but
    reaches the 2 % band only after 10 ms (not decided); D_d = -1 settles without overshoot."""
    roles = {role: PAPER_CASES[role] for role in ("mems_reg_0", "mems_reg_1")}
    cosim, _ = run_paper_scenarios(roles, stop_time=0.01, fmu_dir=fmu_dir, jobs=1)
    for run in cosim.values():
        run.horizon = 0.01
    mono = {role: monolithic_run(name, role, 0.01) for role, name in roles.items()}
    cases = {role: role for role in roles}
    ours = report.claims({r: cosim[r] for r in roles}, cases)
    truth = report.claims(mono, cases)
    assert [c.text for c in ours] == [c.text for c in truth] and len(ours) == 3
    assert [c.verdict for c in ours] == [c.verdict for c in truth] == [report.UNDECIDED, report.HOLDS, report.HOLDS]
    assert ours[0].numbers["fitted decay rate [1/s]"] == pytest.approx(truth[0].numbers["fitted decay rate [1/s]"],
                                                                       rel=0.01)


CONVERGENCE_TEST = ("|e| = |q - q*| enters the 2 % band of |e(0)| and stays in it to the end of the horizon (holds); "
                    "envelope of |e| (16 windows) fitted by an exponential: a rate <= 0 with R^2 >= 0.9 does not hold; "
                    "decaying without reaching the band: not decided; horizon ")
DECISION_ROLES = ("mems_reg_0", "mems_reg_1", "maglev_1", "maglev_2", "maglev_3", "maglev_4")


@pytest.fixture(scope="module")
def decided(fmu_dir):
    """The runs claims 1 and 6 need, with their decision runs (DECISION_RUNS), as `reproduce` makes them."""
    names = {role: PAPER_CASES[role] for role in DECISION_ROLES}
    runs, walls = run_paper_scenarios(names, fmu_dir=fmu_dir, jobs=2, decisions=DECISION_RUNS)
    return runs, walls


@pytest.mark.slow      # 8-21 s: in the full set, out of the quick one (issue 33)
def test_decision_runs_decide_claims_1_and_6(decided):
    """Issue 26, item 10: the scenarios' horizons left claim 1 (MEMS regulation, D_d = 0, converges: the band
    at 33 ms against a 20 ms horizon) and claim 6 (all four maglev cases converge: case 1 at about 216 s against
    40 s) not decided. reproduce's decision runs (0.1 s and 400 s, 0.5 s and 6 s of wall time) decide both with
    the same test; the verdict over the scenario's own horizon is given beside it."""
    runs, walls = decided
    assert set(runs) == {*DECISION_ROLES, *(decision_role(r) for r in DECISION_RUNS if r in DECISION_ROLES)}
    assert set(walls) == {*(PAPER_CASES[r] for r in DECISION_ROLES), "mems_regulation_Dd0_to_0.1s",
                          "maglev_tracking_D0_R0.82_to_400s"}
    claims = {c.text: c for c in report.claims({r.name: r for r in runs.values()},
                                               {role: r.name for role, r in runs.items()})}
    one = claims["MEMS regulation, D_d = 0: the states converge to eta_d"]
    assert one.verdict == report.HOLDS, one
    assert one.test.startswith(CONVERGENCE_TEST + "0.1 s (a decision run of mems_regulation_Dd0 to 0.1 s")
    assert one.numbers["time into 2 % band [s]"] == pytest.approx(0.0331, rel=0.01)
    assert one.numbers["verdict over the scenario's 0.02 s horizon"].startswith("not decided")
    six = claims["Maglev: all four cases converge to the desired trajectory"]
    assert six.verdict == report.HOLDS, six
    assert six.test.startswith("each case converges (" + CONVERGENCE_TEST.removesuffix("; horizon ") + "); horizon "
                               "40 s and 400 s (a decision run of maglev_tracking_D0_R0.82 to 400 s at its default step")
    assert six.numbers["case 1 time into 2 % band [s]"] == pytest.approx(216.4, rel=0.01)
    assert six.numbers["case 1 verdict over the scenario's 40 s horizon"].startswith("not decided")
    assert [six.numbers[f"case {i} time into 2 % band [s]"] < 40 for i in (2, 3, 4)] == [True] * 3
    oscillates = claims["MEMS regulation, D_d = 0: the transient oscillates before reaching eta_d"]
    assert "over 0.02 s" in oscillates.test                      # the other claims keep the scenarios' horizons


@pytest.mark.slow      # its fixture runs the decision runs (10 s): in the full set (issue 33)
def test_the_report_lists_the_decision_runs(decided, tmp_path):
    runs, _ = decided
    report.write_reports({r.name: r for r in runs.values()}, {role: r.name for role, r in runs.items()}, tmp_path, [])
    text = (tmp_path / "claims.md").read_text()
    assert "| mems_regulation_Dd0_to_0.1s | 0.1 | 0.02 | 2e-05 |" in text      # resolving the oscillation (issue 35)
    assert "| maglev_tracking_D0_R0.82_to_400s | 400 | 40 | 0.0125 |" in text        # the step since issue 35
    assert "| 1 | MEMS regulation, D_d = 0: the states converge to eta_d (Sec. 7.1, Fig. 1) | holds |" in text
    assert "mems_regulation_Dd0_to_0.1s, maglev_tracking_D0_R0.82_to_400s: decision runs" in text


@pytest.mark.slow
@pytest.mark.parametrize("role, band", [("mems_reg_0", 0.03326), ("maglev_1", 216.44)])
def test_decision_runs_settle_as_the_monolithic_reference(decided, role, band):
    """The decision runs' time into the 2 % band, against the monolithic closed loop over the same horizon
    (about 17 s and 28 s of Radau): 33.26 ms and 216.44 s (33.1 ms before issue 35: the metrics then read the
    band time off the 0.1 ms recording grid; now off a signal that resolves the loop)."""
    runs, _ = decided
    cosim = runs[decision_role(role)]
    truth = monolithic_run(PAPER_CASES[role], role, DECISION_RUNS[role])
    assert report.run_metrics(truth).settling_time_2pct == pytest.approx(band, rel=1e-3)
    assert report.run_metrics(cosim).settling_time_2pct == pytest.approx(band, rel=0.01)


@pytest.mark.parametrize("name", ["maglev_regulation_prop2", "mems_tracking_Dd-0.4"])
def test_a_run_is_the_start_of_its_longer_run(name, fmu_dir):
    """Issue 35: reproduce takes the scenario runs of the roles with a decision run from the start of that run
    instead of running them again (reproduce._heads). That rests on this: a run's rows are the first rows of a
    run of the same scenario to a later stop time, bit for bit but the last row's rounding of t (explicit and
    implicit coupling; their error estimates step aside without changing a row)."""
    from emcosim.engine.master import simulate
    from emcosim.paper.reproduce import _head, _heads

    s = read_scenario(ROOT / "scenarios" / name, fmu_dir=fmu_dir)
    horizon = 25 * s.step_size
    short, long = simulate(s, stop_time=horizon), simulate(s, stop_time=2 * horizon)
    _, head, _ = _head((long.columns, long.rows, 1.0), horizon)
    assert len(head) == len(short.rows) == 26
    assert head[:-1] == short.rows[:-1]
    assert head[-1][0] == pytest.approx(short.rows[-1][0], rel=1e-12)
    assert np.allclose(head[-1][1:], short.rows[-1][1:], rtol=1e-9, atol=0)
    heads = _heads(PAPER_CASES, None, DECISION_RUNS)
    assert heads == {PAPER_CASES[r]: (f"{PAPER_CASES[r]}_to_{t:g}s", read_scenario(ROOT / "scenarios" / PAPER_CASES[r]).stop_time)
                     for r, t in DECISION_RUNS.items()}
    assert _heads(PAPER_CASES, 2e-3, DECISION_RUNS) == {}
