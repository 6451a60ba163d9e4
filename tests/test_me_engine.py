"""The generic Model Exchange engine (emcosim/engine/model_exchange.py) on the C toy FMUs of
tests/fixtures/toy_me.c (tests/toy_me_fmus.py), FMUs the engine did not grow up with.

Independent truths, all closed forms:
- Dahlquist x' = a x + b u in a loop with Gain u = k x: x(t) = x0 exp((a + b k) t); alone (u = 0):
  x0 exp(a t); driven by the Clock's count (a = 0, b = 1): x(t) = sum_n max(0, t - n period).
- The Jacobian of a chain of connections with linear transformations: the product of the partials and
  factors along it.
- BouncingBall h' = v, v' = -g from h0 at rest, v := -e v at h = 0: the bounces at t_1 = sqrt(2 h0 / g),
  t_{n+1} = t_n + 2 e^n t_1, and h, v between them.
The fixtures themselves are checked against an independent host first (fmpy's validation and its CVode
Model Exchange simulation)."""
from __future__ import annotations

import math
import os
import re
import shutil
import signal
import subprocess
import sys
from contextlib import contextmanager
from pathlib import Path

import numpy as np
import pytest

from emcosim.engine import binding, ode, stopping
from emcosim.engine import model_exchange as me
from emcosim.engine.errors import Interrupted, LimitError, OptionError, ScenarioError, SimulationError
from emcosim.engine.master import simulate
from emcosim.engine.options import RunOptions, experiment
from emcosim.engine.outputs import ResultFile, read_sidecar
from emcosim.engine.plan import make_plan
from emcosim.engine.results import partial_note, read_csv
from emcosim.engine.ssd import Component, Connection, Connector, Parameter, Scenario, read_scenario
from emcosim.engine.ssd_writer import parameter_set_xml, system_structure_xml
from tests import toy_fmus, toy_me_fmus

ROOT = Path(__file__).resolve().parents[1]
SOLVERS = ["LSODA", "BDF", "Radau"]
ME = {"interface_type": "ModelExchange"}


@pytest.fixture(scope="session")
def toys(tmp_path_factory) -> dict[str, Path]:
    fmus = toy_me_fmus.fmus(tmp_path_factory.mktemp("toy_me_fmus"))
    if fmus is None:
        pytest.skip("the C Model Exchange toys need gcc")
    return fmus


def connectors(fmu: Path) -> list[Connector]:
    from fmpy import read_model_description
    md = read_model_description(str(fmu))
    return [Connector(v.name, v.causality, v.type) for v in md.modelVariables if v.causality in ("input", "output")]


@pytest.fixture
def make(tmp_path, toys):
    """make(components, connections, parameters, stop_time, step_size, start_time) -> the scenario (read back
    from its folder); components: [(name, toy kind or an .fmu path)]; connections: [(start, end[, factor,
    offset])]; parameters: {component: {name: value}}."""
    def build(components, connections=(), parameters=None, stop_time=1.0, step_size=0.01, start_time=0.0):
        folder = tmp_path / f"s{len(list(tmp_path.iterdir()))}"
        folder.mkdir()
        comps = []
        for name, kind in components:
            fmu = Path(kind) if isinstance(kind, Path) else toys[kind]
            if not (folder / fmu.name).exists():
                shutil.copy(fmu, folder / fmu.name)
            comp = Component(name, folder / fmu.name, connectors=connectors(fmu))
            if parameters and name in parameters:
                (folder / f"{name}.ssv").write_text(parameter_set_xml(
                    name, [Parameter(k, "Real", float(v)) for k, v in parameters[name].items()]))
                comp.parameter_sources = [f"{name}.ssv"]
            comps.append(comp)
        conns = [Connection(*a.split(".") + b.split("."), *rest) for a, b, *rest in connections]
        scenario = Scenario("toy_me", folder / "SystemStructure.ssd", comps, conns, start_time=start_time,
                            stop_time=stop_time)
        (folder / "SystemStructure.ssd").write_text(
            system_structure_xml(scenario, {c.name: c.source.name for c in comps}, step_size))
        return read_scenario(folder)
    return build


# ---- the fixtures against an independent host --------------------------------------------------------
def test_fixtures_are_valid_and_fmpy_reproduces_the_bounces(toys):
    from fmpy import simulate_fmu
    from fmpy.validation import validate_fmu

    for kind, fmu in toys.items():
        assert validate_fmu(str(fmu)) == [], kind
    r = simulate_fmu(str(toys["BouncingBall"]), fmi_type="ModelExchange", stop_time=2.0, output_interval=1e-3,
                     start_values={"e": 0.8}, relative_tolerance=1e-8)
    v = r["v"]
    bounces = r["time"][np.flatnonzero((v[:-1] < 0) & (v[1:] > 0))]       # fmpy records both sides of an event
    np.testing.assert_allclose(bounces, bounce_times(9.81, 0.8, 1.0, 2.0), atol=1e-6)


# ---- Dahlquist ------------------------------------------------------------------------------------------
LOOP = dict(components=[("d", "Dahlquist"), ("g", "Gain"), ("f", "Dahlquist")],
            connections=[("d.x", "g.u"), ("g.y", "d.u")])
LOOP_PARAMETERS = {"d": {"a": -0.5, "b": 1.0, "x0": 2.0}, "g": {"k": -1.5},    # x' = -2 x
                   "f": {"a": -1e4, "x0": 1.0, "nominal": 1e-3}}                # alone: stiff, x' = -1e4 x


def loop_errors(r) -> tuple[float, float]:
    """The loop's and the stiff Dahlquist's largest errors against the closed forms, relative to their
    largest magnitudes."""
    return (float(np.max(np.abs(r["d.x"] - 2 * np.exp(-2 * r.time))) / 2),
            float(np.max(np.abs(r["f.x"] - np.exp(-1e4 * r.time)))))


@pytest.mark.parametrize("solver", SOLVERS)
def test_dahlquist_loop_and_alone_with_exact_jacobian(make, solver):
    """The loop x' = (a + b k) x beside a stiff Dahlquist alone (so that LSODA turns to its stiff method
    and asks for Jacobians), each against its closed form at rtol 1e-7; the Jacobians come from the FMUs'
    directional derivatives. A Dahlquist FMU that does not declare them makes the solver take finite
    differences, with the same answer."""
    rtol = 1e-7
    r = simulate(make(**LOOP, parameters=LOOP_PARAMETERS, stop_time=2.0), **ME, solver=solver, rtol=rtol,
                 record=["d.x", "g.y", "f.x"])
    loop, alone = loop_errors(r)
    assert loop < 20 * rtol and alone < 20 * rtol, (loop, alone)
    np.testing.assert_allclose(r["g.y"], -1.5 * r["d.x"], rtol=1e-15)
    stats = r.model_exchange
    assert stats.solver == solver and stats.exact_jacobian and stats.jacobians > 0, stats.summary()

    fd = dict(LOOP, components=[("d", "Dahlquist"), ("g", "Gain"), ("f", "DahlquistFD")])
    r_fd = simulate(make(**fd, parameters=LOOP_PARAMETERS, stop_time=2.0), **ME, solver=solver, rtol=rtol,
                    record=["d.x", "g.y", "f.x"])
    assert not r_fd.model_exchange.exact_jacobian and r_fd.model_exchange.jacobians == 0
    loop_fd, alone_fd = loop_errors(r_fd)
    assert loop_fd < 20 * rtol and alone_fd < 20 * rtol, (loop_fd, alone_fd)
    np.testing.assert_allclose(r_fd["d.x"], r["d.x"], rtol=0, atol=20 * rtol)


@pytest.mark.parametrize("tolerance", [1e-3, 1e-5])
def test_tolerance_keeps_the_global_error(make, tolerance):
    """tolerance=T: two or three solves whose result keeps the recorded variables' error (relative to their
    largest magnitude) within T."""
    r = simulate(make(**LOOP, parameters=LOOP_PARAMETERS, stop_time=2.0), **ME, tolerance=tolerance,
                 record=["d.x", "f.x"])
    loop, alone = loop_errors(r)
    assert loop <= tolerance and alone <= tolerance, (loop, alone)
    stats = r.model_exchange
    assert stats.tolerance == tolerance and stats.solves in (2, 3) and stats.estimated_error <= tolerance


def test_rows_on_the_grid_or_at_the_solver_steps(make):
    """Rows at t0 + n h (never an accumulated t += h) up to the stop time; with solver_steps one row at the
    start and one at every accepted step, each on the closed form."""
    t0, h, t_stop = 0.25, 0.1, 1.0
    scenario = make(**LOOP, parameters=LOOP_PARAMETERS, start_time=t0, stop_time=t_stop, step_size=h)
    r = simulate(scenario, **ME, rtol=1e-8, record=["d.x"])
    expected = [t0 + n * h for n in range(8)] + [t_stop]
    assert r.time.tolist() == expected
    np.testing.assert_allclose(r["d.x"], 2 * np.exp(-2 * (r.time - t0)), rtol=1e-6)

    steps = simulate(scenario, **ME, rtol=1e-8, record=["d.x"], solver_steps=True)
    assert len(steps) == steps.model_exchange.steps + 1
    assert steps.time[0] == t0 and steps.time[-1] == t_stop and np.all(np.diff(steps.time) > 0)
    assert not set(steps.time[1:-1]) & set(expected)
    np.testing.assert_allclose(steps["d.x"], 2 * np.exp(-2 * (steps.time - t0)), rtol=1e-6)


# ---- the assembled Jacobian -----------------------------------------------------------------------------
@contextmanager
def system_at(scenario):
    """A model_exchange.System of the scenario's FMUs, initialized and in continuous-time mode."""
    with me.ModelExchangeSimulation(scenario) as sim:
        plan = make_plan(scenario, sim.instances, sim.connections, None)
        system = ode.System(scenario, sim.instances, sim.connections, plan)
        system.statistics = ode.Statistics("BDF", 1e-6)
        options = RunOptions(interface_type="ModelExchange")
        me.initialize(system, binding.parameter_values(scenario, sim.instances, {}), experiment(scenario, options),
                       1e-6)
        yield system


def fd_jacobian(system, t: float, xi: np.ndarray) -> np.ndarray:
    J = np.empty((system.n, system.n))
    for j in range(system.n):
        e = np.zeros(system.n)
        e[j] = 1e-6 * max(1.0, abs(xi[j]))
        J[:, j] = (system.rhs(t, xi + e) - system.rhs(t, xi - e)) / (2 * e[j])
    return J


def test_jacobian_through_factors_and_a_feedthrough_chain(make):
    """d1.x -(factor 2.5, offset 0.3)-> g1 -> g2 -(factor -0.7)-> d2.u and d2.x -(factor 1.5)-> d1.u:
    dF/dx = [[a1, b1 1.5], [b2 (-0.7) k2 k1 2.5, a2]], in states scaled by the nominals (2 and 0.5):
    J_ij s_j / s_i. The engine's Jacobian equals it and a finite-difference Jacobian of its right-hand
    side."""
    p = {"d1": {"a": -0.3, "b": 0.8, "x0": 1.2, "nominal": 2.0}, "d2": {"a": -2.0, "b": 1.7, "x0": -0.4, "nominal": 0.5},
         "g1": {"k": 3.0}, "g2": {"k": -1.25}}
    scenario = make([("d1", "Dahlquist"), ("g1", "Gain"), ("g2", "Gain"), ("d2", "Dahlquist")],
                    [("d1.x", "g1.u", 2.5, 0.3), ("g1.y", "g2.u"), ("g2.y", "d2.u", -0.7), ("d2.x", "d1.u", 1.5)], p)
    J = np.array([[-0.3, 0.8 * 1.5], [1.7 * -0.7 * -1.25 * 3.0 * 2.5, -2.0]])
    s = np.array([2.0, 0.5])
    with system_at(scenario) as system:
        assert system.jacobian_plan is not None and system.n == 2
        np.testing.assert_array_equal(system.scale, s)
        t, xi = 0.3, np.array([0.7, -1.9])
        assembled = system.jacobian(t, xi)
        np.testing.assert_allclose(assembled, J * s[None, :] / s[:, None], rtol=1e-14)
        np.testing.assert_allclose(assembled, fd_jacobian(system, t, xi), rtol=1e-8)
        x = xi * s                                          # the right-hand side itself, through the offset
        u2 = -0.7 * (-1.25 * (3.0 * (2.5 * x[0] + 0.3)))
        np.testing.assert_allclose(system.rhs(t, xi) * s, [-0.3 * x[0] + 0.8 * 1.5 * x[1], -2.0 * x[1] + 1.7 * u2],
                                   rtol=1e-14)


def test_buffered_resolution_equals_the_transfers_and_rows_make_only_the_calls_they_need(make):
    """The chain of the test above resolved through the numpy slot buffer (ode._Buffers: gets into it, sets
    from it by address, the transformed ones gathered) and through the plan's transfers (plan.resolve_values,
    the general path): the same right-hand sides, Jacobians and rows, bit for bit, at points the solver
    would visit, and again at a point already set. Recording d1.x, g1.y and d2.u, a row leaves out the get
    of d2.x and the set of d1.u (d1.x is read before it, and no recorded value needs d2.x): 2 of 8 calls."""
    p = {"d1": {"a": -0.3, "b": 0.8, "x0": 1.2, "nominal": 2.0}, "d2": {"a": -2.0, "b": 1.7, "x0": -0.4, "nominal": 0.5},
         "g1": {"k": 3.0}, "g2": {"k": -1.25}}
    scenario = make([("d1", "Dahlquist"), ("g1", "Gain"), ("g2", "Gain"), ("d2", "Dahlquist")],
                    [("d1.x", "g1.u", 2.5, 0.3), ("g1.y", "g2.u"), ("g2.y", "d2.u", -0.7), ("d2.x", "d1.u", 1.5)], p)
    points = [(0.3, np.array([0.7, -1.9])), (0.4, np.array([-0.2, 0.05])), (0.4, np.array([-0.2, 0.05])),
              (0.5, np.array([1e3, 3.0]))]
    seen = []
    for buffered in (True, False):
        with me.ModelExchangeSimulation(scenario) as sim:
            plan = make_plan(scenario, sim.instances, sim.connections, ["d1.x", "g1.y", "d2.u"])
            system = ode.System(scenario, sim.instances, sim.connections, plan, buffered=buffered)
            system.statistics = ode.Statistics("BDF", 1e-6)
            me.initialize(system, binding.parameter_values(scenario, sim.instances, {}),
                          experiment(scenario, RunOptions(interface_type="ModelExchange")), 1e-6)
            values = []
            for t, xi in points:
                system.set_point(t, xi, record=True)
                values.append((system.rhs(t, xi), system.jacobian(t, xi), system.row()))
                system.set_point(t + 0.01, xi + 1.0, record=True)
                values.append(system.row())
            seen.append(values)
            if buffered:
                assert isinstance(system.values, ode._Buffers)
                # steps: the calls, and before each transformed set its gather
                assert [(step[3].inst.name, step[3].getter) for step in system.values.row_steps] == [
                    ("d1", True), ("g1", False), ("g1", False), ("g1", True), ("g2", False), ("g2", True),
                    ("d2", False), ("d2", False)]
                assert len(system.values.connected) == 11
    for a, b in zip(*seen):
        for x, y in zip(a if isinstance(a, tuple) else (a,), b if isinstance(b, tuple) else (b,)):
            np.testing.assert_array_equal(x, y)


def test_only_fmus_that_ask_for_it_get_completed_integrator_step(make):
    """fmi2CompletedIntegratorStep goes to the FMUs whose completedIntegratorStepNotNeeded is false (the ball),
    not to those that declare it true (Dahlquist, Gain), as their modelDescription.xml says; fmpy's reader
    leaves that attribute false for every FMI 2.0 FMU (ode.needs_completed_step)."""
    import zipfile
    scenario = make([("b", "BouncingBall"), ("d", "Dahlquist"), ("g", "Gain")], [("d.x", "g.u"), ("g.y", "d.u")])
    declared = {}
    for c in scenario.components:
        with zipfile.ZipFile(c.source) as z:
            xml = z.read("modelDescription.xml").decode()
        declared[c.name] = re.search(r'completedIntegratorStepNotNeeded="(\w+)"', xml).group(1)
    assert declared == {"b": "false", "d": "true", "g": "true"}
    with system_at(scenario) as system:
        assert [u.inst.name for u in system.step_reporters] == ["b"]


# ---- events ---------------------------------------------------------------------------------------------
def bounce_times(g: float, e: float, h0: float, t_stop: float) -> list[float]:
    t1 = math.sqrt(2 * h0 / g)
    times, t, n = [], t1, 0
    while t < t_stop:
        times.append(t)
        n += 1
        t += 2 * e ** n * t1
    return times


def ball_truth(t: np.ndarray, g: float, e: float, h0: float) -> tuple[np.ndarray, np.ndarray]:
    """h and v at times t (after the bounce at a bounce time)."""
    bounces = np.array(bounce_times(g, e, h0, float(np.max(t)) + 1.0))
    n = np.searchsorted(bounces, t, side="right")          # bounces so far
    start = np.where(n == 0, 0.0, bounces[np.maximum(n - 1, 0)])
    v_start = np.where(n == 0, 0.0, e ** n * g * bounces[0])
    h_start = np.where(n == 0, h0, 0.0)
    s = t - start
    return h_start + v_start * s - g / 2 * s ** 2, v_start - g * s


@pytest.mark.parametrize("solver", SOLVERS)
def test_bouncing_ball_bounces_at_the_closed_form_times(make, solver):
    g, e, h0, t_stop = 9.81, 0.8, 1.0, 2.0
    truth = bounce_times(g, e, h0, t_stop)
    assert len(truth) == 3
    scenario = make([("b", "BouncingBall")], [], {"b": {"g": g, "e": e, "h0": h0}}, stop_time=t_stop)
    steps = simulate(scenario, **ME, solver=solver, rtol=1e-9, record=["b.h", "b.v"], solver_steps=True)
    v = steps["b.v"]
    falling = np.flatnonzero((v[:-1] < 0) & (v[1:] > 0))   # the row at a bounce holds the values before it
    np.testing.assert_allclose(steps.time[falling], truth, rtol=0, atol=3e-6)
    np.testing.assert_allclose(steps["b.h"][falling], 0.0, atol=1e-9)
    assert steps.model_exchange.events == len(truth), steps.model_exchange.summary()

    r = simulate(scenario, **ME, solver=solver, rtol=1e-9, record=["b.h", "b.v"])
    h, v = ball_truth(r.time, g, e, h0)
    np.testing.assert_allclose(r["b.h"], h, rtol=0, atol=3e-5)
    np.testing.assert_allclose(r["b.v"], v, rtol=0, atol=3e-5)
    assert np.all(r["b.h"] >= -1e-9)                       # restarted at every bounce, never below the floor


def test_terminate_simulation_ends_the_run_keeping_the_rows(make):
    """v_min = 3: the first bounce leaves 0.8 * 4.43 = 3.54 m/s, the second 2.83 m/s < v_min, and the FMU
    asks to terminate there."""
    g, e, h0 = 9.81, 0.8, 1.0
    t2 = bounce_times(g, e, h0, 2.0)[1]
    scenario = make([("b", "BouncingBall")], [], {"b": {"g": g, "e": e, "h0": h0, "v_min": 3.0}}, stop_time=2.0)
    with pytest.raises(SimulationError, match=r"ToyMEBouncingBall\.fmu: component 'b' asked to terminate") as info:
        simulate(scenario, **ME, rtol=1e-9, record=["b.h", "b.v"])
    assert abs(event_time(info.value) - t2) < 3e-6
    rows = info.value.result
    assert rows.time[-1] < t2 < rows.time[-1] + 0.01 + 1e-12
    h, _ = ball_truth(rows.time, g, e, h0)
    np.testing.assert_allclose(rows["b.h"], h, atol=3e-5)


def event_time(exc: Exception) -> float:
    return float(re.search(r"at t = ([-+0-9.e]+) s", str(exc)).group(1))


@pytest.mark.parametrize("solver", SOLVERS)
def test_time_events_step_the_clock_at_their_times(make, solver):
    """Clock.count -> Dahlquist.u (a = 0, b = 1): count steps by one at every 0.25 s (nextEventTime), and
    x(t) = sum_n max(0, t - 0.25 n). A row at an event's time holds the values after it (as a
    Co-Simulation step to that time gives them)."""
    period, h = 0.25, 0.05
    scenario = make([("c", "Clock"), ("d", "Dahlquist")], [("c.count", "d.u")],
                    {"c": {"period": period}, "d": {"a": 0.0, "b": 1.0, "x0": 0.0}}, stop_time=1.0, step_size=h)
    r = simulate(scenario, **ME, solver=solver, rtol=1e-8, record=["c.count", "d.x"])
    t = r.time
    np.testing.assert_array_equal(r["c.count"], np.floor(np.round(t / period, 9)))
    before, after = np.flatnonzero(np.isclose(t, 0.5 - h)), np.flatnonzero(np.isclose(t, 0.5 + h))
    assert r["c.count"][before] == 1 and r["c.count"][after] == 2
    np.testing.assert_allclose(r["d.x"], sum(np.maximum(0.0, t - period * n) for n in range(1, 5)), atol=1e-7)
    assert r.model_exchange.events == 4                      # 0.25, 0.5, 0.75 and the stop time


def test_a_clock_alone_has_no_states(make):
    r = simulate(make([("c", "Clock")], [], {"c": {"period": 0.3}}, stop_time=1.0, step_size=0.1), **ME,
                 record=["c.count"])
    np.testing.assert_array_equal(r["c.count"], [0, 0, 0, 1, 1, 1, 2, 2, 2, 3, 3])


# ---- failures -------------------------------------------------------------------------------------------
def test_fmu_error_in_derivatives_ends_the_run_with_the_rows(make):
    scenario = make([("f", "Faulty")], [], {"f": {"a": -1.0, "x0": 1.0, "fail_at": 0.5}})
    with pytest.raises(SimulationError) as info:
        simulate(scenario, **ME, record=["f.y"])
    message = str(info.value)
    assert "ToyMEFaulty.fmu: component 'f' failed in fmi2GetDerivatives" in message
    assert "fmi2GetDerivatives fails at t = " in message                # the FMU's own logged message
    assert 0.5 <= event_time(info.value) < 0.6
    rows = info.value.result
    assert rows is not None and 0.4 < rows.time[-1] < 0.5
    np.testing.assert_allclose(rows["f.y"], np.exp(-rows.time), rtol=1e-5)


def test_nan_output_ends_the_run_naming_the_variable(make):
    scenario = make([("f", "Faulty"), ("g", "Gain")], [("f.y", "g.u")], {"f": {"nan_at": 0.3}})
    with pytest.raises(SimulationError, match=r"f\.y = nan at t = .*ToyMEFaulty\.fmu \(component 'f'\) returned a "
                                              r"value that is not finite") as info:
        simulate(scenario, **ME, record=["f.y", "g.y"])
    assert 0.3 <= event_time(info.value) < 0.4
    rows = info.value.result
    assert 0.2 < rows.time[-1] < 0.3 and np.all(np.isfinite(rows["g.y"]))


def test_cli_failure_leaves_a_partial_file(make, tmp_path):
    scenario = make([("f", "Faulty")], [], {"f": {"fail_at": 0.5}})
    out = tmp_path / "out.csv"
    env = dict(os.environ, PYTHONPATH=str(ROOT))                       # this worktree's emcosim
    run = subprocess.run([sys.executable, "-m", "emcosim.cli", "run", str(scenario.path.parent), "--interface-type",
                          "ModelExchange", "-o", str(out), "--no-progress"], check=False, capture_output=True, text=True,
                         cwd=tmp_path, env=env, timeout=120)
    assert run.returncode == 1, run.stderr
    assert "ToyMEFaulty.fmu: component 'f' failed in fmi2GetDerivatives" in run.stderr
    partial = tmp_path / "out.partial.csv"
    assert partial.is_file() and not out.exists()
    lines = partial.read_text().splitlines()                          # issue 41: the header first, why beside
    assert lines[0] == "time,f.y" and not any(line.startswith("#") for line in lines)
    assert "fmi2GetDerivatives" in partial_note(partial) and read_sidecar(partial)["status"] == "partial"
    with pytest.raises(SimulationError) as info:                      # the same rows as the API keeps
        simulate(scenario, **ME, record=["f.y"])
    kept = read_csv(partial)
    assert len(kept["time"]) == len(info.value.result) > 10
    np.testing.assert_array_equal(kept["time"], info.value.result.time)
    np.testing.assert_array_equal(kept["f.y"], info.value.result["f.y"])


# ---- refused FMUs -----------------------------------------------------------------------------------------
def test_interfaces_are_refused_naming_the_fmu(make, tmp_path):
    """A Co-Simulation-only FMU (the C toys of tests/toy_fmus.py) in a Model Exchange run, and a Model-
    Exchange-only one in a Co-Simulation run."""
    lib = toy_fmus.compile_library(tmp_path)
    cs = toy_fmus.build(tmp_path, lib, "static", "ToyStaticCS")
    scenario = make([("d", "Dahlquist"), ("ctrl", cs)], [("d.x", "ctrl.u1"), ("ctrl.y", "d.u")])
    with pytest.raises(ScenarioError, match=r"ToyStaticCS\.fmu: component 'ctrl' is a Co-Simulation-only FMU"):
        simulate(scenario, **ME)
    with pytest.raises(ScenarioError, match=r"ToyMEDahlquist\.fmu: component 'd' is a Model-Exchange-only FMU"):
        simulate(scenario)


@pytest.mark.parametrize("solver", SOLVERS)
def test_the_plants_boundary_is_the_reason_given_when_the_controller_fails_there(fmu_dir, solver):
    """The MEMS loop driven into the closed gap (p_0 = -2.35e-8 N s, the gap closes at 1.648e-5 s). Radau's
    stages reach q = -c0 before the step's event indicators are compared, and the controller's law (a
    division by q + c0) fails there: the run must still end with the plant's reason, the gap, and keep
    the controller's failure as what came before it. Without the diagnosis Radau named only the controller."""
    from tests.helpers import scenario
    s = scenario("mems_regulation_Dd-1", fmu_dir)
    with pytest.raises(SimulationError) as info:
        simulate(s, start_values={"plant.p_0": -2.35e-8}, interface_type="ModelExchange", solver=solver, rtol=1e-9)
    message = str(info.value)
    if solver == "Radau" and message.startswith("Model Exchange: Radau failed"):
        # Radau's stages hover within 1e-19 m of q = -c0 (x_e ~ 1e-24 C); the controller's law fails only where
        # a stage lands exactly on it, a coincidence of rounding: it did with the hand-written law (one of 9688
        # evaluations), not with the law printed from components/laws.py (none of 9890; both logged, issue 32).
        # Otherwise Radau's step size underflows there, which is the boundary's time too.
        assert "Required step size is less than spacing between numbers" in message, message
    else:
        assert message.startswith("MEMS.fmu: component 'plant'") and "the capacitor gap has closed" in message, message
    t = float(re.search(r"at t = ([0-9.e+-]+) s", message).group(1))
    assert abs(t - 1.6479e-5) < 1e-9, message
    assert info.value.result is not None and info.value.result.rows[0][0] == 0.0


# ---- bounded, stoppable runs (issue 31) ---------------------------------------------------------------
@pytest.mark.parametrize("kwargs, words", [
    ({"rtol": 1e-300}, "rtol 1e-300: below 1e-13"),
    ({"rtol": 5e-14}, "rtol 5e-14: below 1e-13"),
    ({"tolerance": 1e-15}, "tolerance 1e-15: a Model Exchange run cannot keep a global error below 1e-11"),
    ({"tolerance": 9e-12}, "tolerance 9e-12: a Model Exchange run cannot keep a global error below 1e-11"),
])
def test_tolerances_the_solvers_cannot_resolve_are_refused(kwargs, words):
    """scipy's solvers raise an rtol below 2.2e-14 to that but keep atol = rtol: at 1e-300 the solve never
    left t = 0. A tolerance's solves run down to tolerance / 100. The smallest values still pass, and a
    Co-Simulation run keeps its own rule for a tolerance (refused when its steps fall below the resolution)."""
    with pytest.raises(OptionError, match=re.escape(words)) as info:
        RunOptions(**ME, **kwargs)
    assert info.value.options[0] == next(iter(kwargs))
    RunOptions(**ME, rtol=1e-13)
    RunOptions(**ME, tolerance=1e-11)
    RunOptions(tolerance=1e-15)


@pytest.mark.parametrize("solver", SOLVERS)
def test_a_stop_request_ends_the_solve_at_the_next_evaluation(make, solver, monkeypatch):
    """A signal's request (what stopping's handler records) in the middle of a solve, with no row to record
    until the stop time: the run ends with Interrupted at the next right-hand side, not at the next row;
    the row at t0 is kept. LSODA calls the right-hand side from Fortran: the stop crosses it."""
    monkeypatch.setattr(stopping, "_requested", None)
    calls = {"n": 0, "after": 0}
    rhs = ode.System.rhs

    def counted(self, t, xi):
        calls["n"] += 1
        if calls["n"] > 20:
            calls["after"] += 1
        out = rhs(self, t, xi)
        if calls["n"] == 20:
            stopping._requested = signal.SIGINT
        return out
    monkeypatch.setattr(ode.System, "rhs", counted)
    scenario = make(**LOOP, parameters=LOOP_PARAMETERS, stop_time=2.0, step_size=2.0)
    with pytest.raises(Interrupted) as info:
        simulate(scenario, **ME, solver=solver, rtol=1e-10, record=["d.x"])
    assert info.value.signal == signal.SIGINT
    assert calls["after"] <= 1, calls                       # at most the call that found the request
    assert info.value.result.time.tolist() == [0.0]


def test_an_fmu_failing_after_a_stop_request_ends_the_run_as_stopped(make, monkeypatch):
    """A second Ctrl-C raised inside a Python FMU comes back as that FMU's error. Once a stop was asked for,
    an FMU's failure ends the run as Interrupted (exit 130/143 on the command line), with the rows so far.
    Here the request is never looked at (check disabled) and the FMU fails at t = 0.5."""
    monkeypatch.setattr(stopping, "_requested", signal.SIGTERM)
    monkeypatch.setattr(stopping, "check", lambda: None)
    scenario = make([("f", "Faulty")], [], {"f": {"fail_at": 0.5}})
    with pytest.raises(Interrupted) as info:
        simulate(scenario, **ME, record=["f.y"])
    assert info.value.signal == signal.SIGTERM and "interrupted by SIGTERM" in str(info.value)
    assert isinstance(info.value.__cause__, SimulationError) and "fmi2GetDerivatives" in str(info.value.__cause__)
    assert 0.4 < info.value.result.time[-1] < 0.5


def test_the_grid_and_the_solver_steps_are_limited_like_communication_steps(make):
    """max_steps bounds a Model Exchange run as it bounds a Co-Simulation one: the rows of its grid up
    front (before anything is loaded), the steps of each solve as it goes (with solver_steps, one row each),
    the rows so far kept."""
    scenario = make(**LOOP, parameters=LOOP_PARAMETERS, stop_time=2.0)
    with pytest.raises(LimitError, match=r"makes 2e\+09 recorded rows \(communication points\), more than the limit "
                                         r"of 1e\+08; give max_steps 2000000000") as info:
        experiment(scenario, RunOptions(**ME, stop_time=2e7, step_size=0.01))
    assert info.value.option == "max_steps"
    experiment(scenario, RunOptions(**ME, stop_time=2e7, step_size=0.01, solver_steps=True))   # counted as it runs
    with pytest.raises(me.RunLimit, match=r"took more than 40 steps and reached t = .* of 2 s; give a larger "
                                          r"max_steps") as limited:
        simulate(scenario, **ME, rtol=1e-10, solver_steps=True, max_steps=40, record=["d.x"])
    assert "--max-steps" in limited.value.describe({"max_steps": "--max-steps"})
    rows = limited.value.result
    assert len(rows) == 41 and rows.time[-1] < 2.0
    np.testing.assert_allclose(rows["d.x"], 2 * np.exp(-2 * rows.time), rtol=1e-7)
    coarse = make(**LOOP, parameters=LOOP_PARAMETERS, stop_time=2.0, step_size=1.0)     # 3 rows, many steps
    with pytest.raises(me.RunLimit, match="took more than 40 steps"):
        simulate(coarse, **ME, rtol=1e-10, max_steps=40, record=["d.x"])
    assert simulate(coarse, **ME, rtol=1e-10, max_steps=10**4, record=["d.x"]).model_exchange.steps > 40


def test_a_tolerance_run_streams_every_solve_and_keeps_the_rows_of_a_failing_one(make, tmp_path):
    """With a results file (the command line's sink) every solve of a tolerance run writes its rows as they
    come, none held: a complete run gives the same rows as the in-memory one, and a plant that fails in the
    first solve leaves the rows before the failure in NAME.partial.csv (there were none before)."""
    scenario = make(**LOOP, parameters=LOOP_PARAMETERS, stop_time=2.0)
    memory = simulate(scenario, **ME, tolerance=1e-5, record=["d.x", "f.x"])
    out = tmp_path / "r.csv"
    with ResultFile(out) as sink:
        streamed = simulate(scenario, **ME, tolerance=1e-5, record=["d.x", "f.x"], sink=sink)
    assert streamed.rows == [] and streamed.model_exchange.solves == memory.model_exchange.solves
    data = read_csv(out)
    np.testing.assert_array_equal(data["time"], memory.time)
    np.testing.assert_array_equal(data["d.x"], memory["d.x"])

    faulty = make([("f", "Faulty")], [], {"f": {"fail_at": 0.5}})
    out = tmp_path / "f.csv"
    with pytest.raises(SimulationError, match="fmi2GetDerivatives"):
        with ResultFile(out) as sink:
            simulate(faulty, **ME, tolerance=1e-4, record=["f.y"], sink=sink)
    kept = read_csv(tmp_path / "f.partial.csv")
    assert not out.exists() and 0.4 < kept["time"][-1] < 0.5 and len(kept["time"]) > 40
    np.testing.assert_allclose(kept["f.y"], np.exp(-kept["time"]), rtol=1e-4)


@pytest.mark.parametrize("args, words", [
    (["--rtol", "1e-300"], "--rtol 1e-300: below 1e-13, the smallest relative tolerance the solvers resolve"),
    (["--tolerance", "1e-15"], "--tolerance 1e-15: a Model Exchange run cannot keep a global error below 1e-11"),
])
def test_cli_refuses_tolerances_the_solvers_cannot_resolve(make, tmp_path, args, words):
    """`emcosim run --interface-type ModelExchange --rtol 1e-300` never ended (the solver stayed at t = 0);
    `--tolerance 1e-15` exited 0 with an estimated error far above it. Both: exit 1 in one line naming the
    flag, before anything runs."""
    scenario = make(**LOOP, parameters=LOOP_PARAMETERS, stop_time=2.0)
    out = tmp_path / "out.csv"
    env = dict(os.environ, PYTHONPATH=str(ROOT))
    run = subprocess.run([sys.executable, "-m", "emcosim.cli", "run", str(scenario.path.parent), "--interface-type",
                          "ModelExchange", "-o", str(out), "--no-progress", *args], check=False, capture_output=True,
                         text=True, cwd=tmp_path, env=env, timeout=60)
    assert run.returncode == 1, run.stderr
    lines = run.stderr.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith(f"emcosim: error: {words}"), run.stderr
    assert not out.exists() and list(tmp_path.glob("out*")) == []


def test_a_tolerance_run_whose_temporary_file_fills_the_disk_says_so(make, monkeypatch):
    """The first solve's rows wait on a temporary file: a full disk there (the file's write failing with
    ENOSPC after 10 rows) ends the run with a SimulationError naming the folder and the rows so far, not
    an OSError from inside the engine."""
    import errno
    import io
    import tempfile

    class Full(io.BytesIO):
        def write(self, data) -> int:
            if self.tell() >= 10 * len(data):
                raise OSError(errno.ENOSPC, "No space left on device")
            return super().write(data)
    monkeypatch.setattr(me.tempfile, "TemporaryFile", Full)
    scenario = make(**LOOP, parameters=LOOP_PARAMETERS, stop_time=2.0)
    with pytest.raises(SimulationError, match=f"cannot keep the first solve's rows for the error estimate in a "
                                              f"temporary file in {re.escape(tempfile.gettempdir())}: No space left "
                                              f"on device") as info:
        simulate(scenario, **ME, tolerance=1e-4, record=["d.x"])
    assert len(info.value.result) == 11


def test_outputs_that_are_states_are_read_from_the_state_vector_and_only_those(make, toys, monkeypatch):
    """An output whose value reference is a continuous state (<Derivatives>' derivative attribute points at
    it: Dahlquist's x, the ball's h and v) is the state the solver set: a row takes it from the state vector
    and calls only the FMUs its other values need (recording d.x and g.y of the loop: the Gain, not the
    Dahlquist). Faulty's y equals its state x but is not declared as one: it is read by fmi2GetReal, so
    its NaN from nan_at on ends the run at a row. The rows equal, bit for bit, those of the same run with
    every output read by fmi2GetReal (state_references emptied)."""
    from fmpy import read_model_description
    declared = {kind: sorted(v for v, _ in ode.state_references(read_model_description(str(fmu))).items())
                for kind, fmu in (("d", toys["Dahlquist"]), ("b", toys["BouncingBall"]),
                                  ("f", toys["Faulty"]), ("g", toys["Gain"]))}
    md = {kind: read_model_description(str(toys[name])) for kind, name in (("d", "Dahlquist"),
                                                                               ("b", "BouncingBall"), ("f", "Faulty"))}
    names = {k: sorted(v.name for v in md[k].modelVariables if v.valueReference in declared[k] and v.type == "Real")
             for k in md}
    assert names == {"d": ["x"], "b": ["h", "v"], "f": ["x"]} and declared["g"] == []      # Faulty's y: not a state

    scenario = make(**LOOP, parameters=LOOP_PARAMETERS, stop_time=1.0, step_size=0.01)
    records = (["d.x", "g.y"], ["f.x", "g.y", "d.x"])     # the states' slots one after the other, or not
    with me.ModelExchangeSimulation(scenario) as sim:
        for record, consecutive in zip(records, (True, False)):
            plan = make_plan(scenario, sim.instances, sim.connections, record)
            values = ode.System(scenario, sim.instances, sim.connections, plan).values
            assert values.row_units == {"g"} and (values.row_states is not None) == consecutive
    fast = [simulate(scenario, **ME, solver=solver, rtol=1e-6, record=record) for record in records
            for solver in ("LSODA", "Radau")]
    monkeypatch.setattr(ode, "state_references", lambda md, offset=0: {})
    slow = [simulate(scenario, **ME, solver=solver, rtol=1e-6, record=record) for record in records
            for solver in ("LSODA", "Radau")]
    for a, b in zip(fast, slow):
        np.testing.assert_array_equal(np.array(a.rows), np.array(b.rows))
    monkeypatch.undo()

    faulty = make([("f", "Faulty")], [], {"f": {"nan_at": 0.305}})
    with pytest.raises(SimulationError, match=r"f\.y = nan at t = ") as info:
        simulate(faulty, **ME, record=["f.y"])
    assert 0.305 <= event_time(info.value) < 0.32


def test_lsoda_dense_output_is_scipys_and_steps_aside_when_it_differs(monkeypatch):
    """model_exchange._LSODA's dense output (the Nordsieck sum without scipy's DenseOutput object) equals
    scipy's LSODA's, bit for bit, at arrays of times and at a scalar, over the steps of a stiff and an
    oscillating problem; where it would differ (a scipy whose internals moved: here a history scaled by
    1 + 1e-9), the first comparison turns it off and the solve gets scipy's own."""
    from scipy.integrate import LSODA

    def f(t, y):
        return np.array([y[1], -y[0] - 0.1 * y[1], -1e3 * (y[2] - np.cos(t))])
    for trusted in (True, False):
        if not trusted:
            nordsieck = me._LSODA._nordsieck
            monkeypatch.setattr(me._LSODA, "_nordsieck", lambda self: _scaled(nordsieck(self)))
        ours, theirs = me._LSODA(f, 0.0, np.array([1.0, 0.0, 0.0]), 10.0, rtol=1e-6, atol=1e-9), \
            LSODA(f, 0.0, np.array([1.0, 0.0, 0.0]), 10.0, rtol=1e-6, atol=1e-9)
        for _ in range(60):
            ours.step()
            theirs.step()
            times = np.linspace(theirs.t_old, theirs.t, 7)[1:]
            mine, scipys = ours.dense_output(), theirs.dense_output()
            np.testing.assert_array_equal(mine(times), scipys(times))
            np.testing.assert_array_equal(mine(float(times[2])), scipys(float(times[2])))
        assert ours._trusted is trusted


def _scaled(dense):
    dense.yh *= 1 + 1e-9
    return dense
