"""The claims report's tests, against independent truths: decay rates of known exponentials, the
linearization's eigenvalues (two independent forms of the closed loop), the algebra of Theorem 1
(iii) on random matrices, and the verdict rules (settled / not decided / does not hold, shortened
runs). Strict JSON, the K_e note of maglev cases 1 and 3, one paragraph per scenario."""
from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from emcosim.engine.ssd import read_scenario
from emcosim.paper import design_facts, report
from emcosim.paper.reproduce import PAPER_CASES, choices, shortened_banner, with_conditions

ROOT = Path(__file__).resolve().parents[1]
SCENARIOS = ROOT / "scenarios"


def synthetic(e: np.ndarray, t: np.ndarray, horizon: float | None = None, name: str = "x") -> report.Run:
    """A maglev-sized run whose position error is e (target q* = 2.5 mm constant)."""
    n = len(t)
    eta_star = np.column_stack([np.full(n, 0.0025), np.zeros(n), np.ones(n)])
    return report.Run(name, "Maglev", name, t, eta_star[:, 0] + e, np.zeros(n), np.ones(n), np.zeros(n), eta_star,
                      horizon=t[-1] if horizon is None else horizon)


T = np.linspace(0.0, 40.0, 40001)


def test_decay_fit_recovers_a_known_rate_and_a_settled_run_converges():
    run = synthetic(-1e-3 * np.exp(-0.3 * T) * np.cos(3.7 * T), T)
    d = report.decay(run)
    assert d.rate == pytest.approx(0.3, rel=0.02) and d.r2 > 0.98 and d.settled
    verdict, _, numbers = report.convergence(run)
    assert verdict == report.HOLDS and numbers["time into 2 % band [s]"] < 15.0


def test_a_slow_decay_is_not_decided_and_its_band_time_is_projected():
    run = synthetic(-1e-3 * np.exp(-0.018 * T) * np.cos(3.7 * T), T)
    verdict, reason, numbers = report.convergence(run)
    assert verdict == report.UNDECIDED and "after the 40 s horizon" in reason
    assert numbers["2 % band projected at [s]"] == pytest.approx(np.log(50) / 0.018, rel=0.05)


def test_a_growing_error_does_not_converge():
    verdict, _, _ = report.convergence(synthetic(1e-5 * np.exp(0.05 * T) * np.cos(3.7 * T), T))
    assert verdict == report.FAILS


def test_shortened_runs_are_not_decided_and_bannered(tmp_path):
    settled = synthetic(-1e-3 * np.exp(-2.0 * T) * np.cos(3.7 * T), T, horizon=80.0, name="cut")
    assert settled.shortened and report.convergence(settled)[0] == report.UNDECIDED
    banner = shortened_banner({"r": settled})
    assert "cut to 40 s of 80 s" in banner
    slow = synthetic(-1e-3 * np.exp(-0.018 * T) * np.cos(3.7 * T), T, name="slow")
    report.write_reports({"cut": settled, "slow": slow}, {}, tmp_path, ["**x.** a choice."], banner=banner)
    for name in ("claims.md", "metrics.md"):
        assert (tmp_path / name).read_text().split("\n")[2].startswith(f"> **{banner}")

    def refuse(constant):
        raise ValueError(f"not strict JSON: {constant}")
    metrics = json.loads((tmp_path / "metrics.json").read_text(), parse_constant=refuse)
    assert metrics["slow"]["settling_time_2pct"] is None and metrics["cut"]["settling_time_2pct"] < 5
    assert json.loads((tmp_path / "claims.json").read_text(), parse_constant=refuse)["banner"] == banner
    assert "| slow | 40 | not reached |" in (tmp_path / "metrics.md").read_text()


def maglev_case(role: str) -> design_facts.Design:
    return design_facts.design(read_scenario(SCENARIOS / PAPER_CASES[role]))


@pytest.mark.parametrize("role", ["maglev_1", "maglev_4", "mems_reg_0", "mems_track_1"])
def test_linearization_is_that_of_the_papers_closed_loop(role):
    """The slowest mode from the plant + controller Jacobian (dominant_mode) equals the one of
    eta' = F_d grad H_d (the paper's closed loop, Jacobian F_d hess H_d) at the target."""
    d = maglev_case(role)
    jet = None if d.reference is None else d.reference.jet(0.0)
    lam = np.linalg.eigvals(d.controller.F_d() @ d.controller.hess_H_d(d.controller.target(jet), jet))
    slow = lam[np.argmax(lam.real)]
    mode = design_facts.dominant_mode(d, n_times=1)
    assert mode["rate"] == pytest.approx(-slow.real, rel=1e-6)
    assert mode["zeta"] == pytest.approx(-slow.real / abs(slow) if slow.imag else 1.0, rel=1e-6)


def test_fitted_decay_rate_of_a_simulated_case_is_the_linearizations(fmu_dir):
    """Maglev case 2 over its 40 s horizon (monolithic closed loop): the envelope's fitted rate is the
    slowest eigenvalue's decay rate within 3 %."""
    from emcosim.paper.reference_check import monolithic
    s = read_scenario(SCENARIOS / PAPER_CASES["maglev_2"])
    r = monolithic(s, n_samples=8001)
    run = report.Run(s.name, "Maglev", "case 2", r.t, r.eta[:, 0], r.eta[:, 1], r.eta[:, 2], r.u[:, 0], r.eta_star,
                     horizon=s.stop_time)
    d = report.decay(run)
    assert d.rate == pytest.approx(design_facts.dominant_mode(maglev_case("maglev_2"))["rate"], rel=0.03)
    assert d.r2 > 0.99 and report.convergence(run)[0] == report.HOLDS


def _imaginary_eigenvalue(F: np.ndarray, gamma: float, eps: float) -> bool:
    n = F.shape[0]
    Q = np.block([[F, gamma * F @ F.T], [-(gamma + eps) * np.eye(n), -F.T]])         # eq. (Eq:N)
    return bool(np.min(np.abs(np.linalg.eigvals(Q).real)) < 1e-8 * np.linalg.norm(Q, 2))


def test_theorem1_iii_is_the_norm_condition():
    """docs/claims.md: Q of eq. (Eq:N) has no imaginary eigenvalue for some eps > 0 iff
    gamma * sup_w |(jwI - F)^-1 F| < 1. Checked on random Hurwitz F: a gamma 5 % below 1/S passes
    with a small eps, one 5 % above fails for every eps."""
    rng = np.random.default_rng(1)
    for _ in range(6):
        A = rng.normal(size=(3, 3))
        F = A - (np.max(np.linalg.eigvals(A).real) + rng.uniform(0.2, 2.0)) * np.eye(3)
        S = design_facts.hinf_norm_F(F)
        assert S >= 1.0 - 1e-9
        assert not _imaginary_eigenvalue(F, 0.95 / S, 1e-6)
        assert all(_imaginary_eigenvalue(F, 1.05 / S, eps) for eps in np.logspace(-8, 3, 23))


@pytest.mark.parametrize("role", ["maglev_1", "maglev_4", "mems_track_0"])
def test_certify_verdict_on_iii_agrees_with_the_norm_condition(role):
    facts = design_facts.theorem1_iii(maglev_case(role))
    assert facts["verdict"] == "fails"
    assert (1 - facts["gamma1/gamma2"]) * facts["S"] >= 1.0


def test_overdamping_claim_decides_on_damping_ratio_and_rate():
    rows = [{"D_d paper": D, "R_e_bar": R, "zeta": z, "rate": r}
            for D, R, z, r in [(0.0, 0.82, 0.5, 1.0), (0.0, 2.82, 1.0, 0.1), (-1.0, 0.82, 0.6, 1.0), (-1.0, 2.82, 1.0, 0.2)]]
    assert report._overdamping_claim(rows).verdict == report.HOLDS
    rows[1]["zeta"] = 0.9
    assert report._overdamping_claim(rows).verdict == report.FAILS


def test_maglev_cases_1_and_3_are_marked_outside_theorem_3():
    for role, outside in [("maglev_1", True), ("maglev_2", False), ("maglev_3", True), ("maglev_4", False)]:
        s = read_scenario(SCENARIOS / PAPER_CASES[role])
        run = with_conditions(synthetic(np.zeros(3), np.arange(3.0), name=role), s)
        assert bool(run.notes) == outside and ("K_e" in run.label) == outside, (role, run.notes)
        if outside:
            assert "K_e = R_e_bar - R_e > 0" in run.notes[0] and "-1.43" in run.notes[0] and "erratum 4" in run.notes[0]


def test_choices_are_one_paragraph_per_scenario_without_dangling_references():
    paragraphs = choices()
    for name in PAPER_CASES.values():
        assert sum(p.startswith(f"**{name}.**") for p in paragraphs) == 1, name
    text = " ".join(paragraphs)
    assert "osp:" not in text and " below)" not in text and "Generated by" not in text    # file-internal references
    from emcosim.paper.scenarios import cases
    for note in {n for c in cases() for n in c.notes}:
        assert text.count(note.rstrip(".")) == 1, f"a choice is missing or repeated: {note}"
