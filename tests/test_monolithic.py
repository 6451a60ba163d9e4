"""Monolithic closed-loop reference: feasibility, tolerance sufficiency, the paper's stated behaviour
(Section 7) as measured quantities, and clean stops."""
import numpy as np
import pytest

from components import metrics
from components.maglev import D_d_from_paper, Maglev
from components.mems import MEMS, R_e_bar_from_rbar_e
from components.monolithic import simulate
from components.proposition1 import Proposition1
from components.proposition2 import Proposition2
from components.references import Constant, Sinusoid
from components.theorem2 import Theorem2
from components.theorem3 import Theorem3

RBAR = R_e_bar_from_rbar_e(100.0)
MAGLEV_REF = Sinusoid(offset=0.0025, amplitude=0.0005, omega=1.0)      # our choice: the paper gives none
MEMS_ETA0 = [15e-6, 0.0, 0.0]                                           # Figs. 1-2


def normalized_deviation(r):
    """max_t |eta_i - eta*_i| / max_t |eta*_i| per state."""
    return np.max(np.abs(r.eta - r.eta_star), axis=0) / np.max(np.abs(r.eta_star), axis=0)


@pytest.mark.parametrize("ctrl,ref,horizon", [
    (Theorem2(MEMS(), RBAR, D_d=-0.4), Sinusoid(), 0.21),                     # one period of q*
    (Theorem3(Maglev(), 0.82, k_c=20.0, D_d=D_d_from_paper(-1.0)), Sinusoid(offset=0.0025, amplitude=0.001, omega=5.0), 2.5),
], ids=["MEMS Theorem 2", "maglev Theorem 3"])
def test_started_on_the_reference_the_loop_stays_on_it(ctrl, ref, horizon):
    r = simulate(ctrl, ctrl.target(ref.jet(0.0)), horizon, ref, rtol=1e-10)
    assert r.success, r.message
    assert np.all(normalized_deviation(r) < 1e-6), normalized_deviation(r)


@pytest.mark.slow      # about 3 s: two runs at rtol 1e-10 and 1e-12
def test_tolerances_are_enough():
    """The default rtol = 1e-10 agrees with rtol = 1e-12 to 1e-8 of the state's range, on the stiffest,
    least damped case (MEMS regulation, D_d = 0, electrical time constant ~1e-10 s)."""
    ctrl = Theorem2(MEMS(), RBAR, D_d=0.0)
    a = simulate(ctrl, MEMS_ETA0, 2e-3, Constant(q_d=3e-5), rtol=1e-10, n_samples=401)
    b = simulate(ctrl, MEMS_ETA0, 2e-3, Constant(q_d=3e-5), rtol=1e-12, n_samples=401, scale=a.scale)
    diff = np.max(np.abs(a.eta - b.eta), axis=0) / np.max(np.abs(b.eta), axis=0)
    assert np.all(diff < 1e-8), diff


def test_mems_regulation_oscillates_without_and_settles_without_overshoot_with_coupled_damping():
    """Section 7.1 / Fig. 1: q_d = 3e-5, rbar_e = 100, eta(0) = (15e-6, 0, 0); Theorem 2 controller."""
    ref = Constant(q_d=3e-5)
    runs = {D: simulate(Theorem2(MEMS(), RBAR, D_d=D), MEMS_ETA0, 0.02, ref, rtol=1e-8) for D in (0.0, -1.0)}
    e0, e1 = (runs[D].q - 3e-5 for D in (0.0, -1.0))
    band = 0.02 * abs(e0[0])
    assert metrics.oscillations(e0, band) >= 20                   # lightly damped: many oscillations
    assert metrics.overshoot(e0) > 0.5
    assert metrics.oscillations(e1, band) == 0
    assert metrics.overshoot(e1) < 1e-6                           # no overshoot
    assert metrics.settling_time(runs[-1.0].t, e1, band) < 2e-3
    assert abs(e1[-1]) < 1e-6 * 3e-5                             # converged
    assert metrics.window_peaks(e0, 4)[-1] < 0.5 * metrics.window_peaks(e0, 4)[0]   # D_d = 0 converges too


def test_mems_regulation_with_proposition_1_converges():
    ctrl = Proposition1(MEMS(), 3e-5, RBAR, D_d=1e-4)             # inside the pH bound |D_d| < 1.48e-4
    r = simulate(ctrl, MEMS_ETA0, 0.02, rtol=1e-8)
    e = r.q - 3e-5
    assert r.success
    assert metrics.window_peaks(e, 4)[-1] < 0.5 * metrics.window_peaks(e, 4)[0]


def test_mems_tracking_oscillates_without_and_not_with_coupled_damping():
    """Section 7.1 / Fig. 2: q* = 0.05 + 0.05 sin 30t, rbar_e = 100, eta(0) = (15e-6, 0, 0)."""
    runs = {D: simulate(Theorem2(MEMS(), RBAR, D_d=D), MEMS_ETA0, 0.05, Sinusoid(), rtol=1e-8) for D in (0.0, -0.4)}
    e0, e1 = (runs[D].q - runs[D].eta_star[:, 0] for D in (0.0, -0.4))
    band = 0.02 * abs(e0[0])
    assert metrics.oscillations(e0, band) >= 20
    assert metrics.oscillations(e1, band) == 0
    assert metrics.settling_time(runs[-0.4].t, e1, band) < 0.02
    assert metrics.window_peaks(e1, 5)[-1] < 0.01 * abs(e1[0])


@pytest.mark.parametrize("D_paper,R_e_bar", [(0.0, 0.82), (0.0, 2.82), (-1.0, 0.82), (-1.0, 2.82)])
def test_maglev_tracking_converges_in_the_four_paper_cases(D_paper, R_e_bar):
    """Section 7.2 / Fig. 3 with the paper's D_d convention; reference and initial offset are our choice."""
    ctrl = Theorem3(Maglev(), R_e_bar, k_c=20.0, D_d=D_d_from_paper(D_paper))
    eta0 = ctrl.target(MAGLEV_REF.jet(0.0)) + np.array([-0.001, 0.0, 0.0])
    r = simulate(ctrl, eta0, 40.0, MAGLEV_REF, rtol=1e-8)
    assert r.success, r.message
    peaks = metrics.window_peaks(r.q - r.eta_star[:, 0], 8)
    shrinking = (np.diff(peaks) < 0) | (peaks[1:] < 1e-6 * peaks[0])   # until the integration noise floor
    assert np.all(shrinking)                                     # the error envelope shrinks ...
    assert peaks[-1] < 0.6 * peaks[0]                            # ... by a clear margin, even in case 1


def test_maglev_regulation_with_proposition_2_converges():
    ctrl = Proposition2(Maglev(), 0.0025, 2.82, k_c=20.0)
    r = simulate(ctrl, ctrl.target() + np.array([-0.001, 0.0, 0.0]), 20.0, rtol=1e-8)
    e = r.q - 0.0025
    assert r.success and abs(e[-1]) < 0.01 * abs(e[0])


def test_leaving_the_domain_stops_cleanly_and_keeps_the_results():
    """A ball thrown up at the magnet: the run stops at q = c with a message, samples so far kept."""
    ctrl = Proposition2(Maglev(), 0.0025, 2.82, k_c=20.0)
    eta0 = ctrl.target() + np.array([0.0, 0.05, 0.0])            # 0.6 m/s upwards, 2.5 mm below the magnet
    r = simulate(ctrl, eta0, 0.01, rtol=1e-8)
    assert not r.success and "q < c" in r.message
    assert 10 < len(r.t) < 2001 and np.all(r.q < Maglev().c)
    with pytest.raises(ValueError, match="q \\+ c0 > 0"):
        simulate(Theorem2(MEMS(), RBAR), [-2e-5, 0, 0], 1e-3, Constant())
    with pytest.raises(ValueError, match="tracking controller"):
        simulate(Theorem2(MEMS(), RBAR), MEMS_ETA0, 1e-3)
