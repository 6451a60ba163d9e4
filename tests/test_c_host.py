"""The FMUs in C hosts (tests/fixtures/c_host.c, c_loop.c, c_calls.c) started with an empty environment
(`env -i`: no libpython linked or preloaded, no PYTHONHOME or PYTHONPATH), as Simulink, OpenModelica or
libcosim load them: the FMU's loader starts the Python that build.py recorded. Each FMU runs, its outputs
equal components/ for the same inputs, and the host process exits with status 0. The derivative
functions, the recorded Python (moved away: one message; EMCOSIM_FMU_PYTHON) and the loader's binary
are checked here too.

Before the exit handler the loader registers (pythonfmu's finalizePythonInterpreter, registered right
after its library is loaded), most C-host processes crashed at exit (SIGSEGV in Py_Finalize, which
pythonfmu 0.7.0 ran after numpy's libraries had shut down; docs/reliability.md, finding 1): 10 of 12
runs of MEMS_Proposition1 here. Each controller runs twice, once with dlclose before exit, once without.
"""
from __future__ import annotations

import math
import subprocess
import sys
import sysconfig
from pathlib import Path

import pytest
from fmpy import read_model_description

from components import catalog, maglev, mems, references
from components.plant_step import PlantStepper

from .c_host import (
    CONTROLLER_INPUTS,
    LOOP_SOURCE,
    THREADS_SOURCE,
    compile_c_host,
    extract,
    last_inputs,
    run_calls,
    run_in_c_host,
    run_loop_in_c_host,
    threads_command,
    toy_fmus,
)

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


# ---- the loader --------------------------------------------------------------------------------------
@pytest.fixture(scope="module")
def toys(tmp_path_factory) -> dict[str, Path]:
    return toy_fmus(tmp_path_factory.mktemp("toys"))


def test_fmu_binary_links_no_python(fmus, tmp_path):
    """The FMU's binary needs libc only: no libpython among its needed libraries, no undefined Python
    symbol (what made a plain C host fail at dlopen before)."""
    folder, _ = extract(fmus["MEMS"], tmp_path)
    binary = folder / "binaries" / "linux64" / "MEMS.so"
    needed = subprocess.run(["readelf", "-d", str(binary)], capture_output=True, text=True, check=True).stdout
    assert [line.split("[")[1].rstrip("]") for line in needed.splitlines() if "(NEEDED)" in line] == ["libc.so.6"]
    undefined = subprocess.run(["nm", "-D", "--undefined-only", str(binary)], capture_output=True, text=True,
                               check=True).stdout.split()
    assert not [name for name in undefined if name.startswith(("Py", "_Py"))]


def _statuses(lines: list[list[str]]) -> list[tuple[str, int]]:
    return [(words[0], int(words[1])) for words in lines if len(words) > 1 and words[0] != "inst"]


def test_derivative_functions_in_c_host(c_calls, toys, tmp_path):
    """fmi2SetRealInputDerivatives, fmi2GetRealOutputDerivatives and fmi2GetDirectionalDerivative from C:
    the toy integrator's polynomial input and output derivatives, the toy gain's Jacobian (known answers,
    tests/fixtures/emcosim_toy_derivatives.py); a bad order is refused with fmi2Error and a message."""
    folder, vr = extract(toys["DerivativeIntegrator"], tmp_path)
    u, x = vr["u"], vr["x"]
    run, lines = run_calls(c_calls, folder, ["inst", "init", "setr", str(u), "2", "dset", str(u), "1", "3",
                                             "dset", str(u), "2", "4", "step", "0", "0.5", "getr", str(x),
                                             "dget", str(x), "1", "dget", str(x), "2", "dset", str(u), "3", "1",
                                             "step", "0.5", "0.5", "getr", str(x), "free"])
    assert run.returncode == 0, run.stderr[-1500:]
    assert lines[0] == ["inst", "0"]
    assert [status for _, status in _statuses(lines)] == [0, 0, 0, 0, 0, 0, 0, 0, 3, 0, 0]
    x1 = 1.0 + 2.0 * 0.5 + 3.0 * 0.5**2 / 2 + 4.0 * 0.5**3 / 6
    assert float(lines[6][2]) == pytest.approx(x1, rel=1e-15)
    assert [float(lines[7][2]), float(lines[8][2])] == [2.0 + 1.5 + 0.5, 3.0 + 2.0]
    assert float(lines[11][2]) == pytest.approx(x1 + 2.0 * 0.5, rel=1e-15)     # held u = 2, derivatives cleared
    assert "order 3 for input u is not in 1..2" in run.stderr
    folder, vr = extract(toys["DerivativeGain"], tmp_path)
    x, y = vr["x"], vr["y"]
    run, lines = run_calls(c_calls, folder, ["inst", "init", "jac", str(y), str(x), "2", "dset", str(x), "1", "7",
                                             "dget", str(y), "1", "jac", str(x), str(y), "1", "free"])
    assert run.returncode == 0, run.stderr[-1500:]
    assert lines[2:5] == [["jac", "0", "6"], ["dset", "0"], ["dget", "0", "21"]]     # k = 3
    assert lines[5][:2] == ["jac", "3"] and "unknown valueReference 1 (input x) is not a Real output" in run.stderr


# ---- the recorded Python -------------------------------------------------------------------------------
def _throwaway_python(where: Path, with_numpy: bool = True) -> Path:
    """A new venv (quick: no pip) whose site-packages see this environment's packages through a .pth file
    when `with_numpy` (numpy and scipy); returns its interpreter."""
    subprocess.run([sys.executable, "-m", "venv", "--without-pip", str(where)], check=True, capture_output=True)
    minor = "python{}.{}".format(*sys.version_info[:2])
    if with_numpy:
        (where / "lib" / minor / "site-packages" / "environment.pth").write_text(sysconfig.get_paths()["purelib"] + "\n")
    return where / "bin" / "python"


def _record(folder: Path, **changes: str) -> None:
    path = folder / "resources" / "emcosim_fmu.txt"
    lines = [f"{line.split(' = ')[0]} = {changes[line.split(' = ')[0]]}" if line.split(" = ")[0] in changes else line
             for line in path.read_text().splitlines()]
    path.write_text("\n".join(lines) + "\n")


def _logged(stderr: str) -> list[str]:
    """The lines the FMU logged through the host's logger (c_calls.c prints them as "[instance] status ...")."""
    return [line for line in stderr.splitlines() if line.startswith("[")]


def test_recorded_python_is_used_and_a_missing_one_is_named_in_one_message(c_calls, fmus, tmp_path):
    """An FMU pointed at a throwaway venv runs from it in a C host under env -i; with that venv moved away,
    fmi2Instantiate returns NULL and logs one message naming the missing interpreter and the variable to
    set (no crash, no loader error); EMCOSIM_FMU_PYTHON set to a working interpreter fixes it."""
    folder, vr = extract(fmus["MEMS_Proposition1"], tmp_path)
    python = _throwaway_python(tmp_path / "throwaway")
    _record(folder, python_executable=str(python))
    calls = ["inst", "init", "setr", str(vr["q"]), "2e-5", "getr", str(vr["u"]), "free"]
    run, lines = run_calls(c_calls, folder, calls)
    assert run.returncode == 0 and lines[0] == ["inst", "0"], run.stderr[-1500:]
    u = float(lines[3][2])
    (tmp_path / "throwaway").rename(tmp_path / "moved")
    run, lines = run_calls(c_calls, folder, calls[:1])
    assert run.returncode == 0 and lines == [["inst", "null"]], run.stderr[-1500:]
    logged = _logged(run.stderr)
    assert len(logged) == 1 and run.stderr.strip() == logged[0], run.stderr
    assert str(python) in logged[0] and "EMCOSIM_FMU_PYTHON" in logged[0] and "does not exist" in logged[0]
    assert " 3 logStatusError: " in logged[0]                               # fmi2Error
    run, lines = run_calls(c_calls, folder, calls, env={"EMCOSIM_FMU_PYTHON": sys.executable})
    assert run.returncode == 0 and lines[0] == ["inst", "0"] and float(lines[3][2]) == u, run.stderr[-1500:]


def test_python_without_numpy_is_named_in_one_message(c_calls, fmus, tmp_path):
    folder, _ = extract(fmus["Reference"], tmp_path)
    python = _throwaway_python(tmp_path / "bare", with_numpy=False)
    run, lines = run_calls(c_calls, folder, ["inst"], env={"EMCOSIM_FMU_PYTHON": str(python)})
    assert run.returncode == 0 and lines == [["inst", "null"]], run.stderr[-1500:]
    logged = _logged(run.stderr)
    assert len(logged) == 1 and run.stderr.strip() == logged[0], run.stderr
    assert all(w in logged[0] for w in (str(python), "cannot import numpy", "EMCOSIM_FMU_PYTHON")), logged[0]


def test_bad_calls_in_c_host_are_refused_and_the_host_survives(c_calls, fmus, tmp_path):
    """Issue 15, item 5, in a C host: a changed and a doubled deserialization, a state pointer no FMU
    gave out, doStep after fmi2Terminate and fmi2FreeInstance twice get fmi2Error (or are ignored);
    the instance keeps working in between, a new one works after, and the host exits with status 0."""
    folder, vr = extract(fmus["MEMS_Theorem2"], tmp_path)
    run, lines = run_calls(c_calls, folder, [
        "inst", "init", "sget", "ser", "flip", "60", "deser", "deser", "step", "0", "1e-6", "sbogus",
        "setr", str(vr["u"]), "1", "getr", "999", "term", "step", "1e-6", "1e-6", "free", "free", "inst", "init",
        "step", "0", "1e-6", "free"])
    assert run.returncode == 0, run.stderr[-1500:]
    assert [w[:2] for w in lines] == [
        ["inst", "0"], ["init", "0"], ["sget", "0"], ["ser", "0"], ["deser", "3"], ["deser", "3"], ["step", "0"],
        ["sbogus", "3"], ["setr", "3"], ["getr", "3"], ["term", "0"], ["step", "3"], ["free"], ["free"],
        ["inst", "0"], ["init", "0"], ["step", "0"], ["free"]]
    for words in ("checksum mismatch", "not a state this FMU gave out", "u is an output",
                  "valueReference 999 (unknown) is not a Real variable", "fmi2DoStep after fmi2Terminate",
                  "fmi2FreeInstance called with an unknown or freed instance"):
        assert words in run.stderr, (words, run.stderr)


def test_instantiate_refuses_another_builds_guid_in_one_message(c_calls, fmus, tmp_path):
    """The GUID passed to fmi2Instantiate must be the FMU's (an empty one is accepted): the
    modelDescription.xml a host read and the binary it loaded must come from one build."""
    folder, _ = extract(fmus["Reference"], tmp_path)
    md = read_model_description(str(folder / "modelDescription.xml"))
    exe = [str(c_calls), str(folder / "binaries" / "linux64" / "Reference.so"), "Reference", (folder / "resources").as_uri()]
    for guid, expected in (("{00000000-0000-0000-0000-000000000000}", "null"), ("", "0"), (md.guid, "0")):
        run = subprocess.run(["env", "-i", *exe, guid, "inst"], capture_output=True, text=True, timeout=300)
        assert run.returncode == 0 and run.stdout.split() == ["inst", expected], (guid, run.stdout, run.stderr)
    assert len(_logged(run.stderr)) == 0
    run = subprocess.run(["env", "-i", *exe, "{00000000-0000-0000-0000-000000000000}", "inst"], capture_output=True,
                         text=True, timeout=300)
    assert len(_logged(run.stderr)) == 1 and md.guid in run.stderr and "is not this FMU's" in run.stderr


# ---- issue 26, item 7: concurrent hosts and loggers that call back ------------------------------------
OUTPUT_READ = {"MEMS": "q", "Maglev": "q", "Reference": "q_star", "MEMS_Proposition1": "u", "MEMS_Theorem2": "u",
               "Maglev_Proposition2": "u", "Maglev_Theorem3": "u"}
PAIRS = [("MEMS", "MEMS_Proposition1"), ("Maglev", "Maglev_Theorem3"), ("Reference", "MEMS_Theorem2"),
         ("Maglev_Proposition2", "MEMS"), ("MEMS_Theorem2", "Maglev"), ("Maglev_Theorem3", "Reference"),
         ("MEMS_Proposition1", "Maglev_Proposition2")]
ROUNDS = 50                                      # processes, each starting Python from two threads at once


@pytest.fixture(scope="module")
def c_threads(tmp_path_factory) -> Path:
    exe = tmp_path_factory.mktemp("c_threads") / "c_threads"
    reason = compile_c_host(exe, THREADS_SOURCE)
    if reason:
        pytest.skip(reason)
    return exe


def _one_at_a_time(c_calls, folder: Path, output: str) -> float:
    """The output after fmi2Instantiate, initialization and one doStep of 1e-6 s, alone in a C host."""
    vr = {v.name: v.valueReference for v in read_model_description(str(folder / "modelDescription.xml")).modelVariables}
    run, lines = run_calls(c_calls, folder, ["inst", "init", "step", "0", "1e-6", "getr", str(vr[output]), "free"])
    assert run.returncode == 0 and lines[3][1] == "0", run.stderr[-1500:]
    return float(lines[3][2])


@pytest.mark.slow      # 8-21 s: in the full set, out of the quick one (issue 33)
def test_two_different_fmus_instantiated_at_once_from_two_threads(c_threads, c_calls, fmus, tmp_path):
    """Issue 26, item 7: a C host without Python instantiates two different emcosim FMUs at the same moment
    from two threads. Every FMU binary had its own lock around starting Python, so both loaders started it
    at once: SIGSEGV, "double free or corruption" or "Python did not start" in 11 of 11 processes. The
    loaders now share one lock per process (the first loaded copy's, found by the loader's SONAME). 50
    processes, the 7 FMUs in 7 pairs, each process 3 rounds (the first races the start of Python, the next
    ones the creation of instances): every process exits with status 0 and every round gives the output
    of the FMU run alone, bit for bit."""
    folders = {identifier: extract(fmus[identifier], tmp_path)[0] for identifier in fmus}
    alone = {identifier: _one_at_a_time(c_calls, folders[identifier], OUTPUT_READ[identifier]) for identifier in fmus}
    commands = [threads_command(c_threads, [folders[a], folders[b]], [OUTPUT_READ[a], OUTPUT_READ[b]], 3)
                for a, b in (PAIRS[k % len(PAIRS)] for k in range(ROUNDS))]
    failed = []
    for start in range(0, ROUNDS, 2):                                # two processes at a time
        running = [(k, subprocess.Popen(commands[k], stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True))
                   for k in range(start, min(start + 2, ROUNDS))]
        for k, process in running:
            out, err = process.communicate(timeout=300)
            pair = PAIRS[k % len(PAIRS)]
            rows = [line.split() for line in out.splitlines()]
            got = [(int(r[4]), float(r[5])) for r in rows if r[0] == "round"]
            if process.returncode != 0 or got != [(0, alone[pair[int(r[3])]]) for r in rows if r[0] == "round"] \
                    or len(got) != 6:
                failed.append((k, pair, process.returncode, got, err[-300:]))
    assert not failed, f"{len(failed)} of {ROUNDS} processes failed; the first: {failed[0]}"


def test_logger_that_calls_back_into_the_instance_does_not_crash_the_host(c_calls, fmus, tmp_path):
    """Issue 26, item 7: a host's logger that calls back into the instance that is logging (here
    fmi2GetReal and an fmi2SetReal that is refused, so it logs again inside) crashed the loader: the
    call-back drained the log queue while the outer call still read it by index (SIGSEGV). A controller
    with a NaN input logs two messages in doStep. The host exits with status 0, every message reaches it
    once, fmi2Reset and fmi2FreeInstance from inside the logger are refused with a message (they would
    free what the call in progress uses), and the instance works on: a finite input gives a finite u."""
    folder, vr = extract(fmus["MEMS_Proposition1"], tmp_path)
    u, q = str(vr["u"]), str(vr["q"])
    run, lines = run_calls(c_calls, folder, ["inst", "init", "reenter", u, "reenter_free", "setr", q, "nan",
                                             "step", "0", "1e-6", "getr", u, "setr", q, "1.5e-5", "step", "0", "1e-6",
                                             "getr", u, "free"])
    assert run.returncode == 0, f"exit status {run.returncode}: {run.stderr[-1500:]}"
    assert ["step", "2"] in lines and ["step", "0"] in lines, lines
    called_back = [w for w in lines if w[0] == "logger-called-back"]
    assert called_back and all(w[1:3] == ["3", "3"] for w in called_back), called_back
    assert all(w == ["logger-reset", "3"] for w in lines if w[0] == "logger-reset")
    last = [w for w in lines if w[0] == "getr"][-1]
    assert last[1] == "0" and math.isfinite(float(last[2])), lines
    doubled = [m for m in _logged(run.stderr) if "(doStep at t = 0 s)" in m]
    assert len(doubled) == 1, doubled                                # once: the queue is read once
    for words in ("fmi2Reset called while another call of this instance is in progress",
                  "fmi2FreeInstance called while another call of this instance is in progress"):
        assert words in run.stderr, (words, run.stderr[-1500:])
