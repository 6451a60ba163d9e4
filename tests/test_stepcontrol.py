"""Communication steps that keep a global tolerance (emcosim/engine/stepcontrol.py), on the C toy
FMUs (tests/toy_fmus.py): the loop x' = k x of ToyDynamic and ToyStatic, whose exact solution
e^{kt} is the independent truth. The paper scenarios' band test is in tests/test_scenarios.py."""
from __future__ import annotations

import ctypes

import numpy as np
import pytest

from emcosim.engine.errors import ScenarioError
from emcosim.engine.master import Simulation, simulate
from tests.helpers import DYNAMIC, STATIC, loop


def error(r, k: float = -1.0) -> float:
    """max |x - e^{kt}| / max |x| at the run's communication points."""
    return float(np.max(np.abs(r["plant.x"] - np.exp(k * r.time))) / np.max(np.abs(r["plant.x"])))


@pytest.mark.parametrize("K, tolerances", [(0, (1e-2, 1e-3)), (1, (1e-2, 1e-3, 1e-4, 1e-5)),
                                           (2, (1e-3, 1e-5))])
def test_error_lies_in_the_band(make, K, tolerances):
    """The achieved error against e^-t lies within [TOL/10, 3 TOL], and the run's own estimate is
    within a factor 3 of it."""
    s = loop(make, stop_time=10.0)
    for tol in tolerances:
        r = simulate(s, tolerance=tol, coupling_order=K, max_step=1.0, record=["plant.x"])
        err, report = error(r), r.step_control
        assert tol / 10 <= err <= 3 * tol, (K, tol, err, report.summary())
        assert err / 3 <= report.estimated_error <= 3 * err, (K, tol, err, report.summary())
        assert report.coupling_order == K


def test_steps_follow_the_tolerance_at_the_coupling_order(make):
    """Steps taken ~ TOL^(-1/p): with first-order coupling (p = 2) a 100x tighter tolerance costs
    about 10x the steps, not 100x."""
    s = loop(make, stop_time=10.0)
    n = [simulate(s, tolerance=tol, coupling_order=1, max_step=1.0, record=["plant.x"]).step_control.accepted
         for tol in (1e-3, 1e-5)]
    assert 4 < n[1] / n[0] < 25, n


def test_a_too_long_first_step_is_rolled_back(make):
    s = loop(make, stop_time=2.0)
    r = simulate(s, tolerance=1e-4, step_size=1.0, coupling_order=1, record=["plant.x"])
    assert r.step_control.rejected >= 1
    assert r.time[0] == 0.0 and r.time[-1] == 2.0 and np.all(np.diff(r.time) > 0)
    assert error(r) <= 3e-4
    assert r.step_control.accepted >= len(r) - 1


def test_stiff_loop_stays_stable(make):
    """x' = -200 x through the coupling: explicit coupling is unstable for steps above about
    2/200 s whatever the defect says once x has decayed; the long-step check keeps it stable."""
    s = loop(make, k=-200.0, stop_time=1.0)
    r = simulate(s, tolerance=1e-3, coupling_order=0, max_step=0.5, record=["plant.x"])
    assert error(r, k=-200.0) <= 3e-3, r.step_control.summary()
    assert np.max(np.abs(r["plant.x"][r.time > 0.2])) < 1e-3


def test_reruns_report_and_session_reuse(make):
    """A Simulation runs error-controlled and fixed-step runs one after the other with the same
    results as fresh ones (the shadow copy is reset between runs)."""
    s = loop(make, stop_time=3.0)
    with Simulation(s) as sim:
        a = sim.run(tolerance=1e-4, record=["plant.x"])
        b = sim.run(record=["plant.x"])
        c = sim.run(tolerance=1e-4, record=["plant.x"])
    np.testing.assert_array_equal(a["plant.x"], c["plant.x"])
    np.testing.assert_array_equal(b["plant.x"], simulate(s, record=["plant.x"])["plant.x"])
    assert "communication steps" in c.step_control.summary() and c.step_control.tolerance == 1e-4


@pytest.mark.parametrize("tolerance", [0.0, -1e-3, 2.0, float("nan")])
def test_bad_tolerance_is_refused(make, tolerance):
    with pytest.raises(ScenarioError, match="tolerance"):
        simulate(loop(make), tolerance=tolerance)


def test_cli_run_with_tolerance_reports_the_steps(make, tmp_path, capsys):
    from emcosim.cli import main
    from emcosim.engine.results import read_csv
    s = loop(make, stop_time=2.0)
    out = tmp_path / "r.csv"
    assert main(["run", str(s.path.parent), "--tolerance", "1e-4", "--coupling-order", "1", "--max-step", "0.5",
                 "--record", "plant.x", "-o", str(out), "--no-progress"]) == 0
    text = capsys.readouterr().out
    assert "communication steps" in text and "rejected" in text and "coupling order 1" in text
    data = read_csv(out)
    assert np.max(np.abs(data["plant.x"] - np.exp(-data["time"]))) <= 3e-4
    with pytest.raises(SystemExit):                     # argparse: K must be 0..3
        main(["run", str(s.path.parent), "--coupling-order", "7", "--no-progress"])


@pytest.mark.parametrize("tolerance", [None, 1e-3])
def test_a_non_finite_derivative_ends_the_run_naming_it(make, tmp_path, tolerance):
    """An FMU that returns a NaN output derivative with fmi2OK (ToyDynamic's nan_at) ends the run
    with a message naming the derivative, its order and the time; the rows before it are kept in the
    sink's partial file, each row accepted once (no rolled-back step among them)."""
    from emcosim.engine.errors import SimulationError
    from emcosim.engine.outputs import ResultFile
    from emcosim.engine.results import read_csv
    s = make([("plant", "dynamic", DYNAMIC, True, 3), ("ctrl", "static", STATIC, True, 3)],
             [("plant.x", "ctrl.u1"), ("ctrl.y", "plant.u")],
             {"ctrl": {"k1": -1.0}, "plant": {"x0": 1.0, "nan_at": 0.5}}, 1.0, 0.01)
    out = tmp_path / "r.csv"
    with pytest.raises(SimulationError) as failure:
        with ResultFile(out) as sink:
            simulate(s, tolerance=tolerance, coupling_order=1, max_step=0.1 if tolerance else None, record=["plant.x"],
                     sink=sink)
    message = str(failure.value)
    assert "derivative of order 1 of plant.x = nan at t = " in message, message
    t_fail = float(message.split("at t = ")[1].split(" s")[0])
    assert 0.5 <= t_fail <= 0.6, message
    data = read_csv(sink.final)
    assert sink.final.name == "r.partial.csv" and not out.exists()
    assert np.all(np.diff(data["time"]) > 0) and data["time"][-1] < t_fail
    assert np.max(np.abs(data["plant.x"] - np.exp(-data["time"]))) <= 3e-3


def test_rejected_steps_never_reach_the_sink(make, tmp_path):
    """With a too long first step (rejected, rolled back) the streamed file holds the accepted points
    only: strictly increasing times, one row per accepted step of the last pass plus the start (a
    second pass, when the first missed the aim, replaces the first pass's rows)."""
    from emcosim.engine.outputs import ResultFile
    from emcosim.engine.results import read_csv
    s = loop(make, stop_time=2.0)
    out = tmp_path / "r.csv"
    with ResultFile(out) as sink:
        r = simulate(s, tolerance=1e-4, step_size=1.0, coupling_order=1, record=["plant.x"], sink=sink)
    data = read_csv(out)
    assert r.step_control.rejected >= 1
    assert np.all(np.diff(data["time"]) > 0) and data["time"][0] == 0.0 and data["time"][-1] == 2.0
    assert len(data["time"]) == len(r) <= r.step_control.accepted + 1
    assert np.max(np.abs(data["plant.x"] - np.exp(-data["time"]))) <= 3e-4


def test_a_maximum_step_without_a_tolerance_is_refused(make):
    """The API as the CLI: max_step bounds the steps a tolerance chooses; alone it would be ignored."""
    from emcosim.engine.errors import ScenarioError
    s = make([("plant", "dynamic", DYNAMIC, True, 3), ("ctrl", "static", STATIC, True, 3)],
             [("plant.x", "ctrl.u1"), ("ctrl.y", "plant.u")], {"ctrl": {"k1": -1.0}}, 0.1, 0.01)
    with pytest.raises(ScenarioError, match="max_step bounds the steps that tolerance chooses"):
        simulate(s, max_step=0.05)


@pytest.mark.parametrize("tolerance, coupling", [(None, "explicit"), (1e-4, "explicit"), (1e-4, "implicit")])
def test_an_fmu_that_cannot_save_its_state_ends_the_run_clearly(make, tolerance, coupling):
    """fmi2GetFMUstate answers fmi2Error (as an FMU with no memory left would): the run ends with a
    SimulationError naming the FMU, the function, the time and what the state was for (here the
    first point's trial of the input derivative orders), not an exception of the FMI layer
    (engine/fmustate.py is the one way the master, the step control and implicit coupling save states)."""
    from emcosim.engine.errors import SimulationError
    with Simulation(loop(make, k=-3.0)) as sim:
        sim.run(stop_time=0.02, tolerance=tolerance, record=["plant.x"], coupling=coupling)   # loaded, works
        refuse = ctypes.CFUNCTYPE(ctypes.c_int, ctypes.c_void_p, ctypes.c_void_p)(lambda component, state: 3)
        sim.instances["plant"].fmu._functions["fmi2GetFMUstate"] = refuse   # fmi2Error (fmpy's raw functions: fmi.raw)
        with pytest.raises(SimulationError, match=r"ToyPlant\w*\.fmu: component 'plant' failed in fmi2GetFMUstate "
                                                  r"at t = 0 s \(the master tries which input derivative orders"):
            sim.run(tolerance=tolerance, record=["plant.x"], coupling=coupling)


def test_an_unreachable_tolerance_stops_at_the_resolution_of_time(fmu_dir, tmp_path, capsys):
    """Issue 26, item 8: `--tolerance 1e-15` on a MEMS scenario. The coupling defects are rounding noise
    (about 2.6e-16) at the level 5e-16 that tolerance asks for, so every step is rejected and shrunk. The step
    control used to go on until t + h == t and hand a step of 0 to fmi2DoStep, which the Reference FMU refused
    ("blaming" it); now it stops at the step that would fall below 4 ulp of the horizon's end, the bound a fixed
    step has (options.experiment), with its own message, and the rows before are kept."""
    from emcosim.cli import main
    from emcosim.engine.errors import SimulationError
    from tests.helpers import scenario

    s = scenario("mems_regulation_Dd0", fmu_dir)
    with pytest.raises(SimulationError) as caught:
        simulate(s, tolerance=1e-15, stop_time=1e-3, record=["plant.q"])
    text = str(caught.value)
    assert "Reference" not in text and "fmi2DoStep" not in text, text
    assert "below the resolution of time near t = 0.001 s" in text and "tolerance 1e-15 cannot be kept" in text

    from emcosim.engine.stepcontrol import StepBelowResolution, resolution
    assert isinstance(caught.value, StepBelowResolution)
    rows = caught.value.result.rows
    assert len(rows) > 1 and all(b[0] > a[0] for a, b in zip(rows, rows[1:]))     # time strictly increases
    assert resolution(0.0, 1e-3) == 4 * np.spacing(1e-3)
    out = tmp_path / "x.csv"
    assert main(["run", "mems_regulation_Dd0", "--fmu-dir", str(fmu_dir), "--tolerance", "1e-15", "--stop-time",
                 "1e-3", "-o", str(out), "--no-progress"]) == 1
    err = capsys.readouterr().err.strip().splitlines()[-1]
    assert err.startswith("emcosim: error: error-controlled steps: the step fell to") and "Reference" not in err
    assert "--tolerance 1e-15 cannot be kept" in err and "give a larger --tolerance" in err
    assert not out.exists() and (tmp_path / "x.partial.csv").is_file()


def test_a_reachable_tight_tolerance_still_runs(fmu_dir):
    """The bound is the resolution of time, not a guess at the tolerance: 1e-13 still runs on the same scenario."""
    from tests.helpers import scenario

    r = simulate(scenario("mems_regulation_Dd0", fmu_dir), tolerance=1e-13, stop_time=1e-3, record=["plant.q"])
    assert r.time[-1] == pytest.approx(1e-3) and r.step_control.estimated_error < 1e-13
