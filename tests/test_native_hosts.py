"""The seven native FMUs (fmus/native_build.py) in this project's plain C hosts started with an empty
environment (`env -i`), as both interfaces: what fmusim and the FMU Compliance Checker do by hand
(docs/fmus.md, "Native FMUs in other tools"), which CI cannot build (no network beyond package registries).

- Co-Simulation: tests/fixtures/c_host.c (set + doStep + get, 200 steps with inputs varied by 1 %);
- Model Exchange: tests/fixtures/c_me_host.c (RK4 of the plants' states) and tests/fixtures/c_calls.c
  (`instme`: the controllers' u and the Reference's jet after fmi2SetTime, no states);
- the example devices' native FMUs (`emcosim plant build --native`) the same way, at the end.

Truths: components/ (the laws' scalar forms, PlantStepper, components.references) and scipy's Radau on
`EMPlant.f`, the same as the pythonfmu FMUs meet in tests/test_c_host.py and tests/test_model_exchange.py.
Every run must exit with status 0 and log nothing (no warning, no error) on stderr.
"""
from __future__ import annotations

import math
import shutil
import subprocess
from pathlib import Path

import numpy as np
import pytest
from fmpy import read_model_description

from components import catalog, maglev, mems, references
from components.plant_step import PlantStepper, nominal_scale

from .c_host import (
    CALLS_SOURCE,
    CONTROLLER_INPUTS,
    compile_c_host,
    extract,
    last_inputs,
    run_calls,
    run_in_c_host,
)
from .test_model_exchange import ME_HOST, STATES, components_plant, components_solution, run_c_me_host, starts

pytestmark = [pytest.mark.skipif(shutil.which("gcc") is None, reason="needs gcc"),
              pytest.mark.slow]                    # 14 s of CPU, most of it building the FMUs
N = 200
PLANT_RUNS = {"MEMS": ({"u": 25.0}, 1e-6), "Maglev": ({"u": 0.009045}, 1e-4)}


@pytest.fixture(scope="module")
def native(tmp_path_factory) -> dict[str, Path]:
    """The seven native FMUs, as `build.py --native` makes them."""
    from fmus.native_build import build_native, build_native_controller, build_native_reference
    dest = tmp_path_factory.mktemp("native_hosts")
    fmus = {name: build_native(name, dest) for name in PLANT_RUNS}
    fmus.update({name: build_native_controller(name, dest) for name in CONTROLLER_INPUTS})
    fmus["Reference"] = build_native_reference(dest)
    return fmus


@pytest.fixture(scope="module")
def hosts(tmp_path_factory) -> dict[str, Path]:
    folder = tmp_path_factory.mktemp("native_c_hosts")
    exes = {}
    for name, source in (("cs", None), ("me", ME_HOST), ("calls", CALLS_SOURCE)):
        exes[name] = folder / name
        reason = compile_c_host(exes[name], source) if source else compile_c_host(exes[name])
        if reason:
            pytest.skip(reason)
    return exes


def _clean(run) -> None:
    assert run.returncode == 0 and run.stderr == "", f"exit status {run.returncode}: {run.stderr[-1500:]}"


@pytest.mark.parametrize("identifier", list(CONTROLLER_INPUTS))
def test_native_controller_in_c_host_co_simulation(hosts, native, tmp_path, identifier):
    start = CONTROLLER_INPUTS[identifier]
    run, values = run_in_c_host(hosts["cs"], native[identifier], tmp_path, start, ["u"], 1e-6, N)
    _clean(run)
    x = last_inputs(start, N)
    expected = catalog.controller(identifier).u_scalar(x[0], x[1], x[2], tuple(x[3:]) if len(x) > 3 else None)
    assert values[2] == pytest.approx(expected, rel=1e-12), identifier


@pytest.mark.parametrize("identifier", list(PLANT_RUNS))
def test_native_plant_in_c_host_co_simulation(hosts, native, tmp_path, identifier):
    """50 steps with u varied by 1 %: the native RODAS4 (rtol 1e-8) against PlantStepper at the FMU's
    starts; they agree to 1e-9 of the trajectory over the DefaultExperiment (tests/test_native_fmus.py)."""
    inputs, h = PLANT_RUNS[identifier]
    run, values = run_in_c_host(hosts["cs"], native[identifier], tmp_path, inputs, ["q", "p", "x_e", "H"], h, n=50)
    _clean(run)
    start = {v.name: float(v.start) for v in read_model_description(str(native[identifier])).modelVariables
             if v.start is not None}
    module = mems if identifier == "MEMS" else maglev
    plant = catalog.plant(identifier, {n: start[n] for n in module.PARAMETERS})
    stepper = PlantStepper(plant, rtol=start["rtol"])
    eta = (start["q_0"], start["p_0"], start["x_e_0"])
    for k in range(50):
        eta = stepper.advance(*eta, inputs["u"] * (1.0 + 0.01 * math.sin(0.1 * k)), h)
    scale = np.maximum(np.abs([*eta, plant.H(eta)]), [*nominal_scale(plant), abs(plant.H(eta))])
    assert np.all(np.abs(np.array(values[2:]) - [*eta, plant.H(eta)]) <= 1e-8 * scale), (values[2:], eta)


def test_native_reference_in_c_host_co_simulation(hosts, native, tmp_path):
    outputs = ["q_star", "q_star_dot", "q_star_ddot", "q_star_dddot"]
    run, values = run_in_c_host(hosts["cs"], native["Reference"], tmp_path, {}, outputs, 1e-3, n=50)
    _clean(run)
    jet = references.Sinusoid().jet(50 * 1e-3)
    assert values[2:] == pytest.approx([jet.q[0], jet.qd[0], jet.qdd[0], jet.qddd[0]], rel=1e-12)


@pytest.mark.parametrize("identifier, u, h, n", [("MEMS", 25.0, 1e-11, 20000), ("Maglev", 0.0, 1e-4, 2000)])
def test_native_plant_in_c_host_model_exchange(hosts, native, tmp_path, identifier, u, h, n):
    """RK4 of the C host at h and 2h against scipy's Radau on components' EMPlant.f, within the Richardson
    estimate of RK4's error (as tests/test_model_exchange.py does for the pythonfmu plants)."""
    md = read_model_description(str(native[identifier]))
    plant, values = components_plant(identifier, md), starts(md)
    finals = []
    for k in (1, 2):
        run = run_c_me_host(hosts["me"], native[identifier], tmp_path / str(k), k * h, n // k, u)
        _clean(run)
        out = [float(v) for v in run.stdout.split()]
        assert out[1] == pytest.approx(n * h, rel=1e-12) and out[5] > 0      # time reached; inside the domain
        finals.append(np.array(out[2:5]))
    expected = components_solution(plant, [values[f"{s}_0"] for s in STATES], u, n * h)
    scale = np.maximum(np.abs(expected), nominal_scale(plant))
    estimate = np.abs(finals[1] - finals[0]) / 15
    assert np.all(estimate / scale < 1e-6), estimate / scale
    assert np.all(np.abs(finals[0] - expected) <= 3 * estimate + 1e-11 * scale), (finals[0], expected, estimate)


def _me_calls(hosts, fmu: Path, tmp_path: Path, calls: list[str]) -> list[list[str]]:
    folder, _ = extract(fmu, tmp_path)
    run, lines = run_calls(hosts["calls"], folder, ["instme", "init", *calls, "term", "free"])
    _clean(run)
    assert lines[0] == ["instme", "0"] and all(w[1] == "0" for w in lines[1:] if w[0] != "free"), lines
    return lines


@pytest.mark.parametrize("identifier", list(CONTROLLER_INPUTS))
def test_native_controller_in_c_host_model_exchange(hosts, native, tmp_path, identifier):
    """A controller instantiated as Model Exchange: inputs set in event mode and in continuous-time mode,
    u read after each; both equal the law."""
    vr = {v.name: v.valueReference for v in read_model_description(str(native[identifier])).modelVariables}
    start = CONTROLLER_INPUTS[identifier]
    x = last_inputs(start, N)
    calls = [w for k, v in zip(start, x) for w in ("setr", str(vr[k]), repr(v))] + ["getr", str(vr["u"])]
    lines = _me_calls(hosts, native[identifier], tmp_path, [*calls, "nds", "ctm", "time", "0.5", *calls])
    law = catalog.controller(identifier)
    expected = law.u_scalar(x[0], x[1], x[2], tuple(x[3:]) if len(x) > 3 else None)
    got = [float(w[2]) for w in lines if w[0] == "getr"]
    assert len(got) == 2 and got == pytest.approx([expected, expected], rel=1e-12), identifier


def test_native_reference_in_c_host_model_exchange(hosts, native, tmp_path):
    vr = {v.name: v.valueReference for v in read_model_description(str(native["Reference"])).modelVariables}
    jet_names = ["q_star", "q_star_dot", "q_star_ddot", "q_star_dddot"]
    times = [0.0125, 0.3]
    calls = ["nds", "ctm"]
    for t in times:
        calls += ["time", repr(t), *(w for n in jet_names for w in ("getr", str(vr[n])))]
    lines = _me_calls(hosts, native["Reference"], tmp_path, calls)
    got = [float(w[2]) for w in lines if w[0] == "getr"]
    expected = []
    for t in times:
        jet = references.Sinusoid().jet(t)
        expected += [jet.q[0], jet.qd[0], jet.qdd[0], jet.qddd[0]]
    assert got == pytest.approx(expected, rel=1e-12)



@pytest.mark.parametrize("identifier", ["Reference", "MEMS_Proposition1"])
def test_empty_set_calls_are_accepted_after_initialization(hosts, native, tmp_path, identifier):
    """FMI 2.0 allows fmi2SetReal and fmi2SetInteger in step, event and continuous-time mode (for inputs); a
    generic host calls them with nvr = 0 for an FMU without inputs (c_host.c does). The native Reference
    refused the call itself there ("not allowed in step mode"), the controllers fmi2SetInteger; now the
    empty call is fmi2OK in both interfaces and a parameter set after initialization is refused, named."""
    from fmpy import extract as unzip
    from fmpy.fmi2 import FMU2Model, FMU2Slave

    md = read_model_description(str(native[identifier]))
    folder = unzip(str(native[identifier]))
    for cls in (FMU2Slave, FMU2Model):
        fmu = cls(guid=md.guid, unzipDirectory=folder, modelIdentifier=identifier, instanceName="i")
        fmu.instantiate()
        fmu.setupExperiment(startTime=0.0)
        fmu.enterInitializationMode()
        fmu.exitInitializationMode()
        if cls is FMU2Model:
            fmu.newDiscreteStates()
            fmu.enterContinuousTimeMode()
        fmu.setReal([], [])                                  # fmpy raises on a status above fmi2Warning
        fmu.setInteger([], [])
        fmu.terminate()
        fmu.freeInstance()
    vr = {v.name: v.valueReference for v in md.modelVariables}
    real, integer = ("omega", "kind") if identifier == "Reference" else ("q_d", "strict")
    ext, _ = extract(native[identifier], tmp_path)
    run, lines = run_calls(hosts["calls"], ext, ["inst", "init", "setr", str(vr[real]), "1.0", "seti",
                                                 str(vr[integer]), "1", "free"])
    assert run.returncode == 0 and [w[:2] for w in lines] == [["inst", "0"], ["init", "0"], ["setr", "3"],
                                                              ["seti", "3"], ["free"]], (lines, run.stderr)
    for name in (real, integer):
        assert f"the parameter {name} cannot be set in step mode" in run.stderr, run.stderr


# ---- the example devices' native FMUs -----------------------------------------------------------------
EXAMPLES = Path(__file__).resolve().parents[1] / "examples"


@pytest.fixture(scope="module")
def device_fmus(tmp_path_factory) -> dict[str, Path]:
    """`emcosim plant build --native` of a device with n_m = n_e = 1 (Solenoid: plant, Proposition1, Theorem2) and
    of one with n_m = n_e = 2 (LevitatedBar: plant, Proposition2, Theorem3 with Newton in C), each with the
    Reference."""
    from emcosim.devices.build import build_native_fmus_of
    out = tmp_path_factory.mktemp("device_fmus")
    fmus: dict[str, Path] = {}
    for device in ("solenoid", "levitated_bar"):
        fmus.update(build_native_fmus_of(EXAMPLES / device / f"{device}.toml", out))
    return {path.stem: path for path in fmus.values()}


def test_example_device_fmus_in_c_hosts(hosts, device_fmus, tmp_path):
    """Every native FMU the example devices build, in the C hosts under env -i, exit 0 and nothing logged:
    a plant's states after 0.01 s with its inputs held, by RK4 as Model Exchange (c_me_host.c, at h and 2h)
    and by its own RODAS4 as Co-Simulation (c_calls.c), agree within RK4's Richardson estimate plus 1e-7 of
    the state (doStep's rtol is 1e-8); a controller's u equals itself through both interfaces (c_host.c,
    c_calls.c `instme`), bit for bit, at the inputs c_host.c ends with."""
    assert sorted(device_fmus) == ["LevitatedBar", "LevitatedBar_Proposition2", "LevitatedBar_Theorem3", "Reference",
                                   "Solenoid", "Solenoid_Proposition1", "Solenoid_Theorem2"]
    for name, fmu in device_fmus.items():
        if name == "Reference":                          # the paper's Reference: test_native_reference_in_c_host_*
            continue
        md = read_model_description(str(fmu))
        vr = {v.name: v.valueReference for v in md.modelVariables}
        inputs = {v.name: float(v.start) for v in md.modelVariables if v.causality == "input"}
        folder, _ = extract(fmu, tmp_path / "cs")
        if md.derivatives:                                                   # a plant
            states = [d.variable.derivative.name for d in md.derivatives]
            h, n = 1e-5, 1000
            calls = ["inst", "init", "step", "0", repr(n * h), *(w for s in states for w in ("getr", str(vr[s])))]
            run, lines = run_calls(hosts["calls"], folder, [*calls, "free"])
            _clean(run)
            cs = np.array([float(w[2]) for w in lines if w[0] == "getr"])
            me = []
            u_name = next(iter(inputs))                                      # held at its start, as the others
            for k in (1, 2):
                unzipped, _ = extract(fmu, tmp_path / f"me{k}")
                run = subprocess.run(["env", "-i", str(hosts["me"]), str(unzipped / "binaries" / "linux64" / f"{name}.so"),
                                      name, (unzipped / "resources").as_uri(), md.guid, repr(k * h), str(n // k),
                                      str(len(states)), str(md.numberOfEventIndicators), str(vr[u_name]),
                                      repr(inputs[u_name])], capture_output=True, text=True, timeout=300)
                _clean(run)
                out = [float(v) for v in run.stdout.split()]
                assert out[1] == pytest.approx(n * h, rel=1e-12), name
                me.append(np.array(out[2:2 + len(states)]))
            nominal = np.array([float(next(v for v in md.modelVariables if v.name == s).nominal or 1.0) for s in states])
            estimate = np.abs(me[1] - me[0]) / 15
            assert np.all(np.abs(me[0] - cs) <= 3 * estimate + 1e-7 * np.maximum(np.abs(cs), nominal)), (name, me[0], cs)
        else:                                                                # a controller
            u = next(v.name for v in md.modelVariables if v.causality == "output")          # u, or u_1 of several
            run, values = run_in_c_host(hosts["cs"], fmu, tmp_path / "host", inputs, [u], 1e-3, N)
            _clean(run)
            x = last_inputs(inputs, N)
            calls = [w for k, v in zip(inputs, x) for w in ("setr", str(vr[k]), repr(v))] + ["getr", str(vr[u])]
            lines = _me_calls(hosts, fmu, tmp_path / "me", calls)
            assert float(lines[-3][2]) == values[2], (name, lines, values)
