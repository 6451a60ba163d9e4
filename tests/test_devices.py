"""emcosim.devices.scenario: the SSP scenario of a device's plant in closed loop with one of its controllers.

Independent truth: the same loop integrated monolithically (components.monolithic, scipy Radau) from the
scenario's initial state; and the paper's own scenario files where the setups coincide."""
from __future__ import annotations

import numpy as np
import pytest

from components import catalog, monolithic
from emcosim.devices.scenario import Setup, StackedReference, parse_reference, reference_components, scenario_files
from emcosim.engine.master import Simulation
from emcosim.engine.ssd import read_scenario

MAGLEV = catalog.DEVICES["Maglev"]
MEMS = catalog.DEVICES["MEMS"]


def write(folder, files):
    folder.mkdir(parents=True, exist_ok=True)
    for name, text in files.items():
        (folder / name).write_text(text)
    return folder


def test_regulation_scenario_runs_to_the_monolithic_loop(tmp_path, fmu_dir):
    setup = Setup("Proposition2", stop_time=4.0, step_size=0.01, q_0=[0.0015])
    folder = write(tmp_path / "s", scenario_files(MAGLEV, setup, str(fmu_dir)))
    s = read_scenario(folder)
    assert {c.name for c in s.components} == {"plant", "controller"}
    with Simulation(s) as sim:
        r = sim.run(record=["plant.q", "plant.p", "plant.x_e"])
    ctrl = catalog.controller("Maglev_Proposition2", {})
    eta0 = MAGLEV.plant().equilibrium([0.0015])
    truth = monolithic.simulate(ctrl, eta0, 4.0, n_samples=401, rtol=1e-10)
    q_truth = np.interp(r.time, truth.t, np.asarray(truth.eta)[:, 0])
    assert np.max(np.abs(r["plant.q"] - q_truth)) < 1e-3 * 0.0025        # the coupling error of h = 0.01 s
    assert float(r["plant.x_e"][0]) == pytest.approx(float(eta0[2]), rel=1e-12)   # started at the equilibrium's flux


def test_tracking_scenario_feeds_the_reference_to_the_controller(tmp_path, fmu_dir):
    ref = parse_reference("sinusoid:offset=0.0025,amplitude=0.0005,omega=1")
    setup = Setup("Theorem3", stop_time=2.0, step_size=0.01, references=[ref], q_0=[0.0015])
    folder = write(tmp_path / "s", scenario_files(MAGLEV, setup, str(fmu_dir)))
    s = read_scenario(folder)
    ends = {(c.start_element, c.start_connector, c.end_connector) for c in s.connections}
    assert ("reference_q", "q_star_ddot", "q_star_ddot") in ends
    with Simulation(s) as sim:
        r = sim.run(record=["plant.q"])
    ctrl = catalog.controller("Maglev_Theorem3", {})
    generator = reference_components(MAGLEV.q, [ref], "test")[0]
    truth = monolithic.simulate(ctrl, MAGLEV.plant().equilibrium([0.0015]), 2.0, reference=generator, n_samples=201)
    q_truth = np.interp(r.time, truth.t, np.asarray(truth.eta)[:, 0])
    assert np.max(np.abs(r["plant.q"] - q_truth)) < 1e-3 * 0.0025


def test_stacked_reference_gives_vector_jets():
    refs = reference_components(MAGLEV.q * 2, [parse_reference("sinusoid:offset=1,amplitude=2,omega=3"),
                                               parse_reference("constant:q_d=4")], "test")
    jet = StackedReference(refs).jet(0.5)
    assert jet.q.tolist() == pytest.approx([1 + 2 * np.sin(1.5), 4.0])
    assert jet.qd.tolist() == pytest.approx([6 * np.cos(1.5), 0.0])


@pytest.mark.parametrize("setup, message", [
    (Setup("Proposition1", 1.0, 0.01), "no design 'Proposition1'"),
    (Setup("Proposition2", 1.0, 0.01, gains={"k_x": 1.0}), "unknown gain(s) ['k_x']"),
    (Setup("Proposition2", 1.0, 0.0), "step size 0.0"),
    (Setup("Proposition2", 1.0, 0.01, q_0=[0.006]), "q_0 = [0.006]"),
    (Setup("Proposition2", 1.0, 0.01, references=[{"kind": "constant", "offset": 0.002}]), "takes no reference"),
    (Setup("Theorem3", 1.0, 0.01), "give one reference for each"),
    (Setup("Theorem3", 1.0, 0.01, references=[parse_reference("sinusoid:offset=0.0045,amplitude=0.001,omega=1")]),
     "not feasible at t = "),
])
def test_bad_setups_are_refused_naming_the_entry(setup, message):
    with pytest.raises(ValueError) as err:
        scenario_files(MAGLEV, setup, "fmus")
    assert message in str(err.value)


@pytest.mark.parametrize("text, message", [
    ("square:offset=1", "kind 'square'"), ("sinusoid:offset", "is not NAME=NUMBER"),
    ("sinusoid:offset=x", "is not NAME=NUMBER"),
])
def test_bad_reference_specs_are_refused(text, message):
    with pytest.raises(ValueError, match=message):
        parse_reference(text)


def test_a_parameter_of_another_reference_kind_is_refused():
    with pytest.raises(ValueError, match=r"a constant reference has no parameter\(s\) \['offset'\]"):
        reference_components(MAGLEV.q, [parse_reference("constant:offset=4")], "test")


def test_mems_regulation_scenario_matches_the_paper_scenario_files(fmu_dir):
    """The same setup as scenarios/mems_regulation_prop1 gives the same plant and controller parameters."""
    files = scenario_files(MEMS, Setup("Proposition1", 0.001, 1e-6, eta_0=[15e-6, 0.0, 0.0]), str(fmu_dir))
    assert "<ssv:Parameter name=\"q_0\"><ssv:Real value=\"1.5e-05\"/>" in files["plant.ssv"]
    assert "<ssv:Parameter name=\"rbar_e\">" in files["controller.ssv"]
