"""Metrics and claims from signals that resolve the loop (issue 35, item 4): the paper's runs sample the closed
loop's fastest oscillation 20 times a period (reproduce.resolving_step), every metric is checked against half
that resolution, and a claim resting on a metric the samples do not resolve is "not decided"."""
from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from emcosim.engine.master import simulate
from emcosim.engine.ssd import read_scenario
from emcosim.paper import report
from emcosim.paper.reproduce import PAPER_CASES, resolving_step, run_from_result

ROOT = Path(__file__).resolve().parents[1]


def _run(name: str, step: float) -> report.Run:
    scenario = read_scenario(ROOT / "scenarios" / name)
    result = simulate(scenario, step_size=step)
    return run_from_result(name, name, scenario, result)


def test_fig2_d_d_0_metrics_are_those_of_a_1e_5_s_run():
    """The issue's finding: mems_tracking_Dd0 recorded at its 1 ms step counted 10 sign changes and a 70.7 %
    overshoot against 106 and about 96 % at 1e-5 s. The run reproduce makes now gives both within 5 % of the
    1e-5 s run's, or says the metric is not resolved."""
    scenario = read_scenario(ROOT / "scenarios" / "mems_tracking_Dd0")
    step = resolving_step(scenario)
    assert step <= 2.5e-5 < scenario.step_size
    ours, fine = report.run_metrics(_run("mems_tracking_Dd0", step)), report.run_metrics(_run("mems_tracking_Dd0", 1e-5))
    for name in ("overshoot", "oscillations"):
        if name in ours.unresolved:
            continue
        assert getattr(ours, name) == pytest.approx(getattr(fine, name), rel=0.05), (name, ours, fine)
    assert ours.resolution == pytest.approx(step)


def test_an_aliased_oscillation_is_not_resolved_and_decides_nothing():
    """A decaying 14000 rad/s oscillation (the MEMS switch's) over 0.1 s: from samples every 2e-5 s (22 a
    period) the check passes; from samples every 1e-4 s (4.5 a period) the sign changes counted from every other
    sample differ, the metric is reported not resolved and the oscillation claim is not decided."""
    def run(h):
        t = np.arange(0.0, 0.1 + h / 2, h)
        e = 1.5e-5 * np.exp(-117 * t) * np.cos(14000 * t)
        zero = np.zeros_like(t)
        return report.Run("x", "MEMS", "x", t, e, zero, zero, zero, np.zeros((len(t), 3)), horizon=0.1)
    fine, coarse = report.run_metrics(run(2e-5)), report.run_metrics(run(1e-4))
    assert fine.unresolved == {} and "oscillations" in coarse.unresolved
    assert report._oscillates(run(2e-5), fine)[0] == report.HOLDS
    verdict, why = report._oscillates(run(1e-4), coarse)
    assert verdict == report.UNDECIDED and "does not resolve" in why


@pytest.mark.slow
def test_verdicts_do_not_change_when_every_runs_resolution_is_doubled(monkeypatch, tmp_path):
    """Every run of `reproduce` at half its step (twice the resolution): the claims that rest on metrics
    (oscillations, overshoot, the maglev's fewer sign changes) keep their verdicts; so does every other."""
    from emcosim.paper import reproduce as reproduce_module

    def verdicts():
        runs, _ = reproduce_module.run_paper_scenarios(PAPER_CASES, jobs=1, decisions=reproduce_module.DECISION_RUNS)
        return {c.text: c.verdict for c in report.claims(runs, {r: r for r in runs})}
    base = verdicts()
    assert len(base) >= 10 and any("oscillat" in text for text in base)
    normal = reproduce_module.resolving_step
    monkeypatch.setattr(reproduce_module, "resolving_step", lambda s: normal(s) / 2)
    doubled = verdicts()
    assert doubled == base
