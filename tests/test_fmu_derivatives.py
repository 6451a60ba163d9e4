"""The FMI 2.0 derivative functions of the built FMUs (fmpy's FMU2Slave and the C host of the tests):
fmi2SetRealInputDerivatives on the plants' u (a polynomial input over the step), fmi2GetRealOutputDerivatives
(plants, controllers, reference) and fmi2GetDirectionalDerivative (controllers), against components/ and
against finite differences of components/ (tests/test_derivatives.py checks components/ itself)."""
from __future__ import annotations

import numpy as np
import pytest
from fmpy import read_model_description
from fmpy.fmi1 import FMICallException

from components import catalog
from components.plant_step import PlantStepper, simulate_polynomial
from tests.c_host import extract, run_calls
from tests.helpers import Slave, richardson_derivative

PLANTS = ("MEMS", "Maglev")
CONTROLLERS = ("MEMS_Proposition1", "MEMS_Theorem2", "Maglev_Proposition2", "Maglev_Theorem3")
# a polynomial input per plant: (u, u', u'') at three communication points, and the step
POLYNOMIALS = {"MEMS": ([(25.0, 2e5, -3e10), (26.0, -1e5, 4e10), (24.0, 0.0, 0.0)], 1e-6),
               "Maglev": ([(0.9, 0.5, -20.0), (0.95, -0.3, 10.0), (0.9, 0.0, 0.0)], 1e-3)}


@pytest.mark.parametrize("identifier,expected", [("MEMS", (True, 2, True)), ("Maglev", (True, 2, True)),
                                                 ("Reference", (False, 3, False))]
                         + [(c, (True, 1, True)) for c in CONTROLLERS])
def test_capabilities_are_declared(fmus, identifier, expected):
    cs = read_model_description(str(fmus[identifier])).coSimulation
    assert (cs.canInterpolateInputs, cs.maxOutputDerivativeOrder, cs.providesDirectionalDerivative) == expected


def _components_plant(slave: Slave, identifier: str):
    start = {v.name: float(v.start) for v in slave.md.modelVariables if v.start is not None and v.name in slave.vr}
    module = catalog.PLANTS[identifier][1]
    plant = catalog.plant(identifier, {k: start[k] for k in module})
    return plant, PlantStepper(plant, rtol=start["rtol"]), tuple(start[f"{x}_0"] for x in ("q", "p", "x_e"))


@pytest.mark.parametrize("identifier", PLANTS)
def test_plant_integrates_the_polynomial_input_the_master_sets(fmus, identifier):
    """Each doStep uses u + u' tau + u'' tau^2/2 as set before it (orders 1 and 2), the same steps as
    components' PlantStepper; the first step also against Radau with that input; derivatives hold for one
    step only (the third step, with none set, holds u)."""
    slave = Slave(fmus[identifier])
    assert slave.init() == 0
    plant, stepper, eta = _components_plant(slave, identifier)
    rows, h = POLYNOMIALS[identifier]
    u_vr = slave.vr["u"]
    for k, (u, du, d2u) in enumerate(rows):
        slave.set(u=u)
        if du or d2u:
            slave.fmu.setRealInputDerivatives([u_vr, u_vr], [1, 2], [du, d2u])
        assert slave.step(k * h, h) == 0, slave.messages
        if k == 0:
            radau = simulate_polynomial(plant, eta, h, [(u, du, d2u)], rtol=1e-12)[-1]
        eta = stepper.advance(*eta, u, h, du, d2u)
        assert slave.get("q", "p", "x_e") == pytest.approx(eta, rel=1e-13, abs=0)
        if k == 0:
            assert np.all(np.abs(np.array(eta) - radau) <= stepper.rtol * (np.array(stepper.scale) + np.abs(radau)))


@pytest.mark.parametrize("identifier", PLANTS)
def test_plant_output_derivatives_follow_the_input_in_force(fmus, identifier):
    """q, p, x_e, H derivatives of orders 1 and 2 equal EMPlant.time_derivatives at the current state with
    the input in force: the value and rate set by the master; after a step, the polynomial's value and rate
    at its end, until the master sets u again; an FMU state saved after the step restores that too."""
    slave = Slave(fmus[identifier])
    assert slave.init() == 0
    plant, _, eta = _components_plant(slave, identifier)
    (u, du, d2u), _, _ = POLYNOMIALS[identifier][0]
    h = POLYNOMIALS[identifier][1]
    vr = slave.vr
    names = ["q", "p", "x_e", "H"]
    request = ([vr[n] for n in names] * 2, [1] * 4 + [2] * 4)

    def expected(eta, u, du):
        d1, d2, H1, H2 = plant.time_derivatives(np.array(eta), u, du)
        return [*d1, H1, *d2, H2]

    slave.set(u=u)
    slave.fmu.setRealInputDerivatives([vr["u"], vr["u"]], [1, 2], [du, d2u])
    assert slave.fmu.getRealOutputDerivatives(*request) == pytest.approx(expected(eta, u, du), rel=1e-12)
    assert slave.step(0.0, h) == 0
    eta = slave.get("q", "p", "x_e")
    end = (u + du * h + d2u * h * h / 2, du + d2u * h)
    after_step = expected(eta, *end)
    assert slave.fmu.getRealOutputDerivatives(*request) == pytest.approx(after_step, rel=1e-12)
    state = slave.fmu.getFMUstate()
    slave.set(u=0.5 * u)                                                  # the master sets u: no rate
    assert slave.fmu.getRealOutputDerivatives(*request) == pytest.approx(expected(eta, 0.5 * u, 0.0), rel=1e-12)
    slave.fmu.setFMUstate(state)
    assert slave.fmu.getRealOutputDerivatives(*request) == pytest.approx(after_step, rel=1e-12)
    slave.fmu.freeFMUstate(state)


def _controller_inputs(identifier: str, slave: Slave) -> dict[str, float]:
    """Inputs near the controller's target (MEMS tracking: q ~ 0.06 m, x_e ~ 3e-6 C)."""
    ctrl = catalog.controller(identifier)
    if ctrl.tracking:
        ref = catalog.reference("sinusoid", {} if identifier.startswith("MEMS")
                                else {"offset": 0.0025, "amplitude": 0.0005, "omega": 1.0})
        jet = ref.values(0.013)
        eta = ctrl.plant.feasible_state(ref.jet(0.013))[0]
    else:
        jet, eta = (), ctrl.target()
    eta = eta * np.array([1.02, 1.0, 0.97]) + np.array([0.0, 1e-3 * (abs(eta[1]) or 1e-10), 0.0])
    names = [v.name for v in slave.md.modelVariables if v.causality == "input"]
    return dict(zip(names, list(eta) + list(jet)))


@pytest.mark.parametrize("identifier", CONTROLLERS)
def test_controller_jacobian_and_du_dt(fmus, identifier):
    """fmi2GetDirectionalDerivative of u with respect to each input, and along a combination, equals
    Richardson differences of components' real u (1e-8 relative); du/dt from the input derivatives the
    master set (inputs without one count as constant) is the same Jacobian applied to them."""
    slave = Slave(fmus[identifier])
    assert slave.init() == 0
    inputs = _controller_inputs(identifier, slave)
    slave.set(**inputs)
    names = list(inputs)
    ctrl = catalog.controller(identifier)
    x = np.array([inputs[n] for n in names])
    u = lambda z: np.atleast_1d(ctrl.u_scalar(z[0], z[1], z[2], tuple(z[3:]) if ctrl.tracking else None))  # noqa: E731
    assert slave.get("u")[0] == pytest.approx(u(x)[0], rel=1e-15)
    scale = np.where(x != 0, np.abs(x), 1.0)
    for j, name in enumerate(names):
        fmu = slave.fmu.getDirectionalDerivative([slave.vr["u"]], [slave.vr[name]], [scale[j]])[0]
        e = np.zeros(x.size)
        e[j] = scale[j]
        fd = richardson_derivative(u, x, e, 1.0)[0]
        assert abs(fmu - fd) <= 1e-8 * abs(fmu) or fmu == fd == 0.0, (name, fmu, fd)
    rates = scale * np.linspace(0.5, -0.7, x.size)
    rates[1] = 0.0                                        # p: no derivative set, counts as constant
    fd = richardson_derivative(u, x, rates, 1.0)[0]
    known = [n for n, r in zip(names, rates) if r]
    seeds = [r for r in rates if r]
    jv = slave.fmu.getDirectionalDerivative([slave.vr["u"]], [slave.vr[n] for n in known], seeds)[0]
    assert jv == pytest.approx(fd, rel=1e-8)
    slave.fmu.setRealInputDerivatives([slave.vr[n] for n in known], [1] * len(known), seeds)
    assert slave.fmu.getRealOutputDerivatives([slave.vr["u"]], [1])[0] == pytest.approx(jv, rel=1e-14)


def test_reference_output_derivatives(fmus):
    """Output q_star_k of derivative order n is q*^(k + n) of components' reference at the FMU's time,
    which also is Richardson differences in time of the order below (1e-8 relative)."""
    slave = Slave(fmus["Reference"])
    assert slave.init() == 0
    assert slave.step(0.0, 0.004) == 0
    ref = catalog.reference("sinusoid", {})
    exact = ref.derivatives(0.004, 6)
    outputs = ["q_star", "q_star_dot", "q_star_ddot", "q_star_dddot"]
    for k, name in enumerate(outputs):
        for n in (1, 2, 3):
            got = slave.fmu.getRealOutputDerivatives([slave.vr[name]], [n])[0]
            assert got == pytest.approx(exact[k + n], rel=1e-14)
            fd = richardson_derivative(lambda t: np.atleast_1d(ref.derivatives(t[0], k + n - 1)[k + n - 1]),
                                       np.array([0.004]), np.ones(1), 1 / 30.0, decades=(-2, -8))[0]
            assert got == pytest.approx(fd, rel=1e-8)


def test_reference_output_derivatives_follow_time_and_restored_states(fmus):
    """The FMU computes the derivatives once per communication point: after a further step, and after
    fmi2SetFMUstate back to the earlier point, every order is that of the FMU's current time."""
    slave = Slave(fmus["Reference"])
    assert slave.init() == 0
    ref = catalog.reference("sinusoid", {})
    outputs = ["q_star", "q_star_dot", "q_star_ddot", "q_star_dddot"]
    vrs = [slave.vr[name] for name in outputs for _ in (1, 2, 3)]
    orders = [n for _ in outputs for n in (1, 2, 3)]

    def check(t: float) -> None:
        exact = ref.derivatives(t, 6)
        got = slave.fmu.getRealOutputDerivatives(vrs, orders)
        np.testing.assert_allclose(got, [exact[k + n] for k in range(4) for n in (1, 2, 3)], rtol=1e-14)

    assert slave.step(0.0, 0.004) == 0
    check(0.004)
    state = slave.fmu.getFMUstate()
    assert slave.step(0.004, 0.003) == 0
    check(0.007)
    slave.fmu.setFMUstate(state)
    check(0.004)


# ---- the same calls from C -------------------------------------------------------------------------------
def test_derivative_functions_of_the_fmus_in_c_host(c_calls, fmus, tmp_path):
    """A C host under env -i: the MEMS plant steps with a polynomial input and answers x_e' and x_e''; the
    Theorem 2 controller answers du/dx_e and du/dt; the reference answers q*''''. All equal components/."""
    folder, vr = extract(fmus["MEMS"], tmp_path)
    (u, du, d2u), _, _ = POLYNOMIALS["MEMS"][0]
    h = POLYNOMIALS["MEMS"][1]
    run, lines = run_calls(c_calls, folder, ["inst", "init", "setr", str(vr["u"]), repr(u),
                                             "dset", str(vr["u"]), "1", repr(du), "dset", str(vr["u"]), "2", repr(d2u),
                                             "step", "0", repr(h), "getr", str(vr["q"]), "getr", str(vr["p"]),
                                             "getr", str(vr["x_e"]), "dget", str(vr["x_e"]), "1",
                                             "dget", str(vr["x_e"]), "2", "free"])
    assert run.returncode == 0, run.stderr[-1500:]
    plant = catalog.plant("MEMS")
    stepper = PlantStepper(plant, rtol=1e-8)
    eta = stepper.advance(15e-6, 0.0, 0.0, u, h, du, d2u)
    got = [float(line[2]) for line in lines if line[0] in ("getr", "dget")]
    assert [line[1] for line in lines if line[0] in ("getr", "dget")] == ["0"] * 5
    assert got[:3] == pytest.approx(eta, rel=1e-13, abs=0)
    d1, d2, _, _ = plant.time_derivatives(np.array(eta), u + du * h + d2u * h * h / 2, du + d2u * h)
    assert got[3:] == pytest.approx([d1[2], d2[2]], rel=1e-12)

    folder, vr = extract(fmus["MEMS_Theorem2"], tmp_path)
    x = {"q": 0.06, "p": 2.8e-9, "x_e": 2.9e-6, "q_star": 0.06, "q_star_dot": 1.2, "q_star_ddot": -30.0,
         "q_star_dddot": -1000.0}
    calls = ["inst", "init"] + [w for n, v in x.items() for w in ("setr", str(vr[n]), repr(v))]
    calls += ["jac", str(vr["u"]), str(vr["x_e"]), "1", "dset", str(vr["q"]), "1", "1.4", "dget", str(vr["u"]), "1", "free"]
    run, lines = run_calls(c_calls, folder, calls)
    assert run.returncode == 0, run.stderr[-1500:]
    ctrl = catalog.controller("MEMS_Theorem2")
    values = list(x.values())
    results = [line for line in lines if line[0] in ("jac", "dget")]
    assert [r[1] for r in results] == ["0", "0"]
    assert float(results[0][2]) == pytest.approx(ctrl.u_derivative(values, [0, 0, 1, 0, 0, 0, 0]), rel=1e-14)
    assert float(results[1][2]) == pytest.approx(ctrl.u_derivative(values, [1.4, 0, 0, 0, 0, 0, 0]), rel=1e-14)

    folder, vr = extract(fmus["Reference"], tmp_path)
    run, lines = run_calls(c_calls, folder, ["inst", "init", "step", "0", "0.01", "dget", str(vr["q_star_dddot"]), "1",
                                             "free"])
    assert run.returncode == 0, run.stderr[-1500:]
    result = [line for line in lines if line[0] == "dget"][0]
    assert result[1] == "0" and float(result[2]) == pytest.approx(catalog.reference("sinusoid").derivatives(0.01, 4)[4],
                                                                  rel=1e-14)


# ---- issue 26, item 9: input derivatives of any order ------------------------------------------------
# a polynomial input of degree 4 per plant: (u, u', u'', u''', u'''') at t = 0, and the step
QUARTICS = {"MEMS": ((25.0, 2e5, -3e10, 1e17, 1e23), 1e-6), "Maglev": ((0.9, 0.5, -20.0, 1e6, 1e9), 1e-3)}


@pytest.mark.parametrize("identifier", PLANTS)
def test_plant_integrates_a_polynomial_input_of_any_degree(fmus, identifier):
    """FMI 2.0 declares no highest input derivative order, and OMSimulator (--inputExtrapolation) sends the
    source's top order: the plants refused order 3 with fmi2Error. Now orders 1..4 set before a doStep give
    the quartic u + u' tau + ... + u'''' tau^4/4!: the same step as components' PlantStepper with the
    orders >= 3 in `higher`, within rtol of Radau with that input, and not the step of the quadratic alone;
    after the step the output derivatives use the quartic's value and rate at its end."""
    slave = Slave(fmus[identifier])
    assert slave.init() == 0
    plant, stepper, eta = _components_plant(slave, identifier)
    coefficients, h = QUARTICS[identifier]
    u, du, d2u, d3u, d4u = coefficients
    vr = slave.vr
    slave.set(u=u)
    slave.fmu.setRealInputDerivatives([vr["u"]] * 4, [1, 2, 3, 4], [du, d2u, d3u, d4u])
    assert slave.step(0.0, h) == 0, slave.messages
    got = slave.get("q", "p", "x_e")
    quadratic = PlantStepper(plant, rtol=stepper.rtol).advance(*eta, u, h, du, d2u)
    expected = stepper.advance(*eta, u, h, du, d2u, {3: d3u, 4: d4u})
    assert got == pytest.approx(expected, rel=1e-13, abs=0)
    radau = simulate_polynomial(plant, eta, h, [coefficients], rtol=1e-12)[-1]
    tolerance = stepper.rtol * (np.array(stepper.scale) + np.abs(radau))
    assert np.all(np.abs(np.array(got) - radau) <= tolerance)
    assert np.any(np.abs(np.array(quadratic) - radau) > tolerance)    # the orders 3 and 4 count
    end = (u + du * h + d2u * h**2 / 2 + d3u * h**3 / 6 + d4u * h**4 / 24,
           du + d2u * h + d3u * h**2 / 2 + d4u * h**3 / 6)
    d1, d2, _, _ = plant.time_derivatives(np.array(got), *end)
    assert slave.fmu.getRealOutputDerivatives([vr["x_e"], vr["x_e"]], [1, 2]) == pytest.approx([d1[2], d2[2]],
                                                                                              rel=1e-10)


@pytest.mark.parametrize("identifier", PLANTS)
def test_plant_takes_an_order_far_beyond_what_it_needs(fmus, identifier):
    """An order as high as fmi2Integer goes (2^31 - 1) with a large value: fmi2OK; its term
    u^(k) tau^k / k! vanishes over a step (evaluated without forming k!), so the step equals the held
    input's; orders below 1 are refused with fmi2Error naming the order."""
    held, moved = Slave(fmus[identifier]), Slave(fmus[identifier])
    h = QUARTICS[identifier][1]
    for slave in (held, moved):
        assert slave.init() == 0
        slave.set(u=QUARTICS[identifier][0][0])
    moved.fmu.setRealInputDerivatives([moved.vr["u"]], [2**31 - 1], [1e300])
    assert held.step(0.0, h) == 0 and moved.step(0.0, h) == 0, moved.messages
    assert moved.get("q", "p", "x_e") == held.get("q", "p", "x_e")
    for order in (0, -1):
        with pytest.raises(FMICallException):
            moved.fmu.setRealInputDerivatives([moved.vr["u"]], [order], [1.0])
        assert f"order {order} for input u is not an integer >= 1" in moved.errors()
    held.free()
    moved.free()


@pytest.mark.parametrize("identifier", CONTROLLERS)
def test_controller_takes_every_order_and_uses_the_first(fmus, identifier):
    """The controllers refused input derivatives of order 2 (fmi2Error): OMSimulator with
    --inputExtrapolation then failed every step. Now orders 1..3 (and 17) are accepted with fmi2OK, and
    du/dt, which needs the first ones only, is the same as with order 1 alone (the rest are dropped)."""
    first, every = Slave(fmus[identifier]), Slave(fmus[identifier])
    names = None
    for slave in (first, every):
        assert slave.init() == 0
        inputs = _controller_inputs(identifier, slave)
        slave.set(**inputs)
        names = list(inputs)
    rates = [0.01 * (abs(v) or 1.0) * (k + 1) for k, v in enumerate(inputs.values())]
    vrs = [first.vr[n] for n in names]
    first.fmu.setRealInputDerivatives(vrs, [1] * len(vrs), rates)
    every.fmu.setRealInputDerivatives(vrs * 4, [1] * len(vrs) + [2] * len(vrs) + [3] * len(vrs) + [17] * len(vrs),
                                      rates + [1e3 * r for r in rates] * 3)
    du = first.fmu.getRealOutputDerivatives([first.vr["u"]], [1])
    assert every.fmu.getRealOutputDerivatives([every.vr["u"]], [1]) == du and np.isfinite(du[0])
    assert every.step(0.0, 1e-6) == 0 and every.messages == []
    first.free()
    every.free()
