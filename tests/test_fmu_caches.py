"""What the FMUs compute once and keep (a controller's u, a plant's H and output derivatives, the reference's
derivatives, the framework's checked derivative requests) is never served stale: after every setter, a
doStep, a restored FMU state, and before initialization after a parameter changed, the FMU answers what
components/ computes for the new situation (the expected values come from components/, never from the FMU)."""
from __future__ import annotations

import numpy as np
import pytest

from components import catalog, references
from tests.helpers import Slave

# maglev tracking inputs near the paper's operating point: q, p, x_e and the reference jet
X1 = {"q": 0.0022, "p": 4.1e-05, "x_e": 1.03, "q_star": 0.00222, "q_star_dot": 4.2e-4, "q_star_ddot": 2.8e-4,
      "q_star_dddot": -4.2e-4}
X2 = {"q": 0.0021, "p": -3.0e-05, "x_e": 1.01, "q_star": 0.00231, "q_star_dot": -1.2e-4, "q_star_ddot": 3.1e-4,
      "q_star_dddot": 1.0e-4}
R1 = [4.9e-4, 4.4e-5, -8.5e-5, 4.2e-4, 2.8e-4, -4.2e-4, -2.8e-4]
R2 = [-2.0e-4, 1.0e-5, 3.0e-3, -1.0e-4, 5.0e-5, 2.0e-4, 1.0e-4]
NAMES = list(X1)


def _controller_expected(x: dict, rates: list[float], gains: dict | None = None) -> tuple[float, float]:
    """(u, du/dt) of components' Theorem 3 controller at inputs x with input rates `rates`."""
    ctrl = catalog.controller("Maglev_Theorem3", gains or {})
    values = [x[n] for n in NAMES]
    return float(ctrl.u_scalar(*values[:3], tuple(values[3:]))), float(ctrl.u_derivative(values, rates))


def _u_and_rate(slave: Slave) -> tuple[float, float]:
    u = slave.get("u")[0]
    return u, slave.fmu.getRealOutputDerivatives([slave.vr["u"]], [1])[0]


def test_controller_u_and_du_dt_follow_every_setter_step_and_restored_state(fmus):
    slave = Slave(fmus["Maglev_Theorem3"])
    assert slave.init() == 0
    vrs = [slave.vr[n] for n in NAMES]
    slave.set(**X1)
    slave.fmu.setRealInputDerivatives(vrs, [1] * 7, R1)
    assert _u_and_rate(slave) == pytest.approx(_controller_expected(X1, R1), rel=1e-15)
    slave.fmu.setRealInputDerivatives(vrs, [1] * 7, R2)               # the same request, other rates
    assert _u_and_rate(slave) == pytest.approx(_controller_expected(X1, R2), rel=1e-15)
    slave.fmu.setRealInputDerivatives(vrs[:2], [1] * 2, R1[:2])       # another request: only q', p'
    mixed = R1[:2] + R2[2:]
    assert _u_and_rate(slave) == pytest.approx(_controller_expected(X1, mixed), rel=1e-15)
    state = slave.fmu.getFMUstate()
    slave.set(**X2)                                                    # new inputs, the rates kept
    assert _u_and_rate(slave) == pytest.approx(_controller_expected(X2, mixed), rel=1e-15)
    assert slave.step(0.0, 0.01) == 0                                  # rates hold for one step only
    assert _u_and_rate(slave) == pytest.approx((_controller_expected(X2, mixed)[0], 0.0), rel=1e-15)
    slave.fmu.setFMUstate(state)                                       # back to X1 with its rates
    assert _u_and_rate(slave) == pytest.approx(_controller_expected(X1, mixed), rel=1e-15)


def test_controller_u_before_initialization_follows_the_parameters(fmus):
    slave = Slave(fmus["Maglev_Theorem3"])
    slave.fmu.setupExperiment(startTime=0.0)
    slave.fmu.enterInitializationMode()
    slave.set(**X1)
    assert slave.get("u")[0] == pytest.approx(_controller_expected(X1, R1)[0], rel=1e-15)
    slave.set(k_c=35.0)
    assert slave.get("u")[0] == pytest.approx(_controller_expected(X1, R1, {"k_c": 35.0})[0], rel=1e-15)
    assert slave.call(slave.fmu.fmi2ExitInitializationMode, slave.fmu.component) == 0
    assert slave.get("u")[0] == pytest.approx(_controller_expected(X1, R1, {"k_c": 35.0})[0], rel=1e-15)


def test_plant_derivatives_and_energy_follow_u_its_rate_parameters_and_restored_state(fmus):
    slave = Slave(fmus["Maglev"])
    slave.fmu.setupExperiment(startTime=0.0)
    slave.fmu.enterInitializationMode()
    names = ["q", "p", "x_e", "H"]
    request = ([slave.vr[n] for n in names] * 2, [1] * 4 + [2] * 4)

    def expected(params: dict, eta, u: float, du: float) -> list[float]:
        plant = catalog.plant("Maglev", params)
        d1, d2, H1, H2 = plant.time_derivatives(np.array(eta), u, du)
        return [*d1, H1, *d2, H2]

    def got() -> list[float]:
        return slave.fmu.getRealOutputDerivatives(*request)

    eta0 = slave.get("q", "p", "x_e")
    plant0 = catalog.plant("Maglev", {})
    slave.set(u=0.9)
    assert got() == pytest.approx(expected({}, eta0, 0.9, 0.0), rel=1e-14)
    assert slave.get("H")[0] == pytest.approx(plant0.H(np.array(eta0)), rel=1e-15)
    slave.set(k=0.7)                                                   # before initialization: a parameter alone
    assert got() == pytest.approx(expected({"k": 0.7}, eta0, 0.9, 0.0), rel=1e-14)
    slave.set(q_0=0.0021)                                              # and the initial state
    eta1 = [0.0021] + list(eta0[1:])
    assert slave.get("q", "p", "x_e") == eta1
    assert got() == pytest.approx(expected({"k": 0.7}, eta1, 0.9, 0.0), rel=1e-14)
    assert slave.get("H")[0] == pytest.approx(catalog.plant("Maglev", {"k": 0.7}).H(np.array(eta1)), rel=1e-15)
    assert slave.call(slave.fmu.fmi2ExitInitializationMode, slave.fmu.component) == 0
    u_vr = slave.vr["u"]
    slave.fmu.setRealInputDerivatives([u_vr], [1], [0.5])
    assert got() == pytest.approx(expected({"k": 0.7}, eta1, 0.9, 0.5), rel=1e-14)
    slave.fmu.setRealInputDerivatives([u_vr], [1], [-0.3])            # the same request, another rate
    assert got() == pytest.approx(expected({"k": 0.7}, eta1, 0.9, -0.3), rel=1e-14)
    state = slave.fmu.getFMUstate()
    slave.set(u=0.95)                                                  # another input, the rate kept
    assert got() == pytest.approx(expected({"k": 0.7}, eta1, 0.95, -0.3), rel=1e-14)
    assert slave.step(0.0, 1e-3) == 0
    eta2 = slave.get("q", "p", "x_e")
    assert eta2 != eta1
    # after the step: the polynomial u + u' tau at its end, until the master sets u again
    assert got() == pytest.approx(expected({"k": 0.7}, eta2, 0.95 - 0.3e-3, -0.3), rel=1e-14)
    assert slave.get("H")[0] == pytest.approx(catalog.plant("Maglev", {"k": 0.7}).H(np.array(eta2)), rel=1e-15)
    slave.fmu.setFMUstate(state)
    assert slave.get("q", "p", "x_e") == eta1
    assert got() == pytest.approx(expected({"k": 0.7}, eta1, 0.9, -0.3), rel=1e-14)
    assert slave.get("H")[0] == pytest.approx(catalog.plant("Maglev", {"k": 0.7}).H(np.array(eta1)), rel=1e-15)


def test_reference_derivatives_of_a_higher_order_after_a_lower_one(fmus):
    """The reference computes q*'s derivatives up to the highest order asked at a communication point: a
    later request of a higher order at the same point gets it, and the lower orders stay the same."""
    slave = Slave(fmus["Reference"])
    assert slave.init() == 0
    assert slave.step(0.0, 0.004) == 0
    exact = catalog.reference("sinusoid", {}).derivatives(0.004, 6)
    vr = slave.vr
    assert slave.fmu.getRealOutputDerivatives([vr["q_star"]], [1]) == [pytest.approx(exact[1], rel=1e-15)]
    got = slave.fmu.getRealOutputDerivatives([vr["q_star_dddot"], vr["q_star"]], [3, 1])
    assert got == [pytest.approx(exact[6], rel=1e-15), pytest.approx(exact[1], rel=1e-15)]


@pytest.mark.parametrize("kind", sorted(references.KINDS))
def test_reference_derivatives_do_not_depend_on_the_order_asked(kind):
    """What the Reference FMU relies on to compute only the orders asked: each entry of
    Reference.derivatives(t, n) is the same number (bit for bit) for every n that includes it."""
    ref = catalog.reference(kind, {})
    for t in (0.0, 3e-4, 7e-4, 0.004, 1.0):
        full = ref.derivatives(t, 7)
        for n in range(7):
            assert ref.derivatives(t, n) == full[:n + 1], (kind, t, n)


def test_checked_requests_still_refuse_bad_values(fmus):
    """A request the FMU checked once (and then takes a fast path for) still refuses a non-finite value and
    still reports which input or output it is."""
    slave = Slave(fmus["Maglev_Theorem3"])
    assert slave.init() == 0
    slave.set(**X1)
    vrs = [slave.vr[n] for n in NAMES]
    slave.fmu.setRealInputDerivatives(vrs, [1] * 7, R1)
    bad = R1[:2] + [float("nan")] + R1[3:]
    assert slave.call(slave.fmu.fmi2SetRealInputDerivatives, slave.fmu.component, _vr_array(vrs), 7,
                      _int_array([1] * 7), _real_array(bad)) == 3
    assert "input x_e" in slave.errors()
    assert _u_and_rate(slave) == pytest.approx(_controller_expected(X1, R1), rel=1e-15)   # all or nothing
    slave.set(q=float("nan"))
    status = slave.call(slave.fmu.fmi2GetRealOutputDerivatives, slave.fmu.component, _vr_array([slave.vr["u"]]), 1,
                        _int_array([1]), _real_array([0.0]))
    assert status == 3
    assert "input q = nan is not finite" in slave.errors()


def _vr_array(values):
    import ctypes
    return (ctypes.c_uint * len(values))(*values)


def _int_array(values):
    import ctypes
    return (ctypes.c_int * len(values))(*values)


def _real_array(values):
    import ctypes
    return (ctypes.c_double * len(values))(*values)
