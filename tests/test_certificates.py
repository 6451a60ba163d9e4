"""Certificates: known answers, verdicts on failing designs, and certified rates against simulation."""
import json

import numpy as np
import pytest

from components import certificates
from components.certificates import FAILS, HOLDS, INCONCLUSIVE, NOT_APPLICABLE, certify, decay_bound_holds
from components.maglev import D_d_from_paper, Maglev
from components.mems import MEMS, R_e_bar_from_rbar_e
from components.monolithic import simulate
from components.proposition1 import Proposition1
from components.references import Constant, Sinusoid
from components.theorem2 import Theorem2
from components.theorem3 import Theorem3
from tests.plants_for_tests import LinearPlant

RBAR = R_e_bar_from_rbar_e(100.0)


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
    assert cert.check("Theorem 1 (i): F_d Hurwitz").verdict == HOLDS


def test_non_hurwitz_F_d_fails_condition_i_and_certifies_nothing():
    ctrl = Theorem3(Maglev(), 0.82, k_c=20.0, D_d=2.0)
    cert = certify(ctrl, Sinusoid(offset=0.0025, amplitude=0.0005, omega=1.0), 1.0, n_times=3, refine=False)
    assert cert.check("Theorem 1 (i): F_d Hurwitz").verdict == FAILS
    assert cert.check("Theorem 1 (i): F_d Hurwitz").numbers["max real part"] > 0
    assert cert.rate is None or cert.rate <= 0


def test_ph_condition_verdicts_and_range():
    bad = certify(Theorem2(MEMS(), RBAR, D_d=-1.0), Constant(q_d=3e-5), refine=False)
    c = bad.check("pH condition (eq. pHcondition)")
    assert c.verdict == FAILS and "not required" in c.note
    assert c.numbers["admissible D_d range"][1] == pytest.approx(np.sqrt(4 * 5.5e-7 * 0.01))
    good = certify(Proposition1(MEMS(), 3e-5, RBAR, D_d=1e-4), refine=False)
    assert good.check("pH condition (eq. pHcondition)").verdict == HOLDS
    assert good.check("Assumption 1").verdict == HOLDS
    assert good.check("Assumption 3").verdict == NOT_APPLICABLE


def test_paper_designs_fail_theorem_1_iii_but_get_a_direct_metric():
    """Theorem 1's (iii) is conservative: with gamma1/gamma2 ~ 1e-12 (MEMS) it fails, while a constant
    metric certifies a local rate near the nominal decay rate."""
    cert = certify(Theorem2(MEMS(), RBAR, D_d=-1.0), Constant(q_d=3e-5), radius=0.1)
    assert cert.check("Theorem 1 (iii): Q of eq. (Eq:N) off the imaginary axis").verdict == FAILS
    lemma = cert.check("Lemma 1: constant contraction metric (eq. crate)")
    assert lemma.verdict == HOLDS
    nominal = -lemma.numbers["nominal spectral abscissa [1/s]"]
    assert 0.5 * nominal < cert.rate <= nominal * (1 + 1e-9)
    text = cert.report()
    assert "Assumption 3" in text and "certified rate" in text
    assert json.loads(cert.to_json())["rate"] == pytest.approx(cert.rate)


@pytest.mark.parametrize("ctrl,ref,eta0,horizon", [
    (Theorem3(Maglev(), 0.82, k_c=20.0, D_d=D_d_from_paper(-1.0)), Sinusoid(offset=0.0025, amplitude=0.0005, omega=1.0),
     np.array([-0.0003, 0.0, 0.0]), 15.0),
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


def test_inconclusive_when_no_constant_metric_covers_a_large_neighbourhood():
    """From eta(0) = (15e-6, 0, 0) the MEMS box spans x_e from 0 to 2 x_e_d: no constant metric found."""
    cert = certify(Theorem2(MEMS(), RBAR, D_d=0.0), Constant(q_d=3e-5), eta0=[15e-6, 0.0, 0.0], refine=False)
    assert cert.check("Lemma 1: constant contraction metric (eq. crate)").verdict == INCONCLUSIVE
    assert cert.rate is None


def test_measured_decay_rate_of_a_known_signal():
    from emcosim.paper.studies import measured_decay_rate
    t = np.linspace(0, 5, 5001)
    e = np.column_stack([np.exp(-0.7 * t) * np.cos(9 * t), 1e-3 * np.exp(-0.7 * t) * np.sin(9 * t), np.exp(-5 * t)])
    assert measured_decay_rate(t, e, np.array([1.0, 1e-3, 1.0])) == pytest.approx(0.7, rel=0.02)


def test_certify_a_scenario_file():
    from emcosim.paper.certify import certify_scenario
    cert = certify_scenario("scenarios/maglev_tracking_D-1_R0.82")
    assert cert.check("Assumption 4").verdict == HOLDS
    assert cert.check("pH condition (eq. pHcondition)").verdict == FAILS          # D_d != 0 with R_m = 0
    assert cert.check("Assumption 1").verdict == NOT_APPLICABLE
    assert 0 < cert.rate < 0.31                                                    # below the nominal 0.304 1/s
    assert cert.neighbourhood["initial state inside"] is False                    # 1 mm off, outside a 10 % tube
    prop2 = certify_scenario("scenarios/maglev_regulation_prop2")
    assert prop2.check("Assumption 2").verdict == HOLDS
    assert prop2.check("pH condition (eq. pHcondition)").verdict == HOLDS


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
