"""The public API (emcosim/api.py, re-exported by `emcosim`): its docstrings' examples run as doctests, the
command line gives the same rows and records the same variables as the API, a run records each connected
value once, and the DataFrame carries the FMUs' units."""
from __future__ import annotations

import doctest

import numpy as np
import pytest

import emcosim
from emcosim import api
from emcosim.cli import main
from emcosim.engine.master import simulate
from emcosim.engine.results import read_csv


@pytest.mark.parametrize("module", [api, emcosim], ids=["emcosim.api", "emcosim"])
def test_the_docstring_examples_run(module, tmp_path, monkeypatch, fmu_dir):
    monkeypatch.chdir(tmp_path)                    # an empty folder: names must be found from anywhere
    finder = doctest.DocTestFinder()
    runner = doctest.DocTestRunner(optionflags=doctest.ELLIPSIS | doctest.NORMALIZE_WHITESPACE)
    tests = finder.find(module, module.__name__, globs={**vars(module), **api._doctest_globals(tmp_path)})
    skipped = sum(bool(e.options.get(doctest.SKIP)) for t in tests for e in t.examples)
    for test in tests:
        runner.run(test)
    failed, attempted = runner.summarize(verbose=False)
    assert failed == 0
    if module is api:
        assert attempted >= 15 and skipped <= 4        # +SKIP only for an FMU build and a Dask sweep


def test_every_public_function_has_an_example():
    for name in emcosim.__all__:
        obj = getattr(emcosim, name)
        if callable(obj) and not isinstance(obj, type) and obj.__module__ in ("emcosim.api", "emcosim.engine.plan"):
            assert ">>> " in (obj.__doc__ or "") or name in ("default_record", "units_of"), name


def test_a_run_records_each_connected_value_once():
    scenario = emcosim.load_scenario("maglev_regulation_prop2")
    fed = {c.end for c in scenario.connections}
    # independent of default_record: the outputs of the loop, none of the inputs they feed
    expected = [f"{c.name}.{k.name}" for c in scenario.components for k in c.connectors if k.kind == "output"]
    assert fed and not fed & set(emcosim.default_record(scenario))
    assert emcosim.default_record(scenario) == expected


def test_the_engine_the_api_and_the_cli_record_the_same(tmp_path, fmu_dir):
    scenario = emcosim.load_scenario("maglev_regulation_prop2")
    engine = simulate(scenario, stop_time=0.02)                     # the engine's own default
    result = emcosim.run("maglev_regulation_prop2", emcosim.RunOptions(stop_time=0.02),
                         error_threshold=1)
    out = tmp_path / "cli.csv"
    # one step: its own error estimate is 1.1 % of the tiny range of u, above the default 1 %; this test is about
    # what is recorded, so the threshold is lifted (the estimate's own tests: tests/test_fixed_error.py)
    assert main(["run", "maglev_regulation_prop2", "--stop-time", "0.02", "-o", str(out), "--no-progress",
                 "--error-threshold", "1"]) == 0
    cli = read_csv(out)
    assert engine.columns == result.columns == [n for n in cli if n != "time"]
    assert "controller.q" not in result.columns and "plant.q" in result.columns     # once, not twice
    np.testing.assert_array_equal(cli["time"], result.time)
    for name in result.columns:
        np.testing.assert_allclose(cli[name], result[name], rtol=1e-12, atol=0)   # the CSV's 17 digits


def test_to_pandas_gives_the_rows_and_the_fmus_units(fmu_dir):
    result = emcosim.run("mems_regulation_Dd0", emcosim.RunOptions(stop_time=1e-3))
    df = result.to_pandas()
    assert list(df.columns) == result.columns and df.index.name == "time"
    np.testing.assert_array_equal(df.index.to_numpy(), result.time)
    np.testing.assert_array_equal(df["plant.q"].to_numpy(), result["plant.q"])
    # the units as docs/fmus.md gives them for the MEMS plant and its controller
    units = df.attrs["units"]
    assert {k: units[k] for k in ("time", "controller.u", "plant.q", "plant.p", "plant.x_e", "plant.H")} == {
        "time": "s", "controller.u": "V", "plant.q": "m", "plant.p": "kg.m/s", "plant.x_e": "C", "plant.H": "J"}
    assert units["reference.q_star"] == "m" and units["reference.q_star_dot"] == "m/s"


def test_a_misspelt_name_gets_suggestions_from_any_folder(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    with pytest.raises(emcosim.engine.errors.ScenarioError, match="did you mean maglev_regulation_prop2"):
        emcosim.load_scenario("maglev_regulation_prop")


# ---- one options object (issue 33, item 3) --------------------------------------------------------

def test_run_options_is_the_one_parameter_of_every_run():
    """simulate, both simulation classes, the sweep's session and the sweep take one RunOptions: none of them
    lists a setting of its own (adding a setting to RunOptions is one edit)."""
    import dataclasses
    import inspect

    from emcosim.engine.master import Simulation
    from emcosim.engine.model_exchange import ModelExchangeSimulation
    from emcosim.engine.session import Session
    from emcosim.paper import sweep as paper_sweep

    fields = {f.name for f in dataclasses.fields(emcosim.RunOptions)}
    from emcosim import sweeps

    for fn in (simulate, Simulation.run, ModelExchangeSimulation.run, Session.run, sweeps.run_point, sweeps.run_all,
               sweeps.sweep, paper_sweep.run_point, paper_sweep.run_all, paper_sweep.sweep, emcosim.run, emcosim.sweep):
        parameters = inspect.signature(fn).parameters
        assert "options" in parameters, fn.__qualname__
        assert not fields & set(parameters), (fn.__qualname__, fields & set(parameters))


def test_keyword_settings_are_shorthands_for_the_options(fmu_dir):
    scenario = emcosim.load_scenario("maglev_regulation_prop2")
    a = simulate(scenario, emcosim.RunOptions(stop_time=0.05, step_size=0.005))
    b = simulate(scenario, stop_time=0.05, step_size=0.005)
    c = simulate(scenario, emcosim.RunOptions(stop_time=1.0), step_size=0.005, stop_time=0.05)
    assert len(a) == 11 and a.rows == b.rows == c.rows
    with pytest.raises(TypeError, match="no_such_setting"):
        simulate(scenario, no_such_setting=1)


def test_a_sweep_point_runs_as_model_exchange(fmu_dir):
    """The sweep's run of one point as Model Exchange: the same metrics as the co-simulation's within the
    coupling error of a 4 us step (the two solve the same closed loop)."""
    from emcosim.paper.sweep import close_sessions, run_point

    ssd = str(emcosim.find_scenario("mems_regulation_Dd0"))
    values = {"controller.D_d": -0.5}
    # threshold: at 4 us explicit coupling errs 4 % of H's range at D_d = -0.5 (estimate 6 %): not accepted at
    # the default 1e-2, but the metrics compared here (ISE, max |u|) agree within 1 %
    cs = run_point(ssd, str(fmu_dir), values, emcosim.RunOptions(stop_time=1e-3, step_size=4e-6), threshold=0.1)
    me = run_point(ssd, str(fmu_dir), values, emcosim.RunOptions(stop_time=1e-3, step_size=4e-6,
                                                                 interface_type="ModelExchange", rtol=1e-8))
    close_sessions()
    assert cs["status"] == me["status"] == "ok", (cs["status"], me["status"])
    assert me["ise"] == pytest.approx(cs["ise"], rel=1e-2) and me["max_abs_u"] == pytest.approx(cs["max_abs_u"], rel=1e-2)


def test_the_generic_plot_leaves_the_papers_layer_alone(make, tmp_path):
    """`run --plot` of a scenario that is not this suite's: the engine's figure, emcosim.paper never imported
    and the device catalog unchanged (run in a fresh process, which starts without either)."""
    import subprocess
    import sys

    from tests.helpers import loop

    folder = loop(make).path.parent
    code = ("import sys; from components import catalog; before = sorted(catalog.DEVICES); "
            "from emcosim.cli import main; "
            f"status = main(['run', {str(folder)!r}, '--plot', 'toy.png', '-o', 'toy.csv', '--no-progress']); "
            "print(status, 'emcosim.paper' in sys.modules, sorted(catalog.DEVICES) == before)")
    run = subprocess.run([sys.executable, "-c", code], cwd=tmp_path, capture_output=True, text=True, timeout=120)
    assert run.stdout.split()[-3:] == ["0", "False", "True"], run.stdout + run.stderr
    assert (tmp_path / "toy.png").stat().st_size > 0


def test_the_sweep_engine_runs_any_scenario(make):
    """emcosim.sweeps (the Dask engine, out of the paper's layer): a point of a toy loop, which has none of the
    paper's metrics, gives the last value of each recorded variable, as an independent run does."""
    from emcosim import sweeps
    from tests.helpers import loop

    scenario = loop(make)
    ssd = str(scenario.path)
    row = sweeps.run_point(ssd, None, {"ctrl.k1": -2.0}, emcosim.RunOptions(stop_time=0.5))
    sweeps.close_sessions()
    alone = simulate(scenario, stop_time=0.5, start_values={"ctrl.k1": -2.0})
    assert row["status"] == "ok" and row["ctrl.k1"] == -2.0
    assert row["plant.x"] == alone["plant.x"][-1]
    assert row["plant.x"] == pytest.approx(np.exp(-2.0 * 0.5), rel=1e-2)          # x' = k1 x, x(0) = 1


@pytest.mark.slow                        # an FMU build of the solenoid: about 20 s
def test_a_description_builds_only_the_designs_that_apply(tmp_path):
    """fmus.build.build_description (also through emcosim.build_plant): the solenoid's Assumptions 2 and 4 fail
    (emcosim plant check), so no Proposition2 / Theorem3 controller is built; and every FMU carries the
    description where the registry finds it, so certify knows the device."""
    from components import catalog
    from emcosim.devices import registry
    from fmus.build import build_description

    toml = api._examples() / "solenoid" / "solenoid.toml"
    assert sorted(emcosim.check_plant(toml).designs) == ["Proposition1", "Theorem2"]
    paths = build_description(toml, tmp_path / "direct")
    assert sorted(paths) == ["Solenoid", "Solenoid_Proposition1", "Solenoid_Theorem2"]
    tables = (catalog.DEVICES, catalog.PLANTS, catalog.GAINS, catalog.CONTROLLER_PLANT, catalog.TRACKING)
    saved = [dict(t) for t in tables]
    for t in tables:
        for key in [k for k in t if k.startswith("Solenoid")]:
            del t[key]
    try:
        device = registry.register_fmu(paths["Solenoid_Proposition1"])
        assert device is not None and device.name == "Solenoid" and "Solenoid_Proposition1" in catalog.GAINS
    finally:
        for t, old in zip(tables, saved):
            t.clear()
            t.update(old)
