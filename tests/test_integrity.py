"""Issue 15 (no result lost, no wrong result with exit 0, no hostile input harmful): the findings that
run in this process. Each test reproduces a finding of the issue and fails on the code before the fix.
The ones that need signals, kill -9, a file-size limit or a second process are in
tests/reliability/test_output_integrity.py and test_sweep_integrity.py.

Independent truths: the toy loop x' = k x whose communication-point recursion is
x_{n+1} = (1 + k h) x_n; unit definitions (1 t = 1000 kg, 1 mm = 1e-3 m); the declared 32-bit range
of fmi2Integer; byte-for-byte equality of files that must not change."""
from __future__ import annotations

import io
import math
import os
import re
import shutil
import zipfile
from pathlib import Path

import numpy as np
import pytest

from emcosim.cli import main
from emcosim.engine import binding, master
from emcosim.engine.errors import ScenarioError
from emcosim.engine.results import read_csv
from emcosim.engine.ssd import read_scenario
from emcosim.engine.ssp import pack_ssp

from .integrity_helpers import ROOT, build_toys, emcosim, partial_note, partial_of, toy_loop

SCENARIOS = ROOT / "scenarios"


@pytest.fixture(scope="module")
def toys(tmp_path_factory) -> dict[str, Path]:
    return build_toys(tmp_path_factory.mktemp("toys"))


@pytest.fixture
def loop(tmp_path, toys) -> Path:
    return toy_loop(tmp_path / "loop", toys)


def run(args: list[str], capsys) -> tuple[int, str]:
    status = main(args + (["--no-progress"] if args[0] == "run" else []))
    err = capsys.readouterr().err.strip()
    return status, err


def error_line(args, capsys) -> str:
    status, err = run(args, capsys)
    assert status == 1, err
    lines = err.splitlines()
    assert lines[-1].startswith("emcosim: error:") and "Traceback" not in err, err
    return lines[-1]


def scenario_copy(tmp_path: Path, name: str) -> Path:
    folder = tmp_path / name
    shutil.copytree(SCENARIOS / name, folder)
    return folder


# ---- 1. a non-finite value never ends a run with exit 0 -------------------------------------------

def test_the_issues_nan_run_ends_with_the_controllers_error(fmu_dir, tmp_path, capsys):
    """The issue's run: the controller cannot compute u at t = 3 ms. It used to return NaN with fmi2OK;
    now the FMU answers fmi2Error with the reason, and the run ends with the rows before it kept."""
    out = tmp_path / "x.csv"
    line = error_line(["run", "maglev_tracking_D0_R2.82", "--set", "reference.omega=200", "--stop-time", "0.003",
                       "--step-size", "0.0005", "--fmu-dir", str(fmu_dir), "-o", str(out)], capsys)
    assert "component 'controller' failed in fmi2GetReal at t = 0.003 s" in line, line
    assert "Maglev_Theorem3.fmu" in line and "infeasible reference" in line, line
    assert not out.exists()
    data = read_csv(partial_of(out))
    assert data["time"][-1] == pytest.approx(0.0025, rel=1e-12)
    assert all(np.all(np.isfinite(v)) for v in data.values())
    assert "infeasible reference" in partial_note(partial_of(out))


def test_non_finite_output_returned_with_ok_ends_the_run(tmp_path, toys, capsys):
    """A foreign FMU (the toy gain, built with plain pythonfmu) returns y = k x = 1e308 * 10 = inf with
    fmi2OK: the master refuses the value, names it, and keeps no result under the final name."""
    loop = toy_loop(tmp_path / "inf", toys, k=1e308, x0=10.0)
    out = tmp_path / "r.csv"
    line = error_line(["run", str(loop), "-o", str(out)], capsys)
    assert "ctrl.y = inf at t = 0 s" in line and "not finite" in line, line
    assert not out.exists()


def test_non_finite_value_after_a_connection_transformation(tmp_path, toys, capsys):
    """plant.x = 10 times a LinearTransformation factor of 1e308 overflows: the input is refused."""
    loop = toy_loop(tmp_path / "big", toys, x0=10.0, factor=1e308)
    line = error_line(["run", str(loop), "-o", str(tmp_path / "r.csv")], capsys)
    assert "ctrl.x = inf at t = 0 s" in line and "not finite" in line, line


# ---- 2. output files ------------------------------------------------------------------------------

def test_failing_run_keeps_its_rows_and_leaves_the_result_alone(loop, tmp_path, capsys):
    out = tmp_path / "r.csv"
    assert run(["run", str(loop), "-o", str(out)], capsys)[0] == 0
    good = out.read_bytes()
    assert len(good.splitlines()) == 102                                 # the header, 101 rows (the estimate: r.json)
    line = error_line(["run", str(loop), "--set", "plant.fail_at=0.5", "-o", str(out)], capsys)
    assert out.read_bytes() == good                                     # the good result is untouched
    partial = partial_of(out)
    assert f"51 rows up to t = 0.5 s saved to {partial}" in line, line
    note = partial_note(partial)
    assert "fmi2DoStep" in note and "integrator fails" in note and "51 rows up to t = 0.5 s" in note, note
    data = read_csv(partial)
    np.testing.assert_allclose(data["plant.x"], 0.99 ** np.arange(51), rtol=1e-12)


@pytest.mark.parametrize("target", ["missing", "read-only", "folder"])
def test_destination_is_checked_before_the_run(loop, tmp_path, target):
    """A run of 1e8 steps (hours) must fail at once when its results cannot be written."""
    folder = tmp_path / "ro"
    folder.mkdir()
    out = {"missing": tmp_path / "missing" / "r.csv", "read-only": folder / "r.csv", "folder": folder}[target]
    os.chmod(folder, 0o555)
    try:
        proc = emcosim(["run", str(loop), "--stop-time", "1e6", "--step-size", "1e-2", "-o", str(out),
                        "--no-progress"], timeout=60)
    finally:
        os.chmod(folder, 0o755)
    assert proc.returncode == 1, proc.stderr
    expected = {"missing": "does not exist", "read-only": "is not writable", "folder": "is a folder"}[target]
    assert expected in proc.stderr and "Traceback" not in proc.stderr, proc.stderr
    assert list(folder.iterdir()) == []


def test_streamed_result_keeps_only_the_last_row(loop, tmp_path):
    from emcosim.engine.outputs import ResultFile

    out = tmp_path / "s.csv"
    with ResultFile(out, "toy") as sink:
        result = master.simulate(read_scenario(loop), sink=sink)
    assert len(result) == 101 and result.rows == [] and result.last[0] == 1.0
    with pytest.raises(ScenarioError, match="streamed to .*s.csv"):
        result["plant.x"]
    np.testing.assert_allclose(read_csv(out)["plant.x"], 0.99 ** np.arange(101), rtol=1e-12)
    assert sink.rows == 101 and sink.final == out and not list(tmp_path.glob("*incomplete*"))


@pytest.mark.parametrize("folder", ["", "old.incomplete-1 [x]"])
def test_file_of_a_killed_run_is_marked_partial(tmp_path, folder):
    """The file of a run that was killed (its marker line still there, its lock free: the kernel
    releases a dead process's locks) gets the partial comment; a torn last line (a write cut by
    kill -9) is left out. Also in a folder whose name holds "incomplete-" and glob's special characters."""
    from emcosim.engine.outputs import ResultFile, mark_orphans

    where = tmp_path / folder
    where.mkdir(exist_ok=True)
    sink = ResultFile(where / "r.csv")
    sink.start(["a"])
    for t, a in ((0.0, 1.0), (0.5, 2.0)):
        sink.write([t, a])
    sink.flush()
    os.pwrite(sink.fd, b"1.0,3", sink.written)                           # torn: cut by the kill
    os.close(sink.fd)                                                    # the process dies
    orphan = sink.temp
    notes = mark_orphans(where / "r.csv")
    assert len(notes) == 1 and f"pid {os.getpid()}" in notes[0]
    assert "ended without a clean exit" in partial_note(orphan) and "2 rows up to t = 0.5 s" in partial_note(orphan)
    assert read_csv(orphan)["a"].tolist() == [1.0, 2.0]
    assert mark_orphans(where / "r.csv") == []                           # marked once


# ---- 2. reproduce: a fresh folder, swapped in on success -------------------------------------------

def test_reproduce_refuses_a_read_only_out_before_any_scenario(fmu_dir, tmp_path):
    from emcosim.paper.reproduce import reproduce

    parent = tmp_path / "ro"
    parent.mkdir()
    os.chmod(parent, 0o555)
    log = io.StringIO()
    try:
        with pytest.raises(ScenarioError, match="not writable"):
            reproduce(parent / "results", stop_time=1e-3, out=log, fmu_dir=fmu_dir, jobs=1)
    finally:
        os.chmod(parent, 0o755)
    assert "[1/10]" not in log.getvalue() and list(parent.iterdir()) == []


def test_failed_reproduce_leaves_the_old_results_alone(fmu_dir, tmp_path):
    from emcosim.engine.output_folder import OutputFolder
    from emcosim.paper.reproduce import reproduce

    out = tmp_path / "results"
    with OutputFolder(out) as earlier:                       # an earlier reproduce's folder
        (earlier.path / "runs.json").write_text("{}")
        (earlier.path / "fig1_mems_regulation.png").write_bytes(b"old figure")
    before = {p.name: p.read_bytes() for p in out.iterdir()}
    no_maglev = tmp_path / "fmus"
    shutil.copytree(fmu_dir, no_maglev)
    (no_maglev / "Maglev.fmu").unlink()
    with pytest.raises(ScenarioError, match=r"5 of 10 scenarios failed.*results\.partial"):
        reproduce(out, stop_time=2e-4, out=io.StringIO(), fmu_dir=no_maglev, jobs=1)
    assert {p.name: p.read_bytes() for p in out.iterdir()} == before     # nothing mixed in
    partial = tmp_path / "results.partial"
    assert "5 of 10 scenarios failed" in (partial / "PARTIAL.txt").read_text()
    assert (partial / "fig1_mems_regulation.png").read_bytes() != b"old figure"
    assert not list(tmp_path.glob("results.incomplete-*"))


# ---- 3. horizons ------------------------------------------------------------------------------------

@pytest.mark.parametrize("args, message", [
    (["--stop-time", "1e308"], "too many communication steps to count"),
    (["--step-size", "1e-15"], "1e+15 communication steps, more than the limit of 1e+08; give --max-steps"),
    (["--stop-time", "1e6", "--step-size", "1e-11", "--max-steps", "1e30"], "below the resolution of time"),
])
def test_absurd_horizons_are_refused(loop, tmp_path, args, message):
    """In a subprocess with a timeout: accepted, these runs would go on for years."""
    proc = emcosim(["run", str(loop), *args, "-o", str(tmp_path / "r.csv"), "--no-progress"], timeout=60)
    assert proc.returncode == 1 and message in proc.stderr and "Traceback" not in proc.stderr, proc.stderr


# ---- 6. silent wrong input --------------------------------------------------------------------------

@pytest.mark.parametrize("setting", ["reference.kind=4294967296", "controller.strict=4294967296",
                                     "reference.kind=-2147483649"])
def test_integers_out_of_32_bits_are_refused(fmu_dir, setting):
    """fmi2Integer is 32 bits: 4294967296 used to wrap to 0 (kind 0: a constant reference). The engine names the
    start value as its API does; the command line as its --set (test_set_on_a_connected_input_is_refused)."""
    from emcosim.engine.session import check_start_values

    scenario = read_scenario(SCENARIOS / "maglev_tracking_D0_R2.82", fmu_dir=fmu_dir)
    name, _, value = setting.partition("=")
    with pytest.raises(ScenarioError, match=rf"start value {re.escape(name)}: value {value} does not fit an FMI Integer"):
        check_start_values(scenario, {name: value})
    check_start_values(scenario, {name: "2147483647" if value[0] != "-" else "-2147483648"})   # the ends fit


SSV_UNITS = ('<ssv:Units><ssc:Unit xmlns:ssc="http://ssp-standard.org/SSP1/SystemStructureCommon" name="{name}">'
             '<ssc:BaseUnit {base}/></ssc:Unit></ssv:Units>')


def maglev_with_mass(tmp_path, fmu_dir, value: str, unit: str, base: str):
    folder = scenario_copy(tmp_path, "maglev_tracking_D0_R2.82")
    ssv = folder / "plant.ssv"
    text = ssv.read_text().replace('<ssv:Real value="0.0844"/>', f'<ssv:Real value="{value}" unit="{unit}"/>')
    ssv.write_text(text.replace("</ssv:Parameters>", "</ssv:Parameters>" + SSV_UNITS.format(name=unit, base=base)))
    scenario = read_scenario(folder, fmu_dir=fmu_dir)
    instances = binding.load(scenario)
    return scenario, instances


def test_ssv_unit_is_converted_to_the_fmu_unit(fmu_dir, tmp_path):
    """m = 8.44e-5 t (1 t = 1000 kg) is set as 0.0844 kg, the unit Maglev.fmu declares."""
    scenario, instances = maglev_with_mass(tmp_path, fmu_dir, "8.44e-5", "t", 'kg="1" factor="1000"')
    values = dict((var.name, v) for var, v in binding.parameter_values(scenario, instances, {})["plant"])
    assert values["m"] == pytest.approx(0.0844, rel=1e-15)


def test_ssv_unit_of_another_dimension_is_refused(fmu_dir, tmp_path):
    scenario, instances = maglev_with_mass(tmp_path, fmu_dir, "0.0844", "mm", 'm="1" factor="0.001"')
    with pytest.raises(ScenarioError, match=r"plant\.m'.*unit mismatch.*\[mm\] \(m\).*Maglev\.fmu declares m in \[kg\] \(kg\)"):
        binding.parameter_values(scenario, instances, {})


def test_connection_between_different_dimensions_is_refused(fmu_dir, tmp_path):
    """The issue's case: plant.q [m] wired to controller.p [kg.m/s]."""
    folder = scenario_copy(tmp_path, "maglev_tracking_D0_R2.82")
    ssd = folder / "SystemStructure.ssd"
    text = ssd.read_text()
    text = text.replace('startConnector="q" endElement="controller" endConnector="q"',
                        'startConnector="q" endElement="controller" endConnector="P"')
    text = text.replace('startConnector="p" endElement="controller" endConnector="p"',
                        'startConnector="p" endElement="controller" endConnector="q"')
    ssd.write_text(text.replace('endConnector="P"', 'endConnector="p"'))
    scenario = read_scenario(folder, fmu_dir=fmu_dir)
    with pytest.raises(ScenarioError, match=r"unit mismatch: connection plant\.q \[m\] \(m\) -> controller\.p "
                                            r"\[kg\.m/s\] \(kg\.m\.s-1\)"):
        binding.check_connections(scenario, binding.load(scenario))


def loop_with_connector_units(loop: Path, suppress: bool = False) -> Path:
    """plant.x declared [m] and ctrl.x [mm] on the .ssd's connectors (the toy FMUs declare no units)."""
    ssd = loop / "SystemStructure.ssd"
    text = ssd.read_text()
    output, input_ = '<ssd:Connector name="x" kind="output">', '<ssd:Connector name="x" kind="input">'
    text = text.replace(f'{output}<ssc:Real/>', f'{output}<ssc:Real unit="m"/>')
    text = text.replace(f'{input_}<ssc:Real/>', f'{input_}<ssc:Real unit="mm"/>')
    text = text.replace("  <ssd:DefaultExperiment", '  <ssd:Units><ssc:Unit name="m"><ssc:BaseUnit m="1"/></ssc:Unit>'
                        '<ssc:Unit name="mm"><ssc:BaseUnit m="1" factor="0.001"/></ssc:Unit></ssd:Units>\n'
                        "  <ssd:DefaultExperiment")
    if suppress:
        text = text.replace('endConnector="x"/>', 'endConnector="x" suppressUnitConversion="true"/>')
    ssd.write_text(text)
    return loop


@pytest.mark.parametrize("suppress", [False, True])
def test_connection_units_are_converted(tmp_path, toys, suppress):
    """ctrl.x in mm = 1000 plant.x in m; with k = -1e-3 per mm the loop is x' = -x: x_n = 0.99^n.
    suppressUnitConversion="true" passes the number as it is (SSP)."""
    loop = loop_with_connector_units(toy_loop(tmp_path / "units", toys, k=-1e-3), suppress)
    r = master.simulate(read_scenario(loop), record=["plant.x", "ctrl.x"])
    scale = 1.0 if suppress else 1000.0
    np.testing.assert_allclose(r["ctrl.x"], scale * r["plant.x"], rtol=1e-15)
    np.testing.assert_allclose(r["plant.x"], (1 - 1e-5 * scale) ** np.arange(101), rtol=1e-12)
    # by default a converted input differs from its source and is recorded; a suppressed one is its source's value
    assert ("ctrl.x" in master.simulate(read_scenario(loop)).columns) == (not suppress)


def test_set_on_a_connected_input_is_refused(loop, tmp_path, capsys):
    line = error_line(["run", str(loop), "--set", "ctrl.x=5", "-o", str(tmp_path / "r.csv")], capsys)
    assert "--set ctrl.x: input is connected (fed by plant.x)" in line, line


COMMENT = {"UTF-16": "Verstärkung, ゲイン", "ISO-8859-1": "Verstärkung", "windows-1252": "Verstärkung – gain",
           "Shift_JIS": "ゲイン (gain)"}


@pytest.mark.parametrize("encoding", list(COMMENT))
def test_xml_in_any_declared_encoding_is_read(loop, tmp_path, encoding):
    reference = master.simulate(read_scenario(loop))
    for name in ("SystemStructure.ssd", "ctrl.ssv", "plant.ssv"):
        path = loop / name
        text = path.read_text().replace('encoding="UTF-8"', f'encoding="{encoding}"')
        path.write_bytes(text.replace("?>\n", f"?>\n<!-- {COMMENT[encoding]} -->\n", 1).encode(encoding))
    scenario = read_scenario(loop)
    assert scenario.notes[0] == COMMENT[encoding]
    assert master.simulate(scenario).rows == reference.rows


# ---- 7. archives ------------------------------------------------------------------------------------

def rewrite_archive(archive: Path, ssd_edit=None, extra: dict[str, bytes] | None = None) -> Path:
    out = archive.with_name("edited.ssp")
    with zipfile.ZipFile(archive) as z, zipfile.ZipFile(out, "w", zipfile.ZIP_DEFLATED) as w:
        for item in z.infolist():
            data = z.read(item)
            if item.filename == "SystemStructure.ssd" and ssd_edit:
                data = ssd_edit(data.decode()).encode()
            w.writestr(item, data)
        for name, data in (extra or {}).items():
            w.writestr(name, data)
    return out


def test_ssp_archive_limits(loop, tmp_path, capsys):
    archive = pack_ssp(loop, tmp_path / "loop.ssp")
    bomb = rewrite_archive(archive, extra={"resources/zeros.bin": bytes(5 << 20)})
    assert bomb.stat().st_size < archive.stat().st_size + 50_000               # 5 MiB of zeros pack to ~5 kB
    line = error_line(["run", str(bomb), "--ssp-max-size", "4", "-o", str(tmp_path / "r.csv")], capsys)
    assert re.search(r"unpacks to [67] MiB, more than the limit of 4 MiB", line) and "--ssp-max-size" in line, line
    line = error_line(["run", str(bomb), "--ssp-max-files", "3", "-o", str(tmp_path / "r.csv")], capsys)
    assert "holds 6 files, more than the limit of 3" in line, line
    assert run(["run", str(bomb), "-o", str(tmp_path / "r.csv")], capsys)[0] == 0      # the defaults: 2 GiB


@pytest.mark.parametrize("reference", ["absolute FMU", "FMU above", "parameters above"])
def test_ssp_references_outside_the_archive_are_refused(loop, toys, tmp_path, capsys, reference):
    archive = pack_ssp(loop, tmp_path / "loop.ssp")
    outside = tmp_path / "outside"
    outside.mkdir()
    shutil.copy(loop / "ctrl.ssv", outside / "ctrl.ssv")
    edit = {"absolute FMU": lambda t: t.replace('source="resources/ToyGain.fmu"', f'source="{toys["gain"]}"'),
            "FMU above": lambda t: t.replace('source="resources/ToyGain.fmu"', 'source="../../../../../../../..'
                                             f'{toys["gain"]}"'),
            "parameters above": lambda t: t.replace('source="ctrl.ssv"', f'source="../../../../../../../..{outside}/ctrl.ssv"')}
    edited = rewrite_archive(archive, edit[reference])
    line = error_line(["run", str(edited), "-o", str(tmp_path / "r.csv")], capsys)
    assert "points outside the archive" in line and "--allow-external" in line, line
    assert run(["run", str(edited), "--allow-external", "-o", str(tmp_path / "r.csv")], capsys)[0] == 0
    assert math.isclose(read_csv(tmp_path / "r.csv")["plant.x"][-1], 0.99 ** 100, rel_tol=1e-12)
