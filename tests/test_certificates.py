"""Certificates: known answers, verdicts on failing designs, the optimal metric (SDP) against known rates,
the former direct search and simulation, neighbourhoods, and the generated docs."""
import json
import math

import numpy as np
import pytest
from scipy import linalg, optimize

from components import certificates
from components.certificates import FAILS, HOLDS, NOT_APPLICABLE, certify, decay_bound_holds, optimal_metric, verified_rate
from components.maglev import D_d_from_paper, Maglev
from components.mems import MEMS, R_e_bar_from_rbar_e
from components.monolithic import simulate
from components.proposition1 import Proposition1
from components.references import Constant, Sinusoid
from components.theorem2 import Theorem2
from components.theorem3 import Theorem3
from tests.plants_for_tests import LinearPlant

RBAR = R_e_bar_from_rbar_e(100.0)
LEMMA1 = "Lemma 1: constant contraction metric (eq. crate)"
PH = "pH condition (eq. pHcondition)"


def rot(sigma, omega):
    return np.array([[sigma, omega], [-omega, sigma]])


def test_linear_plant_rate_is_the_closed_form_spectral_abscissa():
    """For a linear closed loop eta' = J eta the best constant metric contracts at -max Re eig(J); here
    J = F_d diag(k, 1/m, psi + 1) with block-triangular F_d, so the rate is
    min(R_m / (2m) (underdamped mechanics), R_e_bar (psi + 1))."""
    P = LinearPlant(m=2.0, k=3.0, R_m=0.4, psi=5.0)
    R_bar = 0.5
    ctrl = Theorem2(P, R_bar, D_d=0.7)
    assert 0.4**2 / 4 < 3.0 * 2.0                                  # underdamped: complex pair, Re = -R_m/(2m)
    expected = min(0.4 / (2 * 2.0), R_bar * (5.0 + 1.0))
    cert = certify(ctrl, Constant(q_d=0.0), 0.0, radius=0.5)
    assert cert.rate == pytest.approx(expected, rel=1e-6)
    assert cert.rate_upper == pytest.approx(expected, rel=1e-6)
    assert cert.check("Theorem 1 (i): F_d Hurwitz").verdict == HOLDS


def test_stiff_linear_inclusion_recovers_its_known_optimal_rate_to_1e_6():
    """Two Jacobians J_i = T N_i T^-1 with N_i normal, spectra as stiff as the MEMS loop (-117 +- 14000j
    and -6.2e9; -150 +- 9000j and -3e9, the second rotated so the fast directions differ) and states in
    MEMS units (T = diag(3e-5 m, 1.5e-9 kg m/s, 4.5e-11 C) times a random matrix). The metric
    T^-T T^-1 contracts both at 117 1/s, and no metric beats sample 1's own -max Re eig = 117: the optimum
    is exactly 117 1/s. J_1's own eigen-metric does not even contract J_2."""
    rng = np.random.default_rng(1)
    N1 = linalg.block_diag(rot(-117.0, 14000.0), -6.2e9)
    Q = linalg.qr(rng.standard_normal((3, 3)))[0]
    N2 = Q @ linalg.block_diag(rot(-150.0, 9000.0), -3e9) @ Q.T
    scale = np.array([3e-5, 1.5e-9, 4.5e-11])
    T = np.diag(scale) @ (np.eye(3) + 0.3 * rng.standard_normal((3, 3)))
    J = [T @ N @ np.linalg.inv(T) for N in (N1, N2)]
    sol = optimal_metric(J, scale, J[0])
    assert sol.rate == pytest.approx(117.0, rel=1e-6)
    assert sol.upper == pytest.approx(117.0, rel=1e-9)
    assert verified_rate(sol.metric, J) == pytest.approx(sol.rate, rel=1e-7)      # in SI units
    S = np.diag(scale)                          # the SDP's starting point: J_1's eigen-metric in eta / scale
    start = np.linalg.inv(S @ certificates.modal_basis(np.linalg.solve(S, J[0] @ S)))
    assert verified_rate(start.T @ start, J) < 0                                  # the SDP did the work


def test_mems_linearization_rate_is_recovered_to_1e_6():
    """The MEMS loop (Theorem 2, D_d = 0) at its set-point alone: a linear system whose optimal
    constant-metric rate is -max Re eig J = 117.04 1/s, with states from 1e-5 m to 1e-11 C."""
    ctrl, ref = Theorem2(MEMS(), RBAR, D_d=0.0), Constant(q_d=3e-5)
    jet = ref.jet(0.0)
    eta_d = ctrl.target(jet)
    J = ctrl.F_d() @ ctrl.hess_H_d(eta_d, jet)
    expected = -np.max(np.linalg.eigvals(J).real)
    sol = optimal_metric([J, J + 1e-12 * J], certificates.state_scale(ctrl, eta_d[None]), J)
    assert sol.rate == pytest.approx(expected, rel=1e-6)


def test_no_common_metric_gets_a_verified_dual_certificate():
    """A1, A2 each Hurwitz (double eigenvalue -1) but A1 A2^-1 has negative real eigenvalues, so they
    share no quadratic Lyapunov function (Shorten and Narendra's 2 x 2 criterion): no metric contracts
    both at any rate lam >= 0. The SDP must say so with a dual certificate, not report a rate."""
    A1, A2 = np.array([[-1.0, 20.0], [0.0, -1.0]]), np.array([[-1.0, 0.0], [20.0, -1.0]])
    ev = np.linalg.eigvals(A1 @ np.linalg.inv(A2))
    assert np.any((np.abs(ev.imag) < 1e-12) & (ev.real < 0))                   # the criterion's premise
    sol = optimal_metric([A1, A2], np.ones(2), A1)
    assert sol.rate < 0 and sol.upper < 0
    assert sol.infeasible is not None and sol.infeasible["lam"] <= 0
    assert sol.infeasible["min eig G / trace G"] > sol.infeasible["rounding bound / trace G"]


def test_infeasibility_margin_is_an_independent_check():
    """The certificate check itself: for A with an eigenvalue mu, Z = Re(v v^H) gives G = 2 (Re mu + lam) Z,
    positive exactly when lam > -Re mu."""
    A = np.array([[0.5, 1.0], [-1.0, 0.5]])                                   # eigenvalues 0.5 +- 1j
    w, V = np.linalg.eig(A)
    v = V[:, 0]
    Z = np.real(np.outer(v, v.conj()))
    Z = Z + np.real(np.outer(V[:, 1], V[:, 1].conj()))
    assert certificates.infeasibility_margin([A], [Z], 0.0)[0] > 0          # no lam >= 0 possible
    assert certificates.infeasibility_margin([A], [Z], -0.6)[0] < 0         # lam = -0.6 < -0.5 is possible


def test_non_hurwitz_F_d_fails_condition_i_and_certifies_nothing():
    ctrl = Theorem3(Maglev(), 0.82, k_c=20.0, D_d=2.0)
    cert = certify(ctrl, Sinusoid(offset=0.0025, amplitude=0.0005, omega=1.0), 1.0, n_times=3)
    assert cert.check("Theorem 1 (i): F_d Hurwitz").verdict == FAILS
    assert cert.check("Theorem 1 (i): F_d Hurwitz").numbers["max real part"] > 0
    assert cert.rate is None and cert.rate_upper <= 0
    assert cert.check(LEMMA1).verdict == FAILS


def test_ph_condition_verdicts_and_range():
    bad = certify(Theorem2(MEMS(), RBAR, D_d=-1.0), Constant(q_d=3e-5))
    c = bad.check(PH)
    assert c.verdict == FAILS and "not required" in c.note
    assert c.numbers["admissible D_d range"][1] == pytest.approx(np.sqrt(4 * 5.5e-7 * 0.01))
    assert "admissible D_d range = [-0.000148324 0.000148324]" in bad.report()    # digits enough to compare
    good = certify(Proposition1(MEMS(), 3e-5, RBAR, D_d=1e-4))
    assert good.check(PH).verdict == HOLDS
    assert good.check("Assumption 1").verdict == HOLDS
    assert good.check("Assumption 3").verdict == NOT_APPLICABLE


def test_prop1_scenario_exercises_coupled_damping_inside_the_ph_bound():
    """scenarios/mems_regulation_prop1: D_d != 0 and |D_d| < sqrt(4 R_m R_e_bar) (eq. pHcondition, strict)."""
    from emcosim.paper.certify import certify_scenario
    cert = certify_scenario("scenarios/mems_regulation_prop1", radius=0.002)
    c = cert.check(PH)
    D, (lo, hi) = c.numbers["D_d"], c.numbers["admissible D_d range"]
    assert D != 0 and lo < D < hi and hi == pytest.approx(math.sqrt(4 * 5.5e-7 * (1 / 100.0)))
    assert c.verdict == HOLDS and c.note == "required"
    assert cert.rate > 0                                     # a small box around eta_d contracts


def test_paper_designs_fail_theorem_1_iii_but_get_the_optimal_metric():
    """Theorem 1's (iii) is conservative: with gamma1/gamma2 ~ 1e-12 (MEMS) it fails, while the best
    constant metric certifies a local rate, bounded by the samples' own eigenvalues."""
    cert = certify(Theorem2(MEMS(), RBAR, D_d=-1.0), Constant(q_d=3e-5), radius=0.1)
    assert cert.check("Theorem 1 (iii): Q of eq. (Eq:N) off the imaginary axis").verdict == FAILS
    lemma = cert.check(LEMMA1)
    assert lemma.verdict == HOLDS
    nominal = -lemma.numbers["nominal spectral abscissa [1/s]"]
    assert 0.5 * nominal < cert.rate <= cert.rate_upper * (1 + 1e-9) <= nominal * (1 + 1e-9)
    assert cert.rate == pytest.approx(cert.rate_upper, rel=1e-6)
    text = cert.report()
    assert "Assumption 3" in text and "certified rate" in text and "CLARABEL" in text
    assert json.loads(cert.to_json())["rate"] == pytest.approx(cert.rate)


@pytest.mark.parametrize("ctrl,ref,eta0,horizon", [
    pytest.param(Theorem3(Maglev(), 0.82, k_c=20.0, D_d=D_d_from_paper(-1.0)),      # slow: a 15 s horizon
                 Sinusoid(offset=0.0025, amplitude=0.0005, omega=1.0), np.array([-0.0003, 0.0, 0.0]), 15.0,
                 marks=pytest.mark.slow),
    (Theorem3(Maglev(), 2.82, k_c=20.0, D_d=D_d_from_paper(-1.0)), Sinusoid(offset=0.0025, amplitude=0.0005, omega=1.0),
     np.array([-0.0003, 0.0, 0.0]), 10.0),
    (Theorem2(MEMS(), RBAR, D_d=-1.0), Constant(q_d=3e-5), np.array([-1.5e-6, 0.0, 0.0]), 2e-3),
    (Theorem2(MEMS(), RBAR, D_d=0.0), Constant(q_d=3e-5), np.array([-3e-8, 0.0, 0.0]), 5e-3),
], ids=["maglev case 3", "maglev case 4", "MEMS D_d=-1", "MEMS D_d=0"])
def test_certified_rate_never_exceeds_the_simulated_decay(ctrl, ref, eta0, horizon):
    """Simulate a run, certify over a box that contains all of it, and check the certificate's promise
    |e(t)|_Omega <= exp(-rate t) |e(0)|_Omega on the simulated error."""
    start = ctrl.target(ref.jet(0.0)) + eta0
    r = simulate(ctrl, start, horizon, ref, rtol=1e-10)
    e = r.eta - r.eta_star
    nb_half = 1.05 * np.max(np.abs(e), axis=0)
    scale = certificates.state_scale(ctrl, r.eta_star)
    cert = certify(ctrl, ref, horizon if ref.params.get("omega") else 0.0,
                   radius=float(np.max(nb_half / scale)), n_times=11)
    assert cert.rate is not None and cert.rate > 0
    assert decay_bound_holds(np.array(cert.metric), cert.rate, r.t, e)
    # and the certified rate is below the error's measured decay over the run
    norms = np.sqrt(np.einsum("ti,ij,tj->t", e, np.array(cert.metric), e))
    measured = -np.log(norms[-1] / norms[0]) / (r.t[-1] - r.t[0])
    assert cert.rate <= measured


def test_no_constant_metric_over_a_large_neighbourhood_is_proven():
    """From eta(0) = (15e-6, 0, 0) the MEMS box spans x_e from 0 to 2 x_e_d: no constant metric exists,
    and the certificate says so with verified dual multipliers (not "none found")."""
    cert = certify(Theorem2(MEMS(), RBAR, D_d=0.0), Constant(q_d=3e-5), eta0=[15e-6, 0.0, 0.0])
    lemma = cert.check(LEMMA1)
    assert lemma.verdict == FAILS and "no constant metric exists" in lemma.note
    assert cert.rate is None and cert.rate_upper <= 0
    assert "no constant metric exists over these samples" in cert.report()


def test_radius_must_be_finite_and_positive():
    ctrl = Theorem2(MEMS(), RBAR, D_d=-1.0)
    for bad in (0.0, -1.0, float("nan"), float("inf"), "x"):
        with pytest.raises(ValueError, match="radius"):
            certify(ctrl, Constant(q_d=3e-5), radius=bad)


def test_periodic_reference_tube_covers_a_full_period():
    """The MEMS tracking reference has period 2 pi / 30 = 209 ms; its run lasts 50 ms. The tube must cover
    the whole period (so every t >= 0), and its targets reach the reference's extremes q* = 0 and 0.1 m."""
    from emcosim.engine.ssd import read_scenario
    from emcosim.paper.certify import design_from_scenario
    d = design_from_scenario(read_scenario("scenarios/mems_tracking_Dd0"))
    assert d.horizon == pytest.approx(0.05)
    nb = certificates.neighbourhood(d.controller, d.reference, d.horizon, 0.1)
    period = 2 * np.pi / 30.0
    step = period / len(nb.times)
    assert nb.times[0] == 0.0 and nb.times[-1] == pytest.approx(period - step) and np.all(np.diff(nb.times) > 0)
    q = [d.controller.target(j)[0] for _, j in nb.samples]
    assert max(q) >= 0.05 + 0.05 * np.cos(np.pi / len(nb.times)) and min(q) <= 0.05 - 0.05 * np.cos(np.pi / len(nb.times))
    assert "one period" in nb.description


def test_measured_decay_rate_of_a_known_signal():
    from emcosim.paper.studies import measured_decay_rate
    t = np.linspace(0, 5, 5001)
    e = np.column_stack([np.exp(-0.7 * t) * np.cos(9 * t), 1e-3 * np.exp(-0.7 * t) * np.sin(9 * t), np.exp(-5 * t)])
    assert measured_decay_rate(t, e, np.array([1.0, 1e-3, 1.0])) == pytest.approx(0.7, rel=0.02)


def test_best_coupled_damping():
    """MEMS: coupled damping adds velocity feedback to the mechanics (eq. closedloop), so the best decay a
    second-order mode can reach is critical damping at its natural frequency: the modulus of the D_d = 0
    mechanical eigenvalue pair. Maglev: a local maximum, above every point of the scan."""
    from emcosim.paper.studies import SEARCH_INTERVALS, best_coupled_damping, linearized_rate
    D, rate = best_coupled_damping("mems")
    ctrl, ref = Theorem2(MEMS(), RBAR, D_d=0.0), Constant(q_d=3e-5)
    ev = np.linalg.eigvals(ctrl.F_d() @ ctrl.hess_H_d(ctrl.target(ref.jet(0)), ref.jet(0)))
    assert rate == pytest.approx(np.abs(ev[np.abs(ev.imag) > 0][0]), rel=1e-4)
    for plant in ("mems", "maglev"):
        D, rate = best_coupled_damping(plant)
        assert rate == pytest.approx(linearized_rate(plant, D))
        for delta in (1e-3, 1e-2):
            assert rate >= linearized_rate(plant, D * (1 + delta)) and rate >= linearized_rate(plant, D * (1 - delta))
        assert rate >= max(linearized_rate(plant, x) for x in np.linspace(*SEARCH_INTERVALS[plant], 200))


@pytest.mark.slow      # 4-6 s: in the full set, out of the quick one (issue 33)
def test_certify_a_scenario_file():
    from emcosim.paper.certify import certify_scenario
    cert = certify_scenario("scenarios/maglev_tracking_D-1_R0.82")
    assert cert.check("Assumption 4").verdict == HOLDS
    assert cert.check(PH).verdict == FAILS                                   # D_d != 0 with R_m = 0
    assert cert.check("Assumption 1").verdict == NOT_APPLICABLE
    assert 0 < cert.rate < 0.31                                              # below the nominal 0.304 1/s
    assert cert.neighbourhood["initial state inside"] is False              # 1 mm off, outside a 10 % tube
    inside = certify_scenario("scenarios/maglev_tracking_D-1_R0.82", include_start=True)
    assert inside.neighbourhood["initial state inside"] is True
    prop2 = certify_scenario("scenarios/maglev_regulation_prop2")
    assert prop2.check("Assumption 2").verdict == HOLDS
    assert prop2.check(PH).verdict == HOLDS


def test_certify_json_never_writes_through_a_symlink(tmp_path, capsys):
    """Issue 26's rule for every output: `certify --json` given a link is refused before the certificate
    is computed (it wrote through the link into the target before), the target untouched; a missing
    folder is refused too, and a good destination is written beside and renamed into place."""
    from emcosim.cli import main
    victim = tmp_path / "victim.conf"
    victim.write_text("setting = 1\n")
    link = tmp_path / "cert.json"
    link.symlink_to(victim)
    assert main(["certify", "maglev_regulation_prop2", "--json", str(link)]) == 1
    captured = capsys.readouterr()
    assert "symbolic link" in captured.err and "Proposition 2" not in captured.out
    assert victim.read_text() == "setting = 1\n" and link.is_symlink()
    assert main(["certify", "maglev_regulation_prop2", "--json", str(tmp_path / "none" / "c.json")]) == 1
    assert "does not exist" in capsys.readouterr().err
    good = tmp_path / "good.json"
    assert main(["certify", "maglev_regulation_prop2", "--json", str(good)]) == 0
    assert json.loads(good.read_text())["checks"]
    assert sorted(p.name for p in tmp_path.iterdir()) == ["cert.json", "good.json", "victim.conf"]


def test_certify_command(tmp_path, capsys):
    from emcosim.cli import main
    out = tmp_path / "cert.json"
    assert main(["certify", "maglev_regulation_prop2", "--json", str(out)]) == 0
    text = capsys.readouterr().out
    assert "Proposition 2" in text and "maglev_regulation_prop2" in text and "[         holds] Assumption 2" in text
    data = json.loads(out.read_text())
    assert {c["name"]: c["verdict"] for c in data["checks"]}["pH condition (eq. pHcondition)"] == "holds"
    assert main(["certify", "no_such_scenario"]) == 1
    assert "scenario not found" in capsys.readouterr().err
    for bad in ("-1", "0", "nan", "inf"):
        with pytest.raises(SystemExit) as exc:
            main(["certify", "maglev_regulation_prop2", "--radius", bad])
        assert exc.value.code == 2
        assert "--radius" in capsys.readouterr().err


# ---- every paper scenario: the SDP against the former direct search, and the generated doc -------

def direct_search(jacobians, scale, nominal, maxiter=150):
    """The metric search certify used before the SDP, kept here as an independent baseline: candidates
    from the nominal Jacobian (identity, eigen-metric, shifted Lyapunov metrics) in coordinates
    eta / scale, then Nelder-Mead on a log-Cholesky factor. Returns the verified rate."""
    S, Si = np.diag(scale), np.diag(1.0 / scale)
    Js = [Si @ J @ S for J in jacobians]
    J0 = Si @ nominal @ S
    n = J0.shape[0]
    _, V = np.linalg.eig(J0)
    Vi = np.linalg.inv(V)
    candidates = [np.eye(n), np.real(Vi.conj().T @ Vi)]
    alpha = -np.max(np.linalg.eigvals(J0).real)
    for f in (0.5, 0.9, 0.99) if alpha > 0 else ():
        candidates.append(linalg.solve_continuous_lyapunov((J0 + f * alpha * np.eye(n)).T, -np.eye(n)))
    scored = [(verified_rate(P, Js), P) for P in (0.5 * (C + C.T) for C in candidates)
              if np.all(np.isfinite(P)) and np.min(np.linalg.eigvalsh(P)) > 0]
    rate, P = max(scored, key=lambda s: s[0])
    idx = np.tril_indices(n)
    L0 = np.linalg.cholesky(P / np.max(np.linalg.eigvalsh(P)))
    L0[np.diag_indices(n)] = np.log(np.diag(L0))

    def unpack(x):
        L = np.zeros((n, n))
        L[idx] = x
        L[np.diag_indices(n)] = np.exp(np.diag(L))
        return L @ L.T

    res = optimize.minimize(lambda x: -verified_rate(unpack(x), Js), L0[idx], method="Nelder-Mead",
                            options={"maxiter": maxiter})
    return max(rate, verified_rate(unpack(res.x), Js))


@pytest.fixture(scope="module")
def paper_certificates():
    from emcosim.paper.certify import ROOT, certify_scenario, scenario_names
    return {n: certify_scenario(ROOT / "scenarios" / n) for n in scenario_names()}


@pytest.mark.slow                        # about 45 s
def test_sdp_rate_is_at_least_the_direct_search_on_every_paper_scenario(paper_certificates):
    """Over the same samples: where the SDP certifies a rate it is >= the search's (to rounding); where
    the SDP says no constant metric exists, its proof (a dual certificate or a sample's eigenvalue) bounds
    every rate, the search's included, by a value <= 0."""
    from emcosim.engine.ssd import read_scenario
    from emcosim.paper.certify import design_from_scenario
    assert len(paper_certificates) == 10
    for name, cert in paper_certificates.items():
        d = design_from_scenario(read_scenario(f"scenarios/{name}"))
        nb = certificates.neighbourhood(d.controller, d.reference, d.horizon, 0.1)
        jac = certificates.closed_loop_jacobians(d.controller, nb)
        searched = direct_search(jac, nb.scale, d.controller.F_d() @ d.controller.hess_H_d(*nb.samples[0]))
        lemma = cert.check(LEMMA1)
        sdp = lemma.numbers["optimal rate lam over the samples [1/s] (sigma = 2 lam)"]
        if lemma.verdict == FAILS:                 # proven: no constant metric with a positive rate
            assert searched <= cert.rate_upper <= 0, name
        else:
            assert sdp >= searched - 1e-9 * abs(searched), name
            assert sdp > 0, name


@pytest.mark.slow      # 8-21 s: in the full set, out of the quick one (issue 33)
def test_docs_list_certify_output_for_every_scenario(paper_certificates):
    """docs/certificates.md holds `emcosim certify NAME` for every scenario, as
    `python -m emcosim.paper.certify` writes it (verdicts and numbers to 1e-4; solver-path lines aside)."""
    from emcosim.paper import certify as module
    new = module.section({n: c.report() for n, c in paper_certificates.items()})
    assert module.same_section(module.current_section(), new) == []
    for name in paper_certificates:
        assert f"$ emcosim certify {name}" in module.current_section()
    assert module.same_section(new, new.replace("holds", "fails", 1)) != []     # the check can fail


def test_same_section_takes_residuals_at_rounding_as_equal_and_nothing_else():
    """Residuals both below 1e-13 (zero to rounding) compare equal on a residual line; a residual of 1e-10 that
    moved by 1e-3 of itself, or a number on another line at rounding level, does not."""
    from emcosim.paper.certify import BEGIN, END, same_section

    def doc(line: str) -> str:
        return f"{BEGIN}\n{line}\n{END}"
    assert same_section(doc("max rel. residual = 2.22775e-16"), doc("max rel. residual = 2.22545e-16")) == []
    assert same_section(doc("max rel. residual = 1.000e-10"), doc("max rel. residual = 1.001e-10")) != []
    assert same_section(doc("min eig K_e = 2.22775e-16"), doc("min eig K_e = 2.22545e-16")) != []
