"""FMU states are checked like the values a host sets (issue 26, item 8): a serialized state with a valid
checksum but contents outside the model's domain, or inconsistent in itself, is refused with fmi2Error
naming the problem, and the instance keeps its state and keeps working.

The checksum (sha256 of the payload, fmus/state.py) catches accidents, not intent: these tests write
states with a matching checksum, as anyone can. Before the checks, each of them was accepted by
fmi2DeSerializeFMUstate (fmi2OK): a MEMS state with q = -1 m (the gap closed) gave q = -1 with fmi2OK
after fmi2SetFMUstate, and a negative or NaN h_next (the integrator's proposed substep) made every later
doStep of the instance fail (fmi2Discard), even after a good input.
"""
from __future__ import annotations

import hashlib
import json
import math
from typing import Callable

import pytest
from fmpy.fmi1 import FMICallException

from fmus.state import STATE_LENGTH_BYTES, STATE_PREFIX
from tests.helpers import Slave

OK, DISCARD, ERROR = 0, 2, 3
PLANTS = {"MEMS": (1e-6, 25.0), "Maglev": (1e-3, 0.0)}          # step, input u
CONTROLLERS = ("MEMS_Proposition1", "MEMS_Theorem2", "Maglev_Proposition2", "Maglev_Theorem3")
_START = STATE_PREFIX                                     # header, format version, length, sha256


def _serialized(slave: Slave) -> bytes:
    state = slave.fmu.getFMUstate()
    data = bytes(slave.fmu.serializeFMUstate(state))
    slave.fmu.freeFMUstate(state)
    return data


def _resigned(data: bytes, edit: Callable[[dict], None]) -> bytes:
    """The serialized state with `edit` applied to its payload and a checksum that matches again."""
    payload = json.loads(data[_START:])
    edit(payload)
    body = json.dumps(payload, sort_keys=True).encode()
    length = (_START + len(body)).to_bytes(STATE_LENGTH_BYTES, "big")
    return data[:_START - 32 - STATE_LENGTH_BYTES] + length + hashlib.sha256(body).digest() + body


def _deserialize(slave: Slave, data: bytes):
    """(status, state) of fmi2DeSerializeFMUstate."""
    try:
        return OK, slave.fmu.deSerializeFMUstate(data)
    except FMICallException as exc:
        return exc.status, None


def _set(path: list, value) -> Callable[[dict], None]:
    def edit(payload: dict) -> None:
        target = payload
        for key in path[:-1]:
            target = target[key]
        target[path[-1]] = value
    return edit


def _stepped_plant(fmus, identifier: str) -> Slave:
    h, u = PLANTS[identifier]
    slave = Slave(fmus[identifier])
    assert slave.init() == OK
    slave.set(u=u)
    assert slave.step(0.0, h) == OK
    return slave


OUTSIDE = {"MEMS": -1.0, "Maglev": 0.006}    # MEMS: the gap closed (q <= -c0); maglev: the magnet (q >= c)
BAD_PLANT_STATES = {
    "q outside the domain": (["internal", "eta", 0], None, "not admissible"),   # OUTSIDE[identifier]
    "q NaN": (["internal", "eta", 0], math.nan, "not three finite numbers"),
    "eta of two entries": (["internal", "eta"], [1e-5, 0.0], "not three finite numbers"),
    "h_next < 0": (["internal", "h_next"], -1e-6, "h_next"),
    "h_next NaN": (["internal", "h_next"], math.nan, "h_next"),
    "h_next inf": (["internal", "h_next"], math.inf, "h_next"),
    "u_end NaN": (["internal", "u_end"], [math.nan, 0.0], "end of the last step"),
    "integrator state missing": (["internal"], {}, "incomplete"),
}


@pytest.mark.parametrize("identifier", list(PLANTS))
@pytest.mark.parametrize("case", list(BAD_PLANT_STATES))
def test_plant_state_outside_the_domain_is_refused_and_the_instance_keeps_its_state(fmus, identifier, case):
    path, value, reason = BAD_PLANT_STATES[case]
    value = OUTSIDE[identifier] if value is None else value
    h, u = PLANTS[identifier]
    slave = _stepped_plant(fmus, identifier)
    data = _serialized(slave)
    before = slave.get("q", "p", "x_e")
    slave.messages.clear()
    status, state = _deserialize(slave, _resigned(data, _set(path, value)))
    assert status == ERROR and state is None, f"{case}: fmi2DeSerializeFMUstate answered {status}"
    assert reason in slave.errors(), slave.errors()
    assert slave.get("q", "p", "x_e") == before
    assert slave.step(h, h) == OK, slave.errors()                  # the instance keeps working
    slave.free()


@pytest.mark.parametrize("identifier", list(PLANTS))
def test_plant_state_inside_the_domain_is_taken_as_written(fmus, identifier):
    """The checks refuse only what is wrong: a state with another admissible q (checksum matching) is
    applied, and doStep goes on from it, as from the same q set at initialization."""
    h, u = PLANTS[identifier]
    slave = _stepped_plant(fmus, identifier)
    q = slave.get("q")[0] * 1.01
    status, state = _deserialize(slave, _resigned(_serialized(slave), _set(["internal", "eta", 0], q)))
    assert status == OK, slave.errors()
    slave.fmu.setFMUstate(state)
    assert slave.get("q")[0] == q
    assert slave.step(h, h) == OK
    slave.free()


@pytest.mark.parametrize("identifier", list(PLANTS) + list(CONTROLLERS))
@pytest.mark.parametrize("case", ["order 0", "order -2", "value NaN", "uninitialized in event mode"])
def test_inconsistent_state_is_refused(fmus, identifier, case):
    """Input derivatives of an order FMI 2.0 does not have (< 1) or with a NaN value, and a state that is
    not initialized but in a Model Exchange mode: fmi2Error, nothing applied."""
    slave = Slave(fmus[identifier])
    first_input = next(v.name for v in slave.md.modelVariables if v.causality == "input")
    if case == "uninitialized in event mode":
        edit = _set(["me_mode"], "event")                            # before initialization
    else:
        assert slave.init() == OK
        order, value = {"order 0": (0, 1.0), "order -2": (-2, 1.0), "value NaN": (1, math.nan)}[case]
        edit = _set(["input_derivatives"], {first_input: {str(order): value}})
    status, state = _deserialize(slave, _resigned(_serialized(slave), edit))
    assert status == ERROR and state is None, f"{identifier}, {case}: {status}"
    assert ("Model Exchange mode" if case.startswith("uninit") else "input derivative") in slave.errors()
    slave.free()


@pytest.mark.parametrize("identifier", list(PLANTS))
def test_a_bad_h_next_no_longer_bricks_the_instance(fmus, identifier):
    """The issue's case: h_next = -1 in a state written with a matching checksum. It is refused, and the
    instance steps on with its own integrator state (before, it took the state and every later doStep
    failed)."""
    h, u = PLANTS[identifier]
    slave = _stepped_plant(fmus, identifier)
    status, _ = _deserialize(slave, _resigned(_serialized(slave), _set(["internal", "h_next"], -1.0)))
    assert status == ERROR
    for k in range(1, 4):
        assert slave.step(k * h, h) == OK, slave.errors()
    slave.free()
