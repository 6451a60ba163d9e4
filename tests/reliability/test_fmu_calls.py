"""FMI calls with bad arguments or in the wrong state (issue 15, item 5): each gets fmi2Error (or
fmi2Discard where FMI says so) with a message, never a crash of the host or fmi2OK, and the instance
stays usable. Every call runs in the worker subprocess (fmpy host: a crash fails the test). Each case
failed on the FMUs before the loader answered these calls (docs/reliability.md, "FMU calls"):

- two failed fmi2DeSerializeFMUstate, then fmi2DoStep: SIGSEGV (pythonfmu released the slave once per
  failure); now each deserialization of bad bytes is refused (header, format version, sha256 checksum);
- fmi2SetFMUstate with a state of another FMU, or deserialized from bytes of the wrong shape: fmi2OK,
  nothing applied; now fmi2Error, the instance keeps its state;
- fmi2SetReal on an output or an unknown value reference: fmi2OK; fmi2GetReal of an unknown value
  reference: NaN with fmi2OK; now fmi2Error naming the variable;
- fmi2DoStep after fmi2Terminate: fmi2OK; now fmi2Error;
- fmi2FreeInstance twice: the host aborted; now the second call is ignored (the loader keeps a registry
  of its live instances);
- fmi2GetReal of a non-finite output (a controller's u for a NaN input): NaN with fmi2OK; now fmi2Error
  naming u.
"""
from __future__ import annotations

import math

import pytest
from fmpy import read_model_description

from .harness import ALL, CONTROLLERS, DISCARD, ERROR, OK

pytestmark = pytest.mark.reliability

H = {"MEMS": 1e-6, "Maglev": 1e-3, "Reference": 1e-3}


def _interface(path) -> tuple[list[str], list[str]]:
    md = read_model_description(str(path))
    return ([v.name for v in md.modelVariables if v.causality == "input"],
            [v.name for v in md.modelVariables if v.causality == "output"])


def _calls(worker, fmus: dict, calls: list) -> list:
    return worker.call({"cmd": "calls", "fmus": {k: str(v) for k, v in fmus.items()}, "calls": calls})["calls"]


def _errors(entry) -> str:
    return "\n".join(m for s, m in entry[3] if s >= ERROR)


def _outputs(identifier: str, path) -> list:
    return [["getr", name] for name in _interface(path)[1]]


@pytest.mark.parametrize("identifier", ALL)
def test_bad_serialized_states_are_refused_and_the_instance_keeps_working(reliability_fmus, worker, tally, identifier):
    """Garbage, a state with one byte changed, a cut state, and bytes of the right JSON shape without
    the header: each fmi2DeSerializeFMUstate returns fmi2Error; two of them and a doStep crashed the
    host before. Then a good state still round-trips."""
    path = reliability_fmus[identifier]
    h = H.get(identifier, 1e-6)
    good = [["sget", "s"], ["ser", "s"]]
    r = _calls(worker, {"A": path}, [
        ["inst", "A"], ["init", {}], ["bytes", b"\x00garbage" * 8], ["deser", "x"], ["deser", "y"], ["step", 0.0, h],
        *good, ["flip", 60], ["deser", "z"], *good, ["cut", 40], ["deser", "z"],
        ["bytes", b'{"values": {}, "time": 0.0, "initialized": true, "internal": {}}'], ["deser", "z"],
        *good, ["deser", "w"], ["sset", "w"], ["step", h, h]])
    statuses = [c[1] for c in r]
    assert statuses[:4] == [OK, OK, ERROR, ERROR], r[:4]
    assert statuses[4] == OK, f"{identifier}: doStep after two failed deserializations: {r[4]}"
    refused = [c for c in r if c[0] == "deser"][2:5]
    assert [c[1] for c in refused] == [ERROR] * 3, refused
    assert "checksum" in _errors(refused[0]) and "not a serialized emcosim FMU state" in _errors(refused[2])
    assert statuses[-3:] == [OK, OK, OK], r[-3:]
    tally.add("fmu calls", identifier, "clean_error", 5)


@pytest.mark.parametrize("identifier", ALL)
def test_state_of_another_fmu_is_refused_and_nothing_applied(reliability_fmus, worker, tally, identifier):
    """fmi2SetFMUstate with the state of another FMU (a pointer it never gave out), and with a pointer
    to arbitrary memory: fmi2Error, the outputs unchanged (it returned fmi2OK before, applying nothing)."""
    other = "Maglev" if identifier == "MEMS" else "MEMS"
    path = reliability_fmus[identifier]
    outputs = _outputs(identifier, path)
    r = _calls(worker, {"A": path, "B": reliability_fmus[other]}, [
        ["inst", "B"], ["init", {}], ["sget", "b"], ["inst", "A"], ["init", {}], *outputs,
        ["sset", "b"], ["sbogus"], *outputs])
    n = len(outputs)
    before, after = r[5:5 + n], r[7 + n:]
    assert [c[1] for c in r[5 + n:7 + n]] == [ERROR, ERROR], r[5 + n:7 + n]
    assert "not a state this FMU gave out" in _errors(r[5 + n])
    assert [c[2] for c in after] == [c[2] for c in before]
    tally.add("fmu calls", identifier, "clean_error", 2)


@pytest.mark.parametrize("identifier", ALL)
def test_set_and_get_of_wrong_value_references_are_errors(reliability_fmus, worker, tally, identifier):
    path = reliability_fmus[identifier]
    inputs, outputs = _interface(path)
    h = H.get(identifier, 1e-6)
    md = read_model_description(str(path))
    unknown = max(v.valueReference for v in md.modelVariables) + 1
    r = _calls(worker, {"A": path}, [
        ["inst", "A"], ["init", {}], ["setr", outputs[0], 1.0], ["setr", unknown, 1.0], ["getr", unknown],
        ["geti", outputs[0]], ["step", 0.0, h], ["getr", outputs[0]]])
    assert [c[1] for c in r[2:6]] == [ERROR] * 4, r[2:6]
    assert f"{outputs[0]} is an output" in _errors(r[2]) and f"valueReference {unknown}" in _errors(r[3])
    assert f"valueReference {unknown}" in _errors(r[4])
    assert [c[1] for c in r[6:]] == [OK, OK] and math.isfinite(r[7][2]), r[6:]
    tally.add("fmu calls", identifier, "clean_error", 4)


@pytest.mark.parametrize("identifier", ALL)
def test_calls_in_the_wrong_state_are_errors(reliability_fmus, worker, tally, identifier):
    """doStep before initialization, after fmi2Terminate, with a step that is not > 0 and finite;
    a parameter set after initialization; doStep on a NULL instance."""
    path = reliability_fmus[identifier]
    md = read_model_description(str(path))
    parameter = next(v.name for v in md.modelVariables if v.causality == "parameter" and v.type == "Real")
    h = H.get(identifier, 1e-6)
    r = _calls(worker, {"A": path}, [
        ["inst", "A"], ["step", 0.0, h], ["init", {}], ["step", 0.0, 0.0], ["step", 0.0, -h],
        ["step", 0.0, math.nan], ["setr", parameter, 1.0], ["nullstep"], ["step", 0.0, h], ["term"],
        ["step", h, h], ["term"]])
    statuses = [c[1] for c in r]
    assert statuses == [OK, ERROR, OK, ERROR, ERROR, ERROR, ERROR, ERROR, OK, OK, ERROR, ERROR], r
    assert "after fmi2Terminate" in _errors(r[10]) and f"parameter {parameter} is fixed" in _errors(r[6])
    tally.add("fmu calls", identifier, "clean_error", 8)


@pytest.mark.parametrize("identifier", ALL)
def test_double_free_does_not_harm_the_host(reliability_fmus, worker, tally, identifier):
    """fmi2FreeInstance twice (the host aborted before), then a new instance runs."""
    path = reliability_fmus[identifier]
    h = H.get(identifier, 1e-6)
    r = _calls(worker, {"A": path}, [["inst", "A"], ["init", {}], ["free"], ["free"], ["inst", "A"],
                                     ["init", {}], ["step", 0.0, h]])
    assert [c[1] for c in r] == [OK, OK, None, None, OK, OK, OK], r
    tally.add("fmu calls", identifier, "correct")


@pytest.mark.parametrize("identifier", CONTROLLERS)
def test_non_finite_output_is_an_error_naming_it(reliability_fmus, worker, tally, identifier):
    """A NaN input makes u NaN: fmi2GetReal returns fmi2Error naming u (NaN with fmi2OK before), doStep
    fmi2Discard; a finite input again gives a finite u with fmi2OK."""
    path = reliability_fmus[identifier]
    r = _calls(worker, {"A": path}, [["inst", "A"], ["init", {}], ["setr", "p", math.nan], ["getr", "u"],
                                     ["step", 0.0, 1e-6], ["setr", "p", 0.0], ["getr", "u"], ["step", 0.0, 1e-6]])
    assert [c[1] for c in r] == [OK, OK, OK, ERROR, DISCARD, OK, OK, OK], r
    assert "u = nan is not finite" in _errors(r[3])
    assert math.isfinite(r[6][2])
    tally.add("fmu calls", identifier, "clean_error", 2)


@pytest.mark.parametrize("identifier", ALL)
def test_step_from_a_point_that_is_not_the_fmus_time_is_an_error(reliability_fmus, worker, tally, identifier):
    """fmi2DoStep with a currentCommunicationPoint that is not the FMU's time (issue 26, item 8): from 0
    again after a step to h, from 5 h, and from a billionth of a step before h: fmi2Error naming both
    times (fmi2OK before, and the time jumped: the Reference's jet and a plant's step followed the
    master's point), nothing changes, and a step from h then gives the straight run's outputs exactly.
    Times that differ from the FMU's by rounding (a master's t0 + n h against the FMU's sum of its steps)
    are its time: 20 steps from n h, n = 2..21."""
    path = reliability_fmus[identifier]
    h = H.get(identifier, 1e-6)
    outputs = _outputs(identifier, path)
    straight = _calls(worker, {"A": path}, [["inst", "A"], ["init", {}], ["step", 0.0, h], ["step", h, h], *outputs])
    r = _calls(worker, {"A": path}, [
        ["inst", "A"], ["init", {}], ["step", 0.0, h], ["step", 0.0, h], ["step", 5 * h, h],
        ["step", h * (1 - 1e-9), h], ["step", h, h], *outputs, *(["step", n * h, h] for n in range(2, 22))])
    refused = r[3:6]
    assert [c[1] for c in refused] == [ERROR] * 3, refused
    assert all("is not this FMU's time" in _errors(c) for c in refused), [_errors(c) for c in refused]
    assert r[6][1] == OK and [c[2] for c in r[7:7 + len(outputs)]] == [c[2] for c in straight[4:]]
    rounded = r[7 + len(outputs):]
    assert [c[1] for c in rounded] == [OK] * 20, [c for c in rounded if c[1] != OK][:1]
    tally.add("fmu calls", identifier, "clean_error", 3)
