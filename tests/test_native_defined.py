"""Issue 40, "Generated C is defined for every input": the native FMUs (fmus/native, components.c_codegen) and their
pythonfmu twins refuse, with one log line, what they cannot compute, and every loop ends.

Truths: the FMI 2.0 statuses a C host sees (tests/fixtures/c_calls.c in a subprocess: a crash is a signal, not a
failed assertion), a wall-clock limit (a loop that never ends is a timeout), the values double arithmetic gives
(0 x inf = NaN, 1e308 + 1e308 = inf), and the pythonfmu twin called in-process.
"""
from __future__ import annotations

import hashlib
import math
import shutil
import tempfile
from pathlib import Path

import numpy as np
import pytest
from fmpy import read_model_description

from .c_host import extract, run_calls

pytestmark = pytest.mark.skipif(shutil.which("gcc") is None, reason="needs gcc")
OK, WARNING, DISCARD, ERROR = 0, 1, 2, 3
EXAMPLES = Path(__file__).resolve().parent.parent / "examples"


def _statuses(lines: list[list[str]]) -> list[tuple[str, int]]:
    return [(words[0], int(words[1])) for words in lines if len(words) > 1 and words[0] not in ("inst", "instme")]


def _errors(stderr: str) -> list[str]:
    return [line for line in stderr.splitlines() if "logStatusError" in line or "logStatusDiscard" in line]


def twin_slaves(toml: Path, designs: list[str]) -> dict:
    """The pythonfmu twins of a description's FMUs (fmus.models.device_slave_classes, what `emcosim plant build`
    packs), instantiated in-process: model identifier -> slave."""
    from components import codegen
    from components.description import load
    from fmus.build import load_device_module
    from fmus.models import device_slave_classes

    desc = load(toml)
    with tempfile.TemporaryDirectory() as tmp:
        module = Path(tmp) / f"{desc.name.lower()}_model.py"
        module.write_text(codegen.module_source(desc, toml.name))
        classes = device_slave_classes(load_device_module(module), designs,
                                       model=hashlib.sha256(toml.read_bytes()).hexdigest())
        return {name: cls(instance_name="twin", resources=tmp) for name, cls in classes.items()}


def _initialized(slave, interface: int = 1, start: float = 0.0):
    assert slave.fmi2_set_interface(interface)[0] == OK
    assert slave.fmi2_setup_experiment(0, 0.0, start, 0, 0.0)[0] == OK
    assert slave.fmi2_enter_initialization_mode()[0] == OK
    status = slave.fmi2_exit_initialization_mode()
    assert status[0] == OK, status
    return slave


# ---- item 2: the least-energy operating point at a jet where every cost is NaN ----------------------------------
# The two-magnet ball with a spring and damping under the least-energy point (tests/test_native_fmus._damped_ball),
# with the legal k = 4: at q* = 5e-324, q*' = q*'' = -1.7e308 the force F* = m q*'' + d_m q*' + ... is finite
# (-1e308) but w = x_e^2 = -F* / A_11 overflows to inf on the lower coil, whose cost Psi_22(q*) = q*/k is 0:
# 0 x inf = NaN. On main no branch was chosen and the C read BRANCH_SIZE[-1] (a made-up u with fmi2OK) and called
# DSTATE[-1] (SIGSEGV).
JET = {"q_star": "5e-324", "q_star_dot": "-1.7e308", "q_star_ddot": "-1.7e308"}


def _ball(folder: Path) -> Path:
    from tests.test_native_fmus import _damped_ball

    toml = folder / "ball.toml"
    toml.write_text(_damped_ball('Psi = [["(c - q)/k", "0"], ["0", "q/k"]]').replace("k   = [0.64042,", "k   = [4.0,"))
    return toml


@pytest.fixture(scope="module")
def least_ball(tmp_path_factory) -> tuple[Path, Path]:
    """(the description, its native Theorem 2 controller) of the damped ball with the least-energy point, k = 4."""
    from fmus.native_build import build_native_description_fmus

    folder = tmp_path_factory.mktemp("least_ball")
    toml = _ball(folder)
    paths = build_native_description_fmus(toml, ["Theorem2"], folder / "fmus")
    return toml, paths["TwoMagnetBall_Theorem2"]


def test_a_jet_with_no_comparable_cost_is_refused_not_a_wild_call(c_calls, least_ball, tmp_path) -> None:
    """fmi2GetReal, fmi2GetDirectionalDerivative and fmi2GetRealOutputDerivatives answer fmi2Error, doStep fmi2Discard,
    each with one log line naming the overflow; the host process ends normally (on main: SIGSEGV), and the same
    instance answers at an ordinary jet again."""
    folder, vr = extract(least_ball[1], tmp_path)
    u_1, q_star = str(vr["u_1"]), str(vr["q_star"])
    calls = ["inst", "init"]
    for name, value in JET.items():
        calls += ["setr", str(vr[name]), value]
    calls += ["getr", u_1, "jac", u_1, q_star, "1.0", "dget", u_1, "1", "step", "0", "0.01"]
    calls += ["setr", q_star, "0.005", "setr", str(vr["q_star_dot"]), "0", "setr", str(vr["q_star_ddot"]), "0",
              "getr", u_1, "jac", u_1, q_star, "1.0"]
    run, lines = run_calls(c_calls, folder, calls)
    assert run.returncode == 0, (run.returncode, run.stderr[-2000:])
    statuses = [s for _, s in _statuses(lines)]
    assert statuses == [OK] * 4 + [ERROR, ERROR, ERROR, DISCARD] + [OK] * 5, lines
    errors = _errors(run.stderr)
    assert len(errors) == 4 and all("is not finite at this jet (an overflow)" in e for e in errors), run.stderr
    assert all(math.isfinite(float(words[2])) for words in lines[-2:])


def test_the_twin_refuses_the_same_jet(least_ball) -> None:
    """The pythonfmu twin of the same law (components.operating_point.solve through the generated device) refuses the
    jet for the same reason: a branch's cost is not finite; u is never NaN with fmi2OK."""
    slave = _initialized(twin_slaves(least_ball[0], ["Theorem2"])["TwoMagnetBall_Theorem2"])
    vr = {v.name: i for i, v in enumerate(slave.variables)}
    assert slave.fmi2_set_real([vr[k] for k in JET], [float(v) for v in JET.values()])[0] == OK
    status, values, message = slave.fmi2_get_real([vr["u_1"]])
    assert status == ERROR, (status, values, message)
    u, reason = slave.compute_u_vector()                        # what the twin logs beside the refusal
    assert "the cost of the ports (1,) is not finite" in reason and all(math.isnan(v) for v in u), reason
    status, _, message = slave.fmi2_get_directional_derivative([vr["u_1"]], [vr["q_star"]], [1.0])
    assert status == ERROR, message


def test_operating_point_solve_refuses_a_cost_that_is_not_finite() -> None:
    """components.operating_point.solve (the twin's choice, which the C copies): a vertex whose cost is 0 x inf is no
    cost at all; on main it was kept, and min() over NaN chose by the order of the vertices."""
    from components.operating_point import NoOperatingPoint, Rule, solve

    A = np.array([[-0.125, 0.125]])
    psi = np.array([1e-300, 0.0])
    with pytest.raises(NoOperatingPoint, match="not finite"):
        solve(Rule(given=False), A, np.array([1.7e308]), psi, 1.0)
    with pytest.raises(NoOperatingPoint, match="not finite"):
        solve(Rule(given=False), A, np.array([math.inf]), psi, 1.0)
    x, branch = solve(Rule(given=False), A, np.array([1.0]), np.array([1.0, 2.0]), 1.0)
    assert branch == (1,) and x[1] == pytest.approx(math.sqrt(8.0))


def test_generated_least_reference_reads_its_tables_at_checked_indices(least_ball) -> None:
    """Every read of BRANCH_SIZE, STATE and DSTATE at the chosen branch follows the check that one was chosen
    (components.c_codegen._LEAST_REFERENCE)."""
    from components.c_codegen import _LEAST_REFERENCE

    check = _LEAST_REFERENCE.index("if (chosen < 0 || chosen >= NT) return NO_BRANCH;")
    for use in ("BRANCH_SIZE[chosen]", "DSTATE[chosen]"):
        assert _LEAST_REFERENCE.index(use) > check
    assert "if (!isfinite(cost[v])) return OVERFLOW;" in _LEAST_REFERENCE
    assert read_model_description(str(least_ball[1])).generationTool.startswith("emcosim native C generator")


# ---- item 3: the boundary-distance bisection ends (a boundary nearer than the least subnormal) ----------------------
# The levitated bar with the domain c - z -+ 1e100 l^2 theta > 0 and the legal c = 1e-100, l = 1e100: along theta the
# boundary lies at 1e-100 / 1e300 = 1e-400, below the least subnormal 4.9e-324. Bisecting [0, 1e-12] ends at
# [0, 4.9e-324], whose midpoint rounds to 0: on main `while (high - low > 1e-3 * high)` never ended, in C at
# fmi2ExitInitializationMode and in components.plant_step._boundary_distance at the twin's initialization.
BAR_PARAMETERS = {"c": 1e-100, "l": 1e100, "z_0": 0.0, "theta_0": 0.0}
LIMIT = 60.0                   # s: far beyond the ~2 s each child needs on a loaded machine


@pytest.fixture(scope="module")
def subnormal_bar(tmp_path_factory) -> tuple[Path, Path]:
    """(the description, its native plant FMU) of the levitated bar with the theta-boundary scaled by 1e100 l^2."""
    from fmus.native_build import build_native_description

    folder = tmp_path_factory.mktemp("subnormal_bar")
    text = (EXAMPLES / "levitated_bar" / "levitated_bar.toml").read_text()
    old = 'domain = ["c - z - l*theta > 0", "c - z + l*theta > 0"]'
    assert old in text
    toml = folder / "bar.toml"
    toml.write_text(text.replace(old, 'domain = ["c - z - 1e100*l*l*theta > 0", "c - z + 1e100*l*l*theta > 0"]'))
    return toml, build_native_description(toml, folder / "fmus")


def _child(code: str) -> list[float]:
    """Run `code` in a child Python under LIMIT seconds (a loop that never ends fails the test, it does not hang it):
    the numbers it printed on its last line."""
    import subprocess
    import sys

    try:
        run = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=LIMIT,
                             cwd=Path(__file__).resolve().parent.parent)
    except subprocess.TimeoutExpired:
        pytest.fail(f"did not end within {LIMIT:g} s: {code}")
    assert run.returncode == 0, run.stderr[-2000:]
    return [float(x) for x in run.stdout.split()]


def test_initialization_ends_where_the_boundary_is_below_the_least_subnormal(subnormal_bar, tmp_path) -> None:
    """The native plant initializes (CS) and answers its nominals (ME) within the time limit, the twin's
    components.plant_step.nominal_scale likewise, and the two agree (the theta axis: no boundary distance above
    0, the fallback nominal 1, as for an axis with no boundary)."""
    toml, fmu = subnormal_bar
    native = _child(f"""
from fmpy import read_model_description, extract
from fmpy.fmi2 import FMU2Model, FMU2Slave
md = read_model_description({str(fmu)!r}); folder = extract({str(fmu)!r}, {str(tmp_path / 'x')!r})
vr = {{v.name: v.valueReference for v in md.modelVariables}}
values = {BAR_PARAMETERS!r}
for kind in (FMU2Slave, FMU2Model):
    f = kind(guid=md.guid, unzipDirectory=folder, modelIdentifier=md.coSimulation.modelIdentifier, instanceName='b')
    f.instantiate(); f.setReal([vr[k] for k in values], list(values.values()))
    f.setupExperiment(startTime=0.0); f.enterInitializationMode(); f.exitInitializationMode()
import ctypes
nominals = (ctypes.c_double * 6)()
assert f.getNominalsOfContinuousStates(nominals, 6) == 0
print(*[repr(float(x)) for x in nominals])
""")
    twin = _child(f"""
from pathlib import Path
from emcosim.devices import registry
from components.plant_step import nominal_scale
device = registry.load(Path({str(toml)!r}))[2]
print(*[repr(float(x)) for x in nominal_scale(device.plant(c=1e-100, l=1e100))])
""")
    assert len(native) == len(twin) == 6
    np.testing.assert_allclose(native, twin, rtol=1e-12)
    assert native[0] == pytest.approx(1e-100, rel=1e-3) and native[1] == 1.0      # z: the boundary c; theta: none


def test_boundary_bisection_is_bounded_by_a_stated_count() -> None:
    """components.plant_step.BISECTIONS and emc_plant.c's EMC_BISECTIONS are one bound, derived from double's
    exponent range: from 1e-12 (> 2^-40) to the least subnormal 2^-1074 by halving, then 2^-10 < 1e-3."""
    from components import plant_step

    source = (Path(plant_step.__file__).parent.parent / "fmus" / "native" / "emc_plant.c").read_text()
    assert f"#define EMC_BISECTIONS {plant_step.BISECTIONS} " in source
    assert plant_step.BISECTIONS >= (1074 - 40) + 10
    assert 1e-12 > 2.0 ** -40 and 2.0 ** -1074 == 5e-324 and 2.0 ** -10 < 1e-3


# ---- item 10: a communication point + step that overflows ----------------------------------------------------
# fmi2DoStep(c, 1e308, 1e308, ...): both finite, the step > 0, but the end time 1e308 + 1e308 = inf. On main every
# native FMU (the framework, emc_fmi2.c) and every pythonfmu FMU (fmus/slave.py) answered fmi2OK and took the time
# to +inf (fmi2GetRealStatus(fmi2LastSuccessfulTime) then inf, no step possible after it).
@pytest.fixture(scope="module")
def native_reference(tmp_path_factory) -> Path:
    from fmus.native_build import build_native_reference
    return build_native_reference(tmp_path_factory.mktemp("native_reference"))


def _step_at_the_top(fmu: Path, folder: Path) -> tuple[int, float]:
    """(fmi2DoStep's status, fmi2LastSuccessfulTime after it) of doStep(1e308, 1e308) after an experiment started at
    1e308 (fmpy, in-process: the framework's answer, not a crash, is under test)."""
    from fmpy import extract as unzip
    from fmpy.fmi1 import FMICallException
    from fmpy.fmi2 import FMU2Slave

    md = read_model_description(str(fmu))
    f = FMU2Slave(guid=md.guid, unzipDirectory=unzip(str(fmu), str(folder)),
                  modelIdentifier=md.coSimulation.modelIdentifier, instanceName="top")
    f.instantiate()
    f.setupExperiment(startTime=1e308)
    f.enterInitializationMode()
    f.exitInitializationMode()
    try:
        f.doStep(currentCommunicationPoint=1e308, communicationStepSize=1e308)
        status = OK
    except FMICallException as exc:
        status = exc.status
    time = f.getRealStatus(2)                       # fmi2LastSuccessfulTime
    f.terminate()
    f.freeInstance()
    return status, time


def test_a_step_whose_end_time_overflows_is_refused_natively(native_reference, least_ball, subnormal_bar,
                                                               tmp_path) -> None:
    """The Reference, a controller and a plant (every kind of the framework): fmi2Error, and the FMU's time stays
    1e308 (on main fmi2OK and +inf)."""
    for k, fmu in enumerate((native_reference, least_ball[1], subnormal_bar[1])):
        assert _step_at_the_top(fmu, tmp_path / str(k)) == (ERROR, 1e308), fmu.name


def test_a_step_whose_end_time_overflows_is_refused_by_the_twins(least_ball) -> None:
    """fmus/slave.py (every pythonfmu FMU): the plant and the controller twins refuse doStep(1e308, 1e308) with
    fmi2Error and keep their time."""
    for name, slave in twin_slaves(least_ball[0], ["Theorem2"]).items():
        _initialized(slave, start=1e308)
        status, message = slave.fmi2_do_step(1e308, 1e308)
        assert status == ERROR and "overflows" in message, (name, status, message)
        assert slave.time == 1e308
    assert slave.fmi2_do_step(1e308, 1e300)[0] == OK              # the controller: 1e308 + 1e300 is finite


# ---- item 14 (the FMU half): a deserialized state is checked as initialization checks -----------------------------
# A serialized native state is the model's data behind the GUID: anyone can write bytes that pass the framework's
# magic, mode and finiteness checks. On main a plant state's rtol was only checked to be finite (initialization
# takes 1e-14 <= rtol <= 1e-2), and a controller state with strict = 1 was not checked against the design's
# conditions (initialization refuses them with strict = 1).
def _native_slave(fmu: Path, folder: Path, name: str, integers: dict | None = None, reals: dict | None = None):
    """An initialized CS instance of `fmu`, unzipped once into `folder` (never over a loaded binary)."""
    from fmpy import extract as unzip
    from fmpy.fmi2 import FMU2Slave

    md = read_model_description(str(fmu))
    vr = {v.name: v.valueReference for v in md.modelVariables}
    if not folder.exists():
        unzip(str(fmu), str(folder))
    f = FMU2Slave(guid=md.guid, unzipDirectory=str(folder),
                  modelIdentifier=md.coSimulation.modelIdentifier, instanceName=name)
    f.instantiate()
    for k, v in (integers or {}).items():
        f.setInteger([vr[k]], [v])
    for k, v in (reals or {}).items():
        f.setReal([vr[k]], [v])
    f.setupExperiment(startTime=0.0)
    f.enterInitializationMode()
    f.exitInitializationMode()
    return f


def _serialized(f) -> bytes:
    state = f.getFMUstate()
    data = bytes(f.serializeFMUstate(state))
    f.freeFMUstate(state)
    return data


def _deserialize_status(f, data: bytes) -> int:
    from fmpy.fmi1 import FMICallException

    try:
        f.freeFMUstate(f.deSerializeFMUstate(bytes(data)))
    except FMICallException as exc:
        return exc.status
    return OK


def test_a_deserialized_plant_state_with_an_rtol_out_of_range_is_refused(subnormal_bar, tmp_path) -> None:
    """The native plant (CS): a serialized state whose rtol bytes say 0.5 is refused with fmi2Error (main: fmi2OK),
    the same state with its own rtol is taken; the twin refuses the same state content (fmus/plant.py)."""
    import struct

    rtol = 1.2345678e-7                                  # a pattern found once in the bytes
    f = _native_slave(subnormal_bar[1], tmp_path / "n", "plant", reals={"rtol": rtol})
    data = _serialized(f)
    assert data.count(struct.pack("<d", rtol)) == 1
    assert _deserialize_status(f, data) == OK
    for bad in (0.5, 1e-15):
        assert _deserialize_status(f, data.replace(struct.pack("<d", rtol), struct.pack("<d", bad))) == ERROR, bad
    f.terminate()
    f.freeInstance()

    slave = _initialized(twin_slaves(subnormal_bar[0], [])["LevitatedBar"])
    status, state, _ = slave.fmi2_get_fmu_state()
    assert status == OK
    state["values"]["rtol"] = 0.5
    status, _, message = slave.fmi2_deserialize_fmu_state(slave.fmi2_serialize_fmu_state(state)[1])
    assert status == ERROR and "rtol = 0.5" in message, message


def test_a_deserialized_controller_state_with_strict_checks_the_design_again(least_ball, tmp_path) -> None:
    """The native controller: a state with strict = 1 whose gains violate Theorem 2's K_e >= 0 (R_e_bar_1_1 = 1 <
    R_c = 2.25), made from the bytes of a strict = 0 state, is refused at fmi2DeSerializeFMUstate with the design's
    reason (main: fmi2OK); the honest strict = 0 and strict = 1 states are taken. The twin refuses the same
    state when it is set (its parameters differ: it initializes again, strict = 1 refuses)."""
    fmu = least_ball[1]
    weak = _native_slave(fmu, tmp_path / "x", "weak", {"strict": 0}, {"R_e_bar_1_1": 1.0})
    honest = [_native_slave(fmu, tmp_path / "x", f"s{k}", {"strict": k}) for k in (0, 1)]
    zero, one = (_serialized(f) for f in honest)
    flipped = [i for i in range(len(zero)) if zero[i] != one[i]]
    assert len(flipped) == 1                              # strict's low byte: nothing else differs
    crafted = bytearray(_serialized(weak))
    crafted[flipped[0]] = one[flipped[0]]
    assert _deserialize_status(honest[1], zero) == OK and _deserialize_status(honest[1], one) == OK
    assert _deserialize_status(honest[1], bytes(crafted)) == ERROR
    for f in (weak, *honest):
        f.terminate()
        f.freeInstance()

    twins = [_initialized(twin_slaves(least_ball[0], ["Theorem2"])["TwoMagnetBall_Theorem2"]) for _ in range(2)]
    vr = {v.name: i for i, v in enumerate(twins[0].variables)}
    status, state, _ = twins[0].fmi2_get_fmu_state()
    state["values"].update({"strict": 1, "R_e_bar_1_1": 1.0})
    status, state, message = twins[1].fmi2_deserialize_fmu_state(twins[0].fmi2_serialize_fmu_state(state)[1])
    assert status == OK, message
    status, message = twins[1].fmi2_set_fmu_state(state)
    assert status == ERROR and "K_e = R_e_bar - R_e >= 0" in message, message
    assert twins[1].fmi2_get_real([vr["R_e_bar_1_1"]])[1] == [1000.0]       # it keeps its own state
