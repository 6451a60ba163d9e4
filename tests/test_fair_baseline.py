"""The benchmark's fair monolithic path (components.monolithic.record: the plant states and u at the
communication points, nothing else) against the reference path (simulate: 2001 samples with u and eta*):
at the same solver, rtol and scale both are one integration, so the fast path cannot drift from it."""
import numpy as np
import pytest

from components.maglev import D_d_from_paper, Maglev
from components.mems import MEMS, R_e_bar_from_rbar_e
from components.monolithic import diagnose, record, simulate
from components.references import Sinusoid
from components.theorem2 import Theorem2
from components.theorem3 import Theorem3

STRIDE = 40                     # the grid: every 40th of simulate's 2001 samples (a step of t_end / 50)
RTOL = 1e-6                     # loose enough that another solver, rtol or scale moves the states by far more


def _maglev_case():
    ctrl = Theorem3(Maglev(), 0.82, k_c=20.0, D_d=D_d_from_paper(-1.0))
    ref = Sinusoid(offset=0.0025, amplitude=0.0005, omega=1.0)
    return ctrl, ref, ctrl.target(ref.jet(0.0)) + np.array([-0.001, 0.0, 0.0]), 4.0


def _mems_case():                # stiff: the charging transient of mems_tracking_Dd-0.4 over its first 2 ms
    return Theorem2(MEMS(), R_e_bar_from_rbar_e(100.0), D_d=-0.4), Sinusoid(), np.array([15e-6, 0.0, 0.0]), 2e-3


@pytest.mark.parametrize("case", [_mems_case, _maglev_case], ids=["MEMS Theorem 2", "maglev Theorem 3"])
def test_the_fair_recording_is_the_reference_integration_at_the_grid_points(case):
    ctrl, ref, eta0, t_end = case()
    full = simulate(ctrl, eta0, t_end, ref, n_samples=2001, rtol=RTOL)
    grid = np.linspace(0.0, t_end, 2000 // STRIDE + 1)
    rec = record(ctrl, eta0, grid, ref, rtol=RTOL, scale=full.scale, method="Radau")
    assert full.success and rec.success, (full.message, rec.message)
    assert rec.eta.shape == full.eta[::STRIDE].shape
    np.testing.assert_allclose(rec.t, full.t[::STRIDE], rtol=0, atol=1e-14 * t_end)

    def rel(a, b):
        return np.max(np.abs(a - b), axis=0) / np.max(np.abs(b), axis=0)
    assert np.all(rel(rec.eta, full.eta[::STRIDE]) < 1e-10), rel(rec.eta, full.eta[::STRIDE])
    assert np.all(rel(rec.u, full.u[::STRIDE]) < 1e-10), rel(rec.u, full.u[::STRIDE])
    assert np.all(rel(diagnose(rec, ctrl, ref).eta_star, full.eta_star[::STRIDE]) < 1e-12)
