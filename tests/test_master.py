"""The co-simulation master on toy FMUs (tests/fixtures): a static gain y = k x with direct
feedthrough and an integrator x' = u. With k = -1 the loop is x' = -x, x(0) = x0, whose exact
solution e^-t and exact discrete recursions (ours: x_{n+1} = (1 - h) x_n; Jacobi:
x_{n+1} = x_n - h x_{n-1}) are the independent truths."""
from __future__ import annotations

import io
import subprocess
import sys
import zipfile
from pathlib import Path

import numpy as np
import pytest

from emcosim.cli import main
from emcosim.engine import dependencies
from emcosim.engine.errors import ScenarioError, SimulationError
from emcosim.engine.master import simulate
from emcosim.engine.results import read_csv
from emcosim.engine.ssd import Component, Connection, Connector, Parameter, Scenario, read_scenario
from emcosim.engine.ssd_writer import parameter_set_xml, system_structure_xml
from emcosim.engine.ssp import pack_ssp
from emcosim.progress import ProgressBar

FIXTURES = Path(__file__).parent / "fixtures"
GAIN = [Connector("x", "input", "Real"), Connector("y", "output", "Real")]
INTEGRATOR = [Connector("u", "input", "Real"), Connector("x", "output", "Real")]


@pytest.fixture(scope="session")
def toy_fmus(tmp_path_factory) -> dict[str, Path]:
    out = tmp_path_factory.mktemp("toy_fmus")
    for script in ("emcosim_toy_gain.py", "emcosim_toy_integrator.py"):
        subprocess.run([sys.executable, "-m", "pythonfmu", "build", "-f", str(FIXTURES / script), "-d", str(out),
                        "--handle-state"], check=True, capture_output=True)
    return {"gain": out / "ToyGain.fmu", "integrator": out / "ToyIntegrator.fmu"}


def write_scenario(folder: Path, fmus: dict[str, Path], components, connections, parameters=None,
                   stop_time=1.0, step_size=0.01) -> Path:
    """A scenario folder: components = [(name, fmu key, connectors)], parameters = {name: {var: value}}."""
    folder.mkdir(parents=True, exist_ok=True)
    comps = []
    for name, key, connectors in components:
        comp = Component(name, fmus[key], connectors=connectors)
        if parameters and name in parameters:
            params = [Parameter(k, "Integer" if isinstance(v, int) else "Real", v) for k, v in parameters[name].items()]
            (folder / f"{name}.ssv").write_text(parameter_set_xml(name, params))
            comp.parameter_sources = [f"{name}.ssv"]
        comps.append(comp)
    scenario = Scenario("toy", folder / "SystemStructure.ssd", comps,
                        [Connection(*a.split(".") + b.split(".")) for a, b in connections], stop_time=stop_time)
    (folder / "SystemStructure.ssd").write_text(
        system_structure_xml(scenario, {c.name: str(c.source) for c in comps}, step_size))
    return folder


LOOP = dict(components=[("plant", "integrator", INTEGRATOR), ("ctrl", "gain", GAIN)],
            connections=[("plant.x", "ctrl.x"), ("ctrl.y", "plant.u")],
            parameters={"ctrl": {"k": -1.0}, "plant": {"x0": 1.0}})


@pytest.fixture
def loop(tmp_path, toy_fmus) -> Path:
    return write_scenario(tmp_path / "loop", toy_fmus, **LOOP)


def test_feedthrough_is_resolved_at_the_same_instant(loop):
    result = simulate(read_scenario(loop))
    x = result["plant.x"]
    assert len(result) == 101 and result.time[-1] == 1.0
    np.testing.assert_allclose(x, 0.99 ** np.arange(101), rtol=1e-12)     # x_{n+1} = (1 - h) x_n: no delay
    np.testing.assert_allclose(result["ctrl.y"], -x, rtol=1e-12)
    assert result.columns == ["plant.x", "ctrl.y"]           # each connected value once: at its source (issue 33)


def test_communication_points_are_not_accumulated(loop):
    result = simulate(read_scenario(loop), stop_time=0.3, step_size=0.1)
    assert list(result.time) == [0.0, 0.1, 0.2, 0.3]                      # 0.1 + 0.1 + 0.1 != 0.3


def test_error_falls_at_first_order(loop):
    """The input is held over a step (zero-order hold): the global error is O(h)."""
    scenario = read_scenario(loop)
    errors = []
    for h in (0.04, 0.02, 0.01):
        r = simulate(scenario, step_size=h, record=["plant.x"])
        errors.append(np.max(np.abs(r["plant.x"] - np.exp(-r.time))))
    orders = np.log2(np.array(errors[:-1]) / np.array(errors[1:]))
    assert np.all(np.abs(orders - 1.0) < 0.1), orders


def test_error_controlled_steps_keep_the_tolerance(loop):
    """Zero-order hold (the toy FMUs declare no derivatives): the error against e^-t lies within
    [TOL/10, 3 TOL] and the run reports its steps."""
    scenario = read_scenario(loop)
    for tol in (1e-2, 1e-3):
        r = simulate(scenario, step_size=0.01, tolerance=tol, record=["plant.x"])
        assert r.time[0] == 0.0 and r.time[-1] == 1.0 and np.all(np.diff(r.time) > 0)
        err = np.max(np.abs(r["plant.x"] - np.exp(-r.time)))
        report = r.step_control
        assert tol / 10 <= err <= 3 * tol, (tol, err, report.summary())
        assert report.coupling_order == 0 and report.accepted >= len(r) - 1
        assert "communication steps" in report.summary()


def test_dependency_levels_and_missing_dependencies_attribute():
    conns = [("p.x", "c.x"), ("c.y", "p.u")]
    assert dependencies.levels(conns, {"c.y": {"c.x"}, "p.x": set()}) == {"p.x": 0, "c.y": 1}
    with pytest.raises(ScenarioError, match=r"algebraic loop.*p\.x -> c\.x -> c\.y -> p\.u -> p\.x|"
                                            r"algebraic loop.*c\.y -> p\.u -> p\.x -> c\.x -> c\.y"):
        dependencies.levels(conns, {"c.y": {"c.x"}, "p.x": {"p.u"}})


def test_algebraic_loop_is_refused_naming_the_cycle(tmp_path, toy_fmus, capsys):
    folder = write_scenario(tmp_path / "cycle", toy_fmus, components=[("a", "gain", GAIN), ("b", "gain", GAIN)],
                            connections=[("a.y", "b.x"), ("b.y", "a.x")])
    assert main(["run", str(folder), "-o", str(tmp_path / "r.csv"), "--no-progress"]) == 1
    err = capsys.readouterr().err.strip()
    assert "\n" not in err and "algebraic loop" in err
    assert "a.y -> b.x -> b.y -> a.x -> a.y" in err or "b.y -> a.x -> a.y -> b.x -> b.y" in err


def test_cli_run_writes_csv_plot_and_applies_set(loop, tmp_path, capsys):
    out, png = tmp_path / "r.csv", tmp_path / "r.png"
    # --error-threshold: the toy's steps differ from half-steps by 3 % of x's range (not what this test is about)
    assert main(["run", str(loop), "--stop-time", "0.5", "--step-size", "0.05", "--set", "ctrl.k=-2",
                 "--output", str(out), "--plot", str(png), "--no-progress", "--error-threshold", "0.1"]) == 0
    data = read_csv(out)
    assert list(data) == ["time", "plant.x", "ctrl.y"]          # each connected value once (the outputs)
    np.testing.assert_allclose(data["plant.x"], 0.9 ** np.arange(11), rtol=1e-12)
    assert png.stat().st_size > 1000


def test_cli_info_lists_scenario_and_variables(loop, capsys):
    assert main(["info", str(loop)]) == 0
    out = capsys.readouterr().out
    assert "ToyGain.fmu" in out and "fail_at" in out and "plant: ToyIntegrator.fmu" in out


def test_ssp_archive_runs(loop, tmp_path):
    archive = pack_ssp(loop, tmp_path / "loop.ssp")
    names = zipfile.ZipFile(archive).namelist()
    assert "SystemStructure.ssd" in names and "resources/ToyGain.fmu" in names and "ctrl.ssv" in names
    r = simulate(read_scenario(archive), record=["plant.x"])
    assert r["plant.x"][-1] == pytest.approx(0.99 ** 100, rel=1e-12)


def test_progress_bar_draws_after_its_delay():
    stream = io.StringIO()
    bar = ProgressBar("run", delay=0.0, stream=stream, only_tty=False)
    bar(0.5)
    bar(1.0)
    bar.close()
    assert "100.0%" in stream.getvalue() and stream.getvalue().endswith("\n")
    quiet = io.StringIO()
    bar = ProgressBar("run", delay=10.0, stream=quiet, only_tty=False)
    bar(1.0)
    bar.close()
    assert quiet.getvalue() == ""


# ---- bad input: one line naming the file or variable, exit status 1 -----------------------------

def run_cli(args, capsys) -> str:
    status = main(args + ["--no-progress"] if args[0] == "run" else args)
    err = capsys.readouterr().err.strip()
    assert status == 1, err
    assert err.startswith("emcosim: error:") and "\n" not in err, err
    return err


def test_missing_fmu(loop, tmp_path, capsys, toy_fmus):
    folder = write_scenario(tmp_path / "m", {**toy_fmus, "gain": tmp_path / "Nowhere.fmu"}, **LOOP)
    assert "Nowhere.fmu" in run_cli(["run", str(folder)], capsys)


def test_missing_scenario(tmp_path, capsys):
    assert "no_such_scenario" in run_cli(["run", str(tmp_path / "no_such_scenario")], capsys)


def test_unknown_variable_in_connection(tmp_path, toy_fmus, capsys):
    folder = write_scenario(tmp_path / "u", toy_fmus, components=[("plant", "integrator", INTEGRATOR),
                            ("ctrl", "gain", GAIN + [Connector("z", "output", "Real")])],
                            connections=[("plant.x", "ctrl.x"), ("ctrl.z", "plant.u")])
    assert "ctrl.z" in run_cli(["run", str(folder)], capsys)


def test_unknown_parameter(tmp_path, toy_fmus, capsys):
    folder = write_scenario(tmp_path / "p", toy_fmus, **{**LOOP, "parameters": {"ctrl": {"gain": 2.0}}})
    err = run_cli(["run", str(folder)], capsys)
    assert "ctrl.gain" in err and "ctrl.ssv" in err


def test_unknown_variable_in_set(loop, capsys):
    assert "ctrl.kk" in run_cli(["run", str(loop), "--set", "ctrl.kk=1"], capsys)


def test_type_mismatch_of_parameter(tmp_path, toy_fmus, capsys):
    folder = write_scenario(tmp_path / "t", toy_fmus, **{**LOOP, "parameters": {"plant": {"n": 1.5}}})
    err = run_cli(["run", str(folder)], capsys)
    assert "type mismatch" in err and "plant.n" in err


def test_type_mismatch_of_connector(tmp_path, toy_fmus, capsys):
    folder = write_scenario(tmp_path / "t2", toy_fmus, components=[
        ("plant", "integrator", INTEGRATOR), ("ctrl", "gain", [Connector("x", "input", "Integer"), GAIN[1]])],
        connections=LOOP["connections"])
    err = run_cli(["run", str(folder)], capsys)
    assert "type mismatch" in err and "ctrl.x" in err


def test_type_mismatch_in_set(loop, capsys):
    assert "plant.n" in run_cli(["run", str(loop), "--set", "plant.n=abc"], capsys)


def test_causality_mismatch(tmp_path, toy_fmus, capsys):
    folder = write_scenario(tmp_path / "c", toy_fmus, components=[
        ("plant", "integrator", INTEGRATOR), ("ctrl", "gain", [Connector("x", "input", "Real"),
                                                               Connector("y", "input", "Real")])],
        connections=LOOP["connections"])
    err = run_cli(["run", str(folder)], capsys)
    assert "causality mismatch" in err and "ctrl.y" in err


def test_causality_mismatch_setting_an_output(loop, capsys):
    err = run_cli(["run", str(loop), "--set", "plant.x=3"], capsys)
    assert "causality mismatch" in err and "plant.x" in err


@pytest.mark.parametrize("victim", ["SystemStructure.ssd", "ctrl.ssv"])
def test_malformed_xml(loop, capsys, victim):
    path = loop / victim
    path.write_text(path.read_text()[:-40])
    err = run_cli(["run", str(loop)], capsys)
    assert victim in err and "malformed XML" in err


def test_fmu_failing_mid_run_keeps_results(loop, tmp_path, capsys):
    out = tmp_path / "r.csv"
    err = run_cli(["run", str(loop), "--set", "plant.fail_at=0.5", "--output", str(out)], capsys)
    assert "ToyIntegrator.fmu" in err and "fmi2DoStep" in err and "t = 0.5" in err and "integrator fails" in err
    assert not out.exists()                                   # the rows are kept, marked partial
    data = read_csv(tmp_path / "r.partial.csv")
    assert data["time"][-1] == pytest.approx(0.5) and len(data["time"]) == 51
    np.testing.assert_allclose(data["plant.x"], 0.99 ** np.arange(51), rtol=1e-12)


def test_failure_carries_partial_result(loop):
    with pytest.raises(SimulationError) as info:
        simulate(read_scenario(loop), start_values={"plant.fail_at": 0.25})
    assert len(info.value.result) == 26


# ---- other engines --------------------------------------------------------------------------------

def test_libcosim_steps_jacobi_style(loop):
    """libcosim's fixed-step algorithm transfers outputs after the step: x_{n+1} = x_n - h x_{n-1}."""
    pytest.importorskip("libcosimpy")
    from emcosim.engine.libcosim import simulate_libcosim

    r = simulate_libcosim(read_scenario(loop))
    x = np.empty(101)
    x[0], x[1] = 1.0, 0.99
    for n in range(1, 100):
        x[n + 1] = x[n] - 0.01 * x[n - 1]
    np.testing.assert_allclose(r.time, np.arange(101) * 0.01, atol=1e-12)
    np.testing.assert_allclose(r["plant.x"], x, rtol=1e-12)


def test_container_fmu_validates_and_runs(loop, tmp_path):
    from fmpy import simulate_fmu
    from fmpy.validation import validate_fmu

    fmu = tmp_path / "loop.fmu"
    assert main(["export", str(loop), "-o", str(fmu)]) == 0
    assert validate_fmu(str(fmu)) == []
    r = simulate_fmu(str(fmu), stop_time=1.0, output_interval=0.01, start_values={"ctrl.k": -2.0})
    assert r["time"][-1] == pytest.approx(1.0)
    np.testing.assert_allclose(r["plant.x"][-1], 0.98 ** 100, rtol=1e-9)
    cli = subprocess.run([sys.executable, "-m", "fmpy.cli", "validate", str(fmu)], capture_output=True, text=True)
    assert cli.returncode == 0, cli.stdout + cli.stderr
