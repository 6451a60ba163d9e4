"""The paper's scenarios (scenarios/): files, runs, accuracy against the monolithic reference,
convergence order, the libcosim cross-check and the container FMU.

Test horizons are shortened (MEMS 0.5 ms, maglev 2 s) to keep the suite fast; the scenarios keep
the paper-scale horizons, which benchmarks/bench_master.py runs in full (accuracy included)."""
from __future__ import annotations

import math
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from emcosim.engine.master import simulate
from emcosim.engine.ssd import read_scenario
from emcosim.paper import scenarios as paper_scenarios
from tests.helpers import TIGHT, declares_derivatives, scenario

ROOT = Path(__file__).resolve().parents[1]
SCENARIOS = [c.name for c in paper_scenarios.cases()]
ACCURACY = 1e-3                 # normalised maximum position error at the default step (docs/scenarios.md)


def test_scenario_files_are_generated_from_components():
    assert paper_scenarios.stale() == [], "run `python -m emcosim.paper.scenarios` to regenerate scenarios/"


def test_every_paper_case_has_a_scenario():
    assert len(SCENARIOS) == 10
    for name in SCENARIOS:
        s = read_scenario(ROOT / "scenarios" / name)
        assert s.stop_time > 0 and s.step_size > 0
        assert {c.name for c in s.components} >= {"controller", "plant"}
        assert s.notes, f"{name}: the .ssd must document its choices"


def test_scenario_files_validate_against_the_ssp_schema():
    etree = pytest.importorskip("lxml.etree")
    import fmpy
    schema_dir = Path(fmpy.__file__).parent / "ssp" / "schema"
    for xsd, pattern in [("SystemStructureDescription.xsd", "*/SystemStructure.ssd"),
                         ("SystemStructureParameterValues.xsd", "*/*.ssv")]:
        schema = etree.XMLSchema(etree.parse(str(schema_dir / xsd)))
        files = sorted((ROOT / "scenarios").glob(pattern))
        assert files
        for f in files:
            assert schema.validate(etree.parse(str(f))), f"{f}: {schema.error_log.last_error}"


def test_maglev_initial_flux_is_the_feasible_one():
    from components.maglev import Maglev
    plant = Maglev()
    q0, p0, x0 = paper_scenarios.maglev_initial_state()
    assert (q0, p0) == (0.0015, 0.0)
    assert x0 == pytest.approx(np.sqrt(2 * plant.k * plant.b), rel=1e-12)        # q*''(0) = 0


# ---- runs: these need the FMUs ------------------------------------------------------------------

def short(name: str) -> float:
    return 5e-4 if name.startswith("mems") else 2.0


@pytest.mark.parametrize("name", SCENARIOS)
def test_scenario_matches_monolithic_reference(name, fmu_dir, references):
    """Every scenario at its default step: the co-simulation follows the monolithic closed loop of
    the same components within ACCURACY (normalised maximum position error), over a short horizon
    (the full horizons: tests/test_full_horizon.py)."""
    from emcosim.paper.reference_check import position_error, position_scale, samples_for
    s = scenario(name, fmu_dir)
    t_end = s.step_size * max(4, math.ceil(short(name) / s.step_size - 1e-9))     # whole steps
    result = simulate(s, stop_time=t_end)
    assert result.time[-1] == pytest.approx(t_end) and len(result) == round(t_end / s.step_size) + 1
    assert set(result.columns) >= {"plant.q", "plant.p", "plant.x_e", "controller.u"}
    assert "plant.u" not in result.columns         # the connected value once, at its source (issue 33)
    if not declares_derivatives(s):
        pytest.skip("the default steps are those of first-order coupling; the FMUs declare no derivatives (issue 13)")
    ref = references(s, t_end, samples_for(t_end, s.step_size, 1001))
    assert position_error(result.time, result["plant.q"], ref, position_scale(s)) < ACCURACY


# steps of the convergence test: zero-order hold (the steps of the first-order defaults before
# derivatives were passed), first-order coupling (the defaults and two coarser)
CONVERGENCE = {"mems_regulation_Dd-1": (4e-4, (2e-6, 1e-6, 5e-7), (4e-6, 2e-6, 1e-6)),
               "maglev_tracking_D-1_R2.82": (2.0, (2e-3, 1e-3, 5e-4), (0.04, 0.02, 0.01))}


@pytest.mark.parametrize("coupling_order", [0, 1, None])
@pytest.mark.parametrize("name", list(CONVERGENCE))
def test_convergence_order(name, coupling_order, fmu_dir, references):
    """Error against the monolithic reference over a range of steps: order 1 with the controller's
    output held over a step (coupling order 0), at least 1.9 with its derivative passed on (order
    1: the plant follows u + u' tau) and with the default coupling (u'' added by extrapolation)."""
    from emcosim.paper.reference_check import position_error, samples_for
    s = scenario(name, fmu_dir)
    t_end, zoh, foh = CONVERGENCE[name]
    if coupling_order != 0 and not declares_derivatives(s):
        pytest.skip("the FMUs declare no output derivatives / input interpolation (issue 13)")
    steps = zoh if coupling_order == 0 else foh
    ref = references(s, t_end, samples_for(t_end, steps[0], 1001))
    errors = []
    for h in steps:
        r = simulate(s, stop_time=t_end, step_size=h, record=["plant.q"], coupling_order=coupling_order,
                     start_values=TIGHT)         # the coupling's order, not the plant integrator's error
        errors.append(position_error(r.time, r["plant.q"], ref, 1.0))
    orders = np.log2(np.array(errors[:-1]) / np.array(errors[1:]))
    if coupling_order == 0:
        assert np.all(np.abs(orders - 1.0) < 0.15), (errors, orders)
    else:
        assert np.all(orders >= 1.9), (errors, orders)


@pytest.mark.parametrize("name", ["mems_regulation_Dd-1",
                                  pytest.param("maglev_tracking_D-1_R2.82", marks=pytest.mark.slow)])
def test_libcosim_cross_check(name, fmu_dir, references):
    """libcosim runs the same files (its own SSP parser and FMI library). Its fixed-step algorithm is
    Jacobi: the plant integrates [t_n, t_n+1] with u(t_{n-1}), an effective input delay of 3h/2
    against the h/2 of our zero-order hold at the same instant (coupling order 0 here: libcosim passes
    no derivatives). To first order its error against
    the monolithic reference is then 3 times ours, and the difference between the two engines
    twice ours."""
    pytest.importorskip("libcosimpy")
    from emcosim.engine.libcosim import simulate_libcosim
    from emcosim.paper.reference_check import position_error, samples_for
    s = scenario(name, fmu_dir)
    t_end = 4e-4 if name.startswith("mems") else 2.0
    ref = references(s, t_end, samples_for(t_end, s.step_size, 1001))
    h = CONVERGENCE[name][1][-1]                             # a step of the zero-order hold
    ours = simulate(s, stop_time=t_end, step_size=h, record=["plant.q"], coupling_order=0)
    theirs = simulate_libcosim(s, stop_time=t_end, step_size=h, record=["plant.q"])
    np.testing.assert_allclose(theirs.time, ours.time, atol=1e-12)
    e_ours = position_error(ours.time, ours["plant.q"], ref, 1.0)
    e_theirs = position_error(theirs.time, theirs["plant.q"], ref, 1.0)
    diff = np.max(np.abs(theirs["plant.q"] - ours["plant.q"]))
    assert 2.5 < e_theirs / e_ours < 3.5, (e_ours, e_theirs)
    assert 1.6 < diff / e_ours < 2.4, (e_ours, diff)


def test_container_fmu_of_a_scenario(fmu_dir, tmp_path):
    """`emcosim export` writes a container FMU that `fmpy validate` accepts and `fmpy simulate`
    runs; its trajectory agrees with our master's with a zero-order hold (the container passes no
    derivatives; see docs/scenarios.md on its stepping)."""
    from fmpy import simulate_fmu

    from emcosim.cli import main
    name = "maglev_tracking_D-1_R2.82"
    fmu = tmp_path / "loop.fmu"
    assert main(["export", name, "-o", str(fmu), "--fmu-dir", str(fmu_dir), "--step-size", "0.0005"]) == 0
    check = subprocess.run([sys.executable, "-m", "fmpy.cli", "validate", str(fmu)], capture_output=True, text=True)
    assert check.returncode == 0, check.stdout + check.stderr
    out = tmp_path / "loop.csv"
    run = subprocess.run([sys.executable, "-m", "fmpy.cli", "simulate", str(fmu), "--stop-time", "0.5",
                          "--output-interval", "0.0005", "--output-file", str(out)], capture_output=True, text=True)
    assert run.returncode == 0, run.stdout + run.stderr
    from emcosim.engine.results import read_csv
    container = read_csv(out)
    ours = simulate(scenario(name, fmu_dir), stop_time=0.5, step_size=0.0005, record=["plant.q"], coupling_order=0)
    np.testing.assert_allclose(container["time"], ours.time, atol=1e-12)
    diff = np.max(np.abs(container["plant.q"] - ours["plant.q"])) / np.max(np.abs(ours["plant.q"]))
    assert diff < 1e-3
    r = simulate_fmu(str(fmu), stop_time=0.1, output_interval=0.0005, start_values={"controller.D_d": 0.0})
    assert r["time"][-1] == pytest.approx(0.1)


def test_cli_runs_a_paper_scenario(fmu_dir, tmp_path, capsys):
    from emcosim.cli import main
    from emcosim.engine.results import read_csv
    out = tmp_path / "r.csv"
    assert main(["run", "maglev_regulation_prop2", "--stop-time", "0.05", "--step-size", "0.0005", "--fmu-dir", str(fmu_dir),
                 "--set", "controller.D_d=0", "--output", str(out), "--no-progress"]) == 0
    data = read_csv(out)
    assert {"time", "plant.q", "plant.H", "controller.u"} <= set(data) and len(data["time"]) == 101
    assert main(["info", "maglev_regulation_prop2", "--fmu-dir", str(fmu_dir)]) == 0
    assert "q_0" in capsys.readouterr().out


def test_scenarios_run_one_after_another_in_one_process(fmu_dir):
    """The master deletes each run's unzip folders, while the FMUs' Python modules stay loaded in
    the process (one interpreter for all pythonfmu FMUs): a second run of the same FMUs must still
    initialize (it once failed checking its bundle against the deleted first copy). A fresh
    process, so that no earlier test has loaded the modules."""
    code = ("import sys; from emcosim.engine.master import simulate; from emcosim.engine.ssd import read_scenario\n"
            "for name in ['mems_regulation_Dd0', 'mems_tracking_Dd0', 'mems_regulation_Dd0']:\n"
            f"    r = simulate(read_scenario({str(ROOT / 'scenarios')!r} + '/' + name, fmu_dir={str(fmu_dir)!r}),"
            " stop_time=2e-5)\n"
            "    print(name, len(r))\n")
    run = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, cwd=ROOT)
    assert run.returncode == 0, run.stderr[-2000:]
    assert len(run.stdout.split("\n")) == 4


def test_build_packs_every_scenario_into_a_runnable_ssp(fmu_dir, tmp_path):
    """build.py packs each scenario with its FMUs into one .ssp archive; the same inputs give the
    same bytes, and an archive runs on its own (its FMUs inside) with the results of the folder."""
    import zipfile

    from emcosim.paper.scenarios import pack_archives
    archives = pack_archives(fmu_dir, tmp_path / "a", verbose=False)
    assert sorted(a.stem for a in archives) == sorted(SCENARIOS)
    again = pack_archives(fmu_dir, tmp_path / "b", verbose=False)
    assert [a.read_bytes() for a in archives] == [b.read_bytes() for b in again]
    ssp = tmp_path / "a" / "maglev_regulation_prop2.ssp"
    names = zipfile.ZipFile(ssp).namelist()
    assert "SystemStructure.ssd" in names and "resources/Maglev.fmu" in names
    packed = simulate(read_scenario(ssp), stop_time=0.05, record=["plant.q"])
    folder = simulate(scenario("maglev_regulation_prop2", fmu_dir), stop_time=0.05, record=["plant.q"])
    np.testing.assert_array_equal(packed["plant.q"], folder["plant.q"])
