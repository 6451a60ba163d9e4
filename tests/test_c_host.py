"""The FMUs in a C host (tests/fixtures/c_host.c): no Python on the caller's side, the interpreter is
the one pythonfmu starts, as in Simulink, OpenModelica or libcosim. Each FMU runs, its outputs equal
components/ for the same inputs, and the host process exits with status 0.

Before `em_fmu_framework.finalize_python_at_exit`, most C-host processes crashed at exit (SIGSEGV in
Py_Finalize, which pythonfmu 0.7.0 ran after numpy's libraries had shut down; docs/reliability.md,
finding 1): 10 of 12 runs of MEMS_Proposition1 here. Each FMU runs twice, once with dlclose
before exit, once without.
"""
from __future__ import annotations

import math
from pathlib import Path

import pytest
from fmpy import read_model_description

from components import catalog, maglev, mems, references
from components.plant_step import PlantStepper

from .c_host import LOOP_SOURCE, CONTROLLER_INPUTS, compile_c_host, last_inputs, run_in_c_host, run_loop_in_c_host

N = 200


@pytest.fixture(scope="module")
def c_host(tmp_path_factory) -> Path:
    exe = tmp_path_factory.mktemp("c_host") / "c_host"
    reason = compile_c_host(exe)
    if reason:
        pytest.skip(reason)
    return exe


@pytest.mark.parametrize("identifier", list(CONTROLLER_INPUTS))
@pytest.mark.parametrize("unload", [False, True], ids=["exit-loaded", "dlclose"])
def test_controller_in_c_host_equals_components_and_exits_cleanly(c_host, fmus, tmp_path, identifier, unload):
    start = CONTROLLER_INPUTS[identifier]
    run, values = run_in_c_host(c_host, fmus[identifier], tmp_path, start, ["u"], 1e-6, N, unload=unload)
    assert run.returncode == 0, f"{identifier}: exit status {run.returncode}: {run.stderr[-1500:]}"
    x = last_inputs(start, N)
    controller = catalog.controller(identifier)                     # the FMU's defaults
    expected = controller.u_scalar(x[0], x[1], x[2], tuple(x[3:]) if len(x) > 3 else None)
    assert values[2] == pytest.approx(expected, rel=1e-12), identifier


@pytest.mark.parametrize("identifier", ["MEMS", "Maglev", "Reference"])
def test_plants_and_reference_run_in_c_host_and_exit_cleanly(c_host, fmus, tmp_path, identifier):
    inputs = {"MEMS": {"u": 25.0}, "Maglev": {"u": 0.009045}, "Reference": {}}[identifier]
    outputs = {"MEMS": ["q", "p", "x_e", "H"], "Maglev": ["q", "p", "x_e", "H"],
               "Reference": ["q_star", "q_star_dot", "q_star_ddot", "q_star_dddot"]}[identifier]
    h = {"MEMS": 1e-6, "Maglev": 1e-4, "Reference": 1e-3}[identifier]
    run, values = run_in_c_host(c_host, fmus[identifier], tmp_path, inputs, outputs, h, n=50)
    assert run.returncode == 0, f"{identifier}: exit status {run.returncode}: {run.stderr[-1500:]}"
    assert len(values) == 2 + len(outputs) and all(math.isfinite(v) for v in values), values
    if identifier == "Reference":                            # the jet at t = 50 h, the end of the 50th step
        jet = references.Sinusoid().jet(50 * h)
        assert values[2:] == pytest.approx([jet.q[0], jet.qd[0], jet.qdd[0], jet.qddd[0]], rel=1e-12)
        return
    start = {v.name: float(v.start) for v in read_model_description(str(fmus[identifier])).modelVariables
             if v.start is not None}                        # the same loop through components/
    module = mems if identifier == "MEMS" else maglev
    plant = catalog.plant(identifier, {n: start[n] for n in module.PARAMETERS})
    stepper = PlantStepper(plant, rtol=start["rtol"])
    eta = (start["q_0"], start["p_0"], start["x_e_0"])
    for k in range(50):
        eta = stepper.advance(*eta, inputs["u"] * (1.0 + 0.01 * math.sin(0.1 * k)), h)
    assert values[2:] == pytest.approx([*eta, plant.H(eta)], rel=1e-12, abs=0.0), identifier


@pytest.fixture(scope="module")
def c_loop(tmp_path_factory) -> Path:
    exe = tmp_path_factory.mktemp("c_loop") / "c_loop"
    reason = compile_c_host(exe, LOOP_SOURCE)
    if reason:
        pytest.skip(reason)
    return exe


@pytest.mark.parametrize("plant_id, controller_id, h, n", [("MEMS", "MEMS_Proposition1", 1e-6, 300),
                                                           ("Maglev", "Maglev_Proposition2", 1e-3, 200)])
def test_closed_loop_of_two_fmus_in_c_host_equals_components(c_loop, fmus, tmp_path, plant_id, controller_id, h, n):
    """Plant and controller FMU in one C process (one interpreter for both, started by pythonfmu):
    the sampled-data loop equals the same loop through components/ (controller.u_scalar at each
    communication point, PlantStepper over the step), and the process exits cleanly. The MEMS moves
    from 15 um past its set point 30 um in 0.3 ms; the maglev FMU starts at the set point of its
    default regulator (a check of the plumbing and of two libraries in one C process)."""
    run, values = run_loop_in_c_host(c_loop, fmus[plant_id], fmus[controller_id], tmp_path, h, n)
    assert run.returncode == 0, f"exit status {run.returncode}: {run.stderr[-1500:]}"
    start = {v.name: float(v.start) for v in read_model_description(str(fmus[plant_id])).modelVariables
             if v.start is not None}
    module = mems if plant_id == "MEMS" else maglev
    plant = catalog.plant(plant_id, {k: start[k] for k in module.PARAMETERS})
    controller = catalog.controller(controller_id)                  # the FMU's defaults
    stepper = PlantStepper(plant, rtol=start["rtol"])
    eta = (start["q_0"], start["p_0"], start["x_e_0"])
    for _ in range(n):
        u = controller.u_scalar(*eta, None)
        eta = stepper.advance(*eta, u, h)
    assert values == pytest.approx([*eta, u], rel=1e-12, abs=0.0)
