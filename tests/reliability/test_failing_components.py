"""Failing components: `emcosim run` (a subprocess: a crash is a failed test, not a dead pytest) on
scenarios whose FMU fails mid-run: a plant leaving its domain, a NaN returned with fmi2OK, an
exception raised inside a slave's do_step. Each stops with exit status 1, one error line naming the
FMU and component (or the variable), the time and the cause, and NAME.partial.csv holding the rows
up to the failure (first line: a comment saying why); no NAME.csv is written."""
from __future__ import annotations

import math

import pytest

from emcosim.engine.ssd import Connector

from .scenarios import build_faulty_fmu, emcosim_run, one_line_error, partial_of, read_csv, write_scenario

pytestmark = pytest.mark.reliability


@pytest.fixture(scope="module")
def faulty_fmu(tmp_path_factory):
    return build_faulty_fmu(tmp_path_factory.mktemp("faulty"))


@pytest.fixture(scope="module")
def fmu_folder(reliability_fmus):
    return reliability_fmus["MEMS"].parent


@pytest.mark.parametrize("scenario, stop, step, sets, fmu, t_fail, words", [
    ("mems_regulation_Dd0", "3e-4", "1e-5", ["plant.p_0=-5e-9"], "MEMS.fmu", "1e-05", ["q + c0 > 0", "gap has closed"]),
    ("maglev_regulation_prop2", "0.5", "5e-4", ["plant.p_0=0.05"], "Maglev.fmu", "0.0055", ["q < c", "reached the magnet"]),
])
def test_plant_leaving_its_domain(tmp_path, fmu_folder, tally, scenario, stop, step, sets, fmu, t_fail, words):
    out = tmp_path / "r.csv"
    args = [scenario, "--fmu-dir", str(fmu_folder), "--stop-time", stop, "--step-size", step, "-o", str(out)]
    for s in sets:
        args += ["--set", s]
    proc = emcosim_run(args)
    assert proc.returncode == 1, (proc.returncode, proc.stderr)
    line = one_line_error(proc.stderr)
    assert fmu in line and "component 'plant'" in line and f"t = {t_fail} s" in line, line
    assert all(w in line for w in words), line
    assert not out.exists()
    header, rows = read_csv(partial_of(out))
    assert header[0] == "time" and rows[-1][0] == pytest.approx(float(t_fail), rel=1e-12)
    assert f"{len(rows)} rows up to t = {t_fail} s saved to {partial_of(out)}" in line
    assert all(math.isfinite(v) for row in rows for v in row)
    tally.add("failing_components", f"{scenario} (domain exit)", "clean_error")


CONTROLLER = [Connector(n, "input", "Real") for n in ("q", "p", "x_e")] + [Connector("u", "output", "Real")]
SOURCE = [Connector("y", "output", "Real")]


def _faulty_loop(tmp_path, faulty_fmu, fmu_folder, fault: dict):
    return write_scenario(tmp_path / "faulty_loop",
                          [("source", faulty_fmu, SOURCE), ("ctrl", fmu_folder / "MEMS_Proposition1.fmu", CONTROLLER)],
                          [("source.y", "ctrl.q")], parameters={"source": fault, "ctrl": {"D_d": 0.0}},
                          stop_time=0.01, step_size=1e-3)


def test_nan_returned_with_ok_mid_run(tmp_path, faulty_fmu, fmu_folder, tally):
    """The source turns NaN at t = 5 ms and still reports fmi2OK: the master stops before handing it
    on, naming the variable, the FMU and the time; every row kept is finite."""
    folder = _faulty_loop(tmp_path, faulty_fmu, fmu_folder, {"nan_at": 0.005})
    out = tmp_path / "r.csv"
    proc = emcosim_run([str(folder), "-o", str(out)])
    assert proc.returncode == 1, (proc.returncode, proc.stderr)
    line = one_line_error(proc.stderr)
    assert "source.y = nan at t = 0.005 s" in line and "ReliabilityFaulty.fmu" in line, line
    assert "component 'source'" in line and "not finite" in line, line
    header, rows = read_csv(partial_of(out))
    assert [r[0] for r in rows] == pytest.approx([k * 1e-3 for k in range(5)], abs=1e-15)
    assert all(math.isfinite(v) for r in rows for v in r)
    tally.add("failing_components", "NaN returned with fmi2OK", "clean_error")


def test_exception_raised_in_do_step_mid_run(tmp_path, faulty_fmu, fmu_folder, tally):
    folder = _faulty_loop(tmp_path, faulty_fmu, fmu_folder, {"raise_at": 0.005, "rate": 1e-3})
    out = tmp_path / "r.csv"
    proc = emcosim_run([str(folder), "-o", str(out)])
    assert proc.returncode == 1, (proc.returncode, proc.stderr)      # a crash of the host would be negative
    line = one_line_error(proc.stderr)
    assert "ReliabilityFaulty.fmu" in line and "component 'source'" in line and "t = 0.005 s" in line, line
    assert "fmi2DoStep" in line and "fatal" in line and "deliberate exception in do_step" in line, line
    header, rows = read_csv(partial_of(out))
    assert rows[-1][0] == pytest.approx(0.005, rel=1e-12) and len(rows) == 6
    y = header.index("source.y")
    assert [r[y] for r in rows] == pytest.approx([2e-5 + 1e-3 * k * 1e-3 for k in range(6)], rel=1e-12)
    tally.add("failing_components", "exception in do_step", "clean_error")
    tally.measurements["failing_components"]["exception_message"] = line
