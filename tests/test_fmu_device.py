"""FMUs of any device (issue 25): fmus.build.build_device on tests/device_two_axis.py (n_m = n_e = 2) and
tests/device_levitator.py (the maglev renamed), and the unit parser of fmus/variables.py.

Independent truths: tests/plants_for_tests.TwoAxisLevitator (a second implementation of the same plant),
scipy's solve_ivp (Radau) of the sampled-data and of the continuous closed loop, complex-step derivatives
of components, the suite's own Maglev FMUs."""
from __future__ import annotations

import re
import zipfile
from pathlib import Path

import numpy as np
import pytest
from fmpy import read_model_description, simulate_fmu
from fmpy.validation import validate_fmu
from scipy.integrate import solve_ivp

from components.proposition2 import Proposition2
from fmus.build import build_device
from fmus.variables import RATE_UNITS, UNITS, base_units, parse_unit
from tests.helpers import Slave
from tests.plants_for_tests import TwoAxisLevitator

HERE = Path(__file__).resolve().parent
STATES = ["q_1", "q_2", "p_1", "p_2", "x_e_1", "x_e_2"]


# ---- units ------------------------------------------------------------------------------------------
def test_the_parser_gives_every_entry_of_the_table():
    for unit, exponents in UNITS.items():
        assert parse_unit(unit) == exponents, unit


@pytest.mark.parametrize("unit, expected", [
    ("Wb2/J/s", {"kg": 1, "m": 2, "s": -3, "A": -2}),            # an ohm: "/" inverts the next factor only
    ("1/Ohm", {"kg": -1, "m": -2, "s": 3, "A": 2}),              # a siemens
    ("N.s/m", {"kg": 1, "s": -1}), ("m/s2", {"m": 1, "s": -2}), ("F", {"kg": -1, "m": -2, "s": 4, "A": 2}),
    ("T.m2", {"kg": 1, "m": 2, "s": -2, "A": -1}), ("Pa.m2/N", {}), ("Hz", {"s": -1}),
    ("W/K", {"kg": 1, "m": 2, "s": -3, "K": -1}),
    ("mol.cd/rad", {"mol": 1, "cd": 1, "rad": -1}), ("m-1", {"m": -1}), ("1", {}),
])
def test_unit_strings(unit, expected):
    assert parse_unit(unit) == expected
    assert base_units(unit) == expected


@pytest.mark.parametrize("unit, factor", [("mm", "mm"), ("m/", ""), ("m^2", "m^2"), ("kg.m s", "m s"), ("12", "12")])
def test_a_bad_unit_string_names_the_factor(unit, factor):
    with pytest.raises(ValueError, match=re.escape(f"factor {factor!r}")):
        parse_unit(unit)


def test_rate_units():
    assert [RATE_UNITS[u] for u in ("m", "kg.m/s", "Wb", "C")] == ["m/s", "N", "Wb/s", "C/s"]   # as before
    assert RATE_UNITS["rad"] == "rad/s" and RATE_UNITS["1"] == "1/s"
    assert parse_unit(RATE_UNITS["kg.m/s"]) == parse_unit("kg.m/s/s")


# ---- the two-axis device's FMUs -----------------------------------------------------------------------
@pytest.fixture(scope="module")
def device_fmus(tmp_path_factory) -> dict[str, Path]:
    folder = tmp_path_factory.mktemp("device")
    description = folder / "TwoAxis.toml"
    description.write_text('name = "TwoAxis"\n# (a stand-in for the plant description the FMUs were built from)\n')
    return build_device(HERE / "device_two_axis.py", "TwoAxis", None, folder / "fmus", description=description)


def truth_plant() -> TwoAxisLevitator:
    return TwoAxisLevitator(damped=True)


def test_the_fmus_and_their_bundle(device_fmus):
    assert sorted(device_fmus) == ["TwoAxis", "TwoAxis_Proposition2", "TwoAxis_Theorem3"]
    for path in device_fmus.values():
        assert validate_fmu(str(path)) == []
        names = zipfile.ZipFile(path).namelist()
        assert "resources/TwoAxis.toml" in names
        assert any(n.endswith("/device_two_axis.py") for n in names)


def test_the_plant_fmu_declares_the_device(device_fmus):
    md = read_model_description(str(device_fmus["TwoAxis"]))
    variables = {v.name: v for v in md.modelVariables}
    assert [v.name for v in md.modelVariables if v.causality == "input"] == ["u_1", "u_2"]
    assert [u.variable.name for u in md.outputs] == STATES + ["H"]
    assert all(f"{s}_0" in variables for s in STATES) and "m_12" in variables and "rtol" in variables
    assert variables["p_1"].unit == "kg.m/s" and variables["der(p_1)"].unit == "N"
    assert variables["psi0_1"].unit == "1/H"
    units = {u.name: u.baseUnit for u in md.unitDefinitions}
    assert units["1/H"].kg == -1 and units["1/H"].A == 2
    deps = {d.variable.name: sorted(v.name for v in d.dependencies) for d in md.derivatives}
    assert deps["der(q_1)"] == ["p_1", "p_2"]                                        # constant mass
    assert deps["der(p_2)"] == sorted(STATES)
    assert deps["der(x_e_1)"] == sorted(["q_1", "q_2", "x_e_1", "x_e_2", "u_1", "u_2"])
    assert md.numberOfEventIndicators == 1
    md_c = read_model_description(str(device_fmus["TwoAxis_Theorem3"]))
    inputs = [v.name for v in md_c.modelVariables if v.causality == "input"]
    assert inputs == STATES + ["q_1_star", "q_2_star", "q_1_star_dot", "q_2_star_dot", "q_1_star_ddot",
                               "q_2_star_ddot", "q_1_star_dddot", "q_2_star_dddot"]
    assert [u.variable.name for u in md_c.outputs] == ["u_1", "u_2"]
    assert "R_e_bar_1_2" in {v.name for v in md_c.modelVariables}


@pytest.mark.parametrize("identifier", ["TwoAxis", "TwoAxis_Proposition2", "TwoAxis_Theorem3"])
def test_each_fmu_runs_alone_as_cs_and_me(device_fmus, identifier):
    runs = [simulate_fmu(str(device_fmus[identifier]), fmi_type=t, stop_time=0.2, output_interval=0.01,
                         relative_tolerance=1e-9) for t in ("CoSimulation", "ModelExchange")]
    for r in runs:
        assert len(r) > 10 and all(np.all(np.isfinite(r[n])) for n in r.dtype.names)
    if identifier == "TwoAxis":                                   # open loop from INITIAL_STATE, u at its start
        eta0 = np.array([0.05, 0.1, 0.0, 0.0, 1.0, 1.0])
        md = read_model_description(str(device_fmus[identifier]))
        u0 = np.array([float(v.start) for v in md.modelVariables if v.causality == "input"])   # default_experiment's
        P = truth_plant()
        sol = solve_ivp(lambda t, x: P.f(x, u0), (0, 0.2), eta0, method="Radau", rtol=1e-11, atol=1e-11)
        for r, tol in zip(runs, (1e-7, 1e-6)):                   # doStep's rtol 1e-8 (1e-9); CVode's 1e-9
            got = np.array([r[n][-1] for n in STATES])
            assert np.max(np.abs(got - sol.y[:, -1]) / (1 + np.abs(sol.y[:, -1]))) < tol


def closed_loop(device_fmus, h: float, steps: int, eta0):
    """plant + Proposition 2 FMUs in a Gauss-Seidel loop (controller from the plant's outputs, u held over
    each step): the plant's states at every communication point."""
    plant, ctrl = Slave(device_fmus["TwoAxis"], "plant"), Slave(device_fmus["TwoAxis_Proposition2"], "ctrl")
    assert plant.init(**{f"{n}_0": v for n, v in zip(STATES, eta0)}, rtol=1e-10) == 0, plant.errors()
    assert ctrl.init(**dict(zip(STATES, eta0))) == 0, ctrl.errors()
    out = [np.array(plant.get(*STATES))]
    for k in range(steps):
        ctrl.set(**dict(zip(STATES, out[-1])))
        u = ctrl.get("u_1", "u_2")
        plant.set(u_1=u[0], u_2=u[1])
        assert plant.step(k * h, h) == 0, plant.errors()
        assert ctrl.step(k * h, h) == 0, ctrl.errors()
        out.append(np.array(plant.get(*STATES)))
    plant.free()
    ctrl.free()
    return np.array(out)


def test_the_closed_loop_agrees_with_the_monolithic_one(device_fmus):
    """The co-simulated loop equals the sampled-data loop (u = controller.u(eta_k) held, Radau) to the
    plant's integration tolerance, and the continuous loop eta' = f(eta, u(eta)) to within the coupling
    error of the zero-order hold (first order: halving h halves it)."""
    P = truth_plant()
    C = Proposition2(P, [0.1, 0.2], np.diag([1.5, 2.5]), k_c=[[3.0, 0.5], [0.5, 2.0]],
                     D_d=[[0.03, 0.0], [0.01, 0.0]])
    eta_d = C.target()
    eta0 = eta_d + np.array([0.05, -0.04, 0.1, 0.0, 0.1, -0.1])
    h, T = 0.02, 4.0
    steps = int(round(T / h))
    cosim = closed_loop(device_fmus, h, steps, eta0)
    eta, sampled = eta0, [eta0]
    for _ in range(steps):
        u = C.u(eta)
        eta = solve_ivp(lambda t, x: P.f(x, u), (0, h), eta, method="Radau", rtol=1e-12, atol=1e-12,
                        jac=lambda t, x: P.jacobian(x)).y[:, -1]
        sampled.append(eta)
    assert np.max(np.abs(cosim - np.array(sampled))) < 1e-7
    grid = np.linspace(0.0, T, steps + 1)
    mono = solve_ivp(lambda t, x: P.f(x, C.u(x)), (0, T), eta0, method="Radau", rtol=1e-11, atol=1e-11,
                     t_eval=grid).y.T
    coupling = np.max(np.abs(cosim - mono))
    half = np.max(np.abs(closed_loop(device_fmus, h / 2, 2 * steps, eta0)[::2] - mono))
    assert coupling < 0.05 * np.max(np.abs(eta0 - eta_d))
    assert 1.6 < coupling / half < 2.4                            # first order in h


def complex_step(fun, x, v):
    return np.imag(fun(x + 1e-30j * v)) / 1e-30


def test_plant_directional_and_output_derivatives(device_fmus):
    """fmi2GetDirectionalDerivative of der(x), the states and H with respect to states and inputs, against
    the complex step of the independent implementation's f and H; output derivatives (orders 1, 2) against
    EMPlant.time_derivatives."""
    P = truth_plant()
    eta = np.array([0.3, -0.2, 0.4, -0.1, 1.2, 0.7])
    u = np.array([0.4, -0.6])
    s = Slave(device_fmus["TwoAxis"])
    assert s.init(**{f"{n}_0": v for n, v in zip(STATES, eta)}) == 0, s.errors()
    s.set(u_1=u[0], u_2=u[1])
    unknowns = [f"der({n})" for n in STATES] + STATES + ["H"]
    knowns = STATES + ["u_1", "u_2"]
    rng = np.random.default_rng(3)
    for _ in range(3):
        seed = rng.normal(size=len(knowns))
        got = np.array(s.fmu.getDirectionalDerivative([s.vr[n] for n in unknowns], [s.vr[n] for n in knowns],
                                                      list(seed)))
        x = np.concatenate([eta, u])
        want = np.concatenate([complex_step(lambda z: P.f(z[:6], z[6:]), x, seed), seed[:6],
                               [complex_step(lambda z: P.H(z[:6]), x, seed)]])
        assert np.allclose(got, want, rtol=1e-8, atol=1e-8 * np.max(np.abs(want)))
    d1, d2, H1, H2 = P.time_derivatives(eta, u, np.zeros(2))
    names = STATES + ["H"]
    vrs = [s.vr[n] for n in names]
    assert np.allclose(s.fmu.getRealOutputDerivatives(vrs, [1] * 7), list(d1) + [H1], rtol=1e-10, atol=1e-12)
    assert np.allclose(s.fmu.getRealOutputDerivatives(vrs, [2] * 7), list(d2) + [H2], rtol=1e-10, atol=1e-12)
    s.free()


def test_controller_directional_derivatives(device_fmus):
    """du_i/d(inputs) of the Theorem 3 FMU (n_e = 2 outputs, 14 inputs) against the complex step of the
    components law, and du/dt from the input rates the master sets."""
    from tests.device_two_axis import DEVICE
    C = DEVICE.controller("Theorem3")
    s = Slave(device_fmus["TwoAxis_Theorem3"])
    x = np.array([0.12, 0.21, 0.05, -0.02, 1.0, 0.9, 0.1, 0.2, 0.05, -0.03, -0.2, 0.1, 0.3, -0.2])
    names = [v.name for v in s.md.modelVariables if v.causality == "input"]
    assert s.init(**dict(zip(names, x))) == 0, s.errors()

    def law(z):
        from components.ph_plant import Jet
        return C.u(z[:6], Jet(*z[6:].reshape(4, 2)))

    assert np.allclose(s.get("u_1", "u_2"), law(x), rtol=1e-13)
    seed = np.random.default_rng(5).normal(size=14)
    got = s.fmu.getDirectionalDerivative([s.vr["u_1"], s.vr["u_2"]], [s.vr[n] for n in names], list(seed))
    want = complex_step(law, x, seed)
    assert np.allclose(got, want, rtol=1e-8, atol=1e-10)
    s.fmu.setRealInputDerivatives([s.vr[n] for n in names], [1] * 14, list(seed))
    assert np.allclose(s.fmu.getRealOutputDerivatives([s.vr["u_1"], s.vr["u_2"]], [1, 1]), want, rtol=1e-8, atol=1e-10)
    s.free()


def test_plant_fmu_state_roll_back(device_fmus):
    """A step rolled back with fmi2SetFMUstate and taken again gives the same state, with the input
    derivatives of the step; a serialized state restores into a new instance."""
    s = Slave(device_fmus["TwoAxis"])
    assert s.init() == 0
    s.set(u_1=0.5, u_2=-0.2)
    assert s.step(0.0, 0.01) == 0
    state = s.fmu.getFMUstate()
    s.fmu.setRealInputDerivatives([s.vr["u_1"], s.vr["u_2"]], [1, 2], [3.0, -1.0])
    assert s.step(0.01, 0.01) == 0
    first = s.get(*STATES)
    s.fmu.setFMUstate(state)
    s.fmu.setRealInputDerivatives([s.vr["u_1"], s.vr["u_2"]], [1, 2], [3.0, -1.0])
    assert s.step(0.01, 0.01) == 0
    assert s.get(*STATES) == first
    serialized = s.fmu.serializeFMUstate(state)
    other = Slave(device_fmus["TwoAxis"], "other")
    assert other.init() == 0
    other.fmu.setFMUstate(other.fmu.deSerializeFMUstate(serialized))
    other.set(u_1=0.5, u_2=-0.2)
    other.fmu.setRealInputDerivatives([s.vr["u_1"], s.vr["u_2"]], [1, 2], [3.0, -1.0])
    assert other.step(0.01, 0.01) == 0
    assert other.get(*STATES) == first
    s.free()
    other.free()


def test_a_state_outside_the_domain_is_refused(device_fmus):
    s = Slave(device_fmus["TwoAxis"])
    assert s.init(q_1_0=6.0) != 0                                 # Psi_11 = 5 - 6 < 0
    assert "q_1_0" in s.errors() and "positive definite" in s.errors()
    s.free()


def test_build_device_refuses_what_does_not_fit(tmp_path):
    with pytest.raises(ValueError, match="not 'Other'"):
        build_device(HERE / "device_two_axis.py", "Other", None, tmp_path)
    with pytest.raises(ValueError, match="no design"):
        build_device(HERE / "device_two_axis.py", "TwoAxis", ["Theorem2"], tmp_path)
    assert list(tmp_path.iterdir()) == []


# ---- n = 1 under another name: the scalar path --------------------------------------------------------
def test_a_renamed_maglev_equals_the_suites_maglev(tmp_path, fmus):
    paths = build_device(HERE / "device_levitator.py", "Levitator", ["Proposition2"], tmp_path)
    assert sorted(paths) == ["Levitator", "Levitator_Proposition2"]
    for name, theirs in (("Levitator", "Maglev"), ("Levitator_Proposition2", "Maglev_Proposition2")):
        ours_md, their_md = (read_model_description(str(p)) for p in (paths[name], fmus[theirs]))
        assert [(v.name, v.unit, v.causality, v.start) for v in ours_md.modelVariables] == \
               [(v.name, v.unit, v.causality, v.start) for v in their_md.modelVariables]
        assert validate_fmu(str(paths[name])) == []
    a = simulate_fmu(str(paths["Levitator"]), stop_time=0.2, output_interval=1e-3, start_values={"u": -0.5})
    b = simulate_fmu(str(fmus["Maglev"]), stop_time=0.2, output_interval=1e-3, start_values={"u": -0.5})
    for n in ("q", "p", "x_e", "H"):
        assert np.array_equal(a[n], b[n])


def test_a_generated_module_gives_its_device_through_device_designs():
    """components.codegen's modules define device(designs) instead of DEVICE: the designs asked for reach it."""
    import types

    from components.catalog import DEVICES
    from fmus.models import device_slave_classes, module_device

    asked = []
    module = types.ModuleType("generated")
    module.device = lambda designs=None: asked.append(designs) or DEVICES["Maglev"]
    assert module_device(module, ["Theorem3"]) is DEVICES["Maglev"] and asked == [["Theorem3"]]
    assert sorted(device_slave_classes(module, ["Theorem3"])) == ["Maglev", "Maglev_Theorem3"]
    with pytest.raises(ValueError, match="neither DEVICE"):
        module_device(types.ModuleType("empty"))


def test_derivative_dependencies_follow_the_structure():
    """q' = M^-1(q) p depends on q only when the mass does (eq. open-loop elecmech)."""
    from fmus.plant import derivative_dependencies
    from tests.device_two_axis import DEVICE

    q, p = ["q_1", "q_2"], ["p_1", "p_2"]
    assert derivative_dependencies(DEVICE, True)["q_2"] == p
    assert derivative_dependencies(DEVICE, False)["q_2"] == p + q
    assert derivative_dependencies(DEVICE, False)["x_e_2"] == q + ["x_e_1", "x_e_2", "u_1", "u_2"]


def test_plant_integrates_the_polynomial_of_each_input(device_fmus):
    """Input derivatives set per input (u_1: orders 1 and 3; u_2: order 2; then none: held) are the
    polynomial doStep integrates: against Radau of the independent implementation, to the FMU's rtol."""
    P = truth_plant()
    s = Slave(device_fmus["TwoAxis"])
    assert s.init(rtol=1e-11) == 0
    eta = np.array(s.get(*STATES))
    h = 0.05
    rows = [((0.5, -0.2), {"u_1": {1: 2.0, 3: 30.0}, "u_2": {2: -4.0}}), ((0.1, 0.3), {})]
    for k, (u, rates) in enumerate(rows):
        s.set(u_1=u[0], u_2=u[1])
        for name, orders in rates.items():
            s.fmu.setRealInputDerivatives([s.vr[name]] * len(orders), list(orders), list(orders.values()))
        assert s.step(k * h, h) == 0, s.errors()

        def u_of(t, u=u, rates=rates):
            return np.array([u[i] + sum(c * t ** o / {1: 1, 2: 2, 3: 6}[o] for o, c in rates.get(n, {}).items())
                             for i, n in enumerate(("u_1", "u_2"))])

        eta = solve_ivp(lambda t, x: P.f(x, u_of(t)), (0, h), eta, method="Radau", rtol=1e-13, atol=1e-13,
                        jac=lambda t, x: P.jacobian(x)).y[:, -1]
        assert np.max(np.abs(np.array(s.get(*STATES)) - eta) / (1 + np.abs(eta))) < 1e-9
    s.free()


def test_the_build_is_reproducible(device_fmus, tmp_path):
    """The same device module and description give byte-identical FMUs (fingerprint, GUID, archive)."""
    description = device_fmus["TwoAxis"].parent.parent / "TwoAxis.toml"
    again = build_device(HERE / "device_two_axis.py", "TwoAxis", None, tmp_path, description=description)
    assert all(again[k].read_bytes() == device_fmus[k].read_bytes() for k in device_fmus)


@pytest.mark.parametrize("unit, rate", [("m", "m/s"), ("kg.m/s", "N"), ("kg.m2/s", "kg.m2/s2"), ("m/s2", "m/s3"),
                                        ("rad", "rad/s"), ("1", "1/s")])
def test_the_unit_of_a_state_derivative_has_one_more_power_of_s(unit, rate):
    from fmus.variables import RATE_UNITS, parse_unit

    assert RATE_UNITS[unit] == rate
    expected = dict(parse_unit(unit))
    expected["s"] = expected.get("s", 0) - 1
    assert parse_unit(rate) == {k: v for k, v in expected.items() if v}
