"""FMU state of an emcosim FMU (fmi2GetFMUstate, fmi2SetFMUstate, fmi2FreeFMUstate and serialization):
a snapshot of every variable plus what an adapter keeps outside them (`save_internal` /
`restore_internal`), so a master can roll a step back exactly. A Model Exchange instance's state also
holds its mode (event or continuous-time: model_exchange.py), as the FMU SDK's and the Reference FMUs' do.
A state is checked before it is applied, and applied all or nothing: it must be this FMU's and this
build's, hold every variable with a number of its type, a finite time, input derivatives of orders the
FMU takes with finite values, and be consistent in itself (a state that is not initialized has no
Model Exchange mode and no integrator state); the adapter checks what it keeps outside the variables
against the model's domain (`internal_problem`: a plant's q, p, x_e must be admissible for the state's
parameters, as at initialization, and its integrator's proposed substep finite and >= 0). Variables are
taken as fmi2SetReal and fmi2SetInteger take them (a parameter is checked when the state is applied
with other parameters: the model is built again from them). Serialized states carry a header, a format
version, the state's length in bytes and a sha256 checksum that deserialization checks. The binary
checks the header, the version and the length against the size a host passes before it reads further
(fmus/emcosim_fmu_loader.c reads this layout: keep both in step); the checksum catches accidents (a cut or
changed file), not intent: anyone can write bytes with a matching checksum, so deserialization checks the
content as fmi2SetFMUstate does (issue 26, item 8: a state with q = -1 m was accepted before).
"""
from __future__ import annotations

import hashlib
import json
import math

from . import BUILD
from .model_exchange import CONTINUOUS, EVENT
from .status import DONE as _OK
from .status import ERROR, MODEL_EXCHANGE, OK

# serialized FMU state: header, format version (1 byte), length of the whole serialized state (8 bytes, big
# endian), sha256 of the payload (32 bytes), JSON payload. Version 2 added the length: a host's size that is
# not the state's is refused before a byte past the header is read (issue 31, item 2).
STATE_HEADER = b"emcosim FMU state\n"
STATE_FORMAT = 2
STATE_LENGTH_BYTES = 8
STATE_PREFIX = len(STATE_HEADER) + 1 + STATE_LENGTH_BYTES + 32      # where the JSON payload starts
STATE_KEYS = {"model", "build", "values", "time", "initialized", "me_mode", "input_derivatives", "internal"}


class StateFunctions:
    """The FMU-state functions of EMSlave (slave.py); adapters implement `save_internal` and
    `restore_internal` when they keep state outside their variables."""

    def save_internal(self) -> dict:
        return {}

    def restore_internal(self, internal: dict) -> None:
        pass

    def internal_problem(self, state: dict) -> str:
        """'' if what `state` keeps outside the variables (`save_internal`) can be restored, else what is
        wrong: an adapter with an internal state checks it against the model's domain (plant.py)."""
        return ""

    def fmi2_get_fmu_state(self) -> tuple[int, dict | None, str]:
        try:
            return OK, self._snapshot(), ""
        except Exception as exc:                                      # noqa: BLE001 - reported as the status
            return ERROR, None, f"{self.model_identifier}: fmi2GetFMUstate failed: {type(exc).__name__}: {exc}"

    def fmi2_set_fmu_state(self, state: dict) -> tuple[int, str]:
        """Apply a state after checking it is this FMU's and complete; all or nothing."""
        where = f"{self.model_identifier}: fmi2SetFMUstate"
        problem = self._state_problem(state)
        if problem:
            return ERROR, f"{where}: {problem}; the instance keeps its state"
        before = self._snapshot()
        try:
            self._apply_state(state)
        except Exception as exc:                                      # noqa: BLE001 - rolled back, reported
            try:
                self._apply_state(before)
            except Exception as again:                                # noqa: BLE001
                return ERROR, f"{where}: {type(exc).__name__}: {exc}; restoring the previous state failed too: {again}"
            return ERROR, (f"{where}: the state could not be applied ({type(exc).__name__}: {exc}); the instance "
                           "keeps its state")
        return _OK

    def fmi2_serialize_fmu_state(self, state: dict) -> tuple[int, bytes, str]:
        """header + format version + sha256(payload) + payload (JSON)."""
        try:
            payload = json.dumps(state, sort_keys=True).encode()
        except (TypeError, ValueError) as exc:
            return ERROR, b"", f"{self.model_identifier}: fmi2SerializeFMUstate failed: {exc}"
        length = (STATE_PREFIX + len(payload)).to_bytes(STATE_LENGTH_BYTES, "big")
        return OK, STATE_HEADER + bytes([STATE_FORMAT]) + length + hashlib.sha256(payload).digest() + payload, ""

    def fmi2_deserialize_fmu_state(self, data: bytes) -> tuple[int, dict | None, str]:
        """The state of serialized bytes, after checking header, format version, checksum and content."""
        where = f"{self.model_identifier}: fmi2DeSerializeFMUstate"
        start = STATE_PREFIX
        if len(data) < len(STATE_HEADER) + 1 or not data.startswith(STATE_HEADER):
            return ERROR, None, f"{where}: {len(data)} bytes that are not a serialized emcosim FMU state"
        if data[len(STATE_HEADER)] != STATE_FORMAT:
            return ERROR, None, (f"{where}: format version {data[len(STATE_HEADER)]} of the serialized state; "
                                 f"this FMU reads version {STATE_FORMAT}")
        at = len(STATE_HEADER) + 1
        length = int.from_bytes(data[at:at + STATE_LENGTH_BYTES], "big") if len(data) >= start else -1
        if length != len(data):
            return ERROR, None, (f"{where}: {len(data)} bytes given, the serialized state says it has "
                                 f"{length if length >= 0 else 'more'}: it was cut or is not one")
        payload = data[start:]
        if hashlib.sha256(payload).digest() != data[start - 32:start]:
            return ERROR, None, f"{where}: checksum mismatch: the bytes were changed or cut"
        try:
            state = json.loads(payload)
            state["input_derivatives"] = {name: {int(order): value for order, value in orders.items()}
                                          for name, orders in state["input_derivatives"].items()}
        except (ValueError, TypeError, KeyError, AttributeError) as exc:
            return ERROR, None, f"{where}: unreadable state: {type(exc).__name__}: {exc}"
        problem = self._state_problem(state)
        if problem:
            return ERROR, None, f"{where}: {problem}"
        return OK, state, ""

    def _snapshot(self) -> dict:
        return {"model": self.model_identifier, "build": BUILD, "values": dict(self.values), "time": self.time,
                "initialized": self.initialized, "me_mode": self.me_mode,
                "input_derivatives": {k: dict(v) for k, v in self.input_derivatives.items()},
                "internal": self.save_internal()}

    def _state_problem(self, state) -> str:
        """'' if `state` can be applied to this FMU, else what is wrong with it."""
        if not isinstance(state, dict) or set(state) != STATE_KEYS:
            return "not a state of an emcosim FMU (wrong content)"
        if state["model"] != self.model_identifier or state["build"] != BUILD:
            return (f"a state of {state['model']} (build {str(state['build'])[:12]}), not of this FMU "
                    f"{self.model_identifier} (build {BUILD[:12]})")
        values = state["values"]
        if not isinstance(values, dict) or set(values) != set(self.values):
            return "its variables are not this FMU's"
        for name, value in values.items():
            kind = int if self.by_name[name].integer else (int, float)
            if isinstance(value, bool) or not isinstance(value, kind):
                return f"its value of {name} is not a number of the variable's type: {value!r}"
        if isinstance(state["time"], bool) or not isinstance(state["time"], (int, float)) or not math.isfinite(state["time"]):
            return f"its time {state['time']!r} is not a finite number"
        if not isinstance(state["initialized"], bool) or not isinstance(state["internal"], dict):
            return "it is incomplete"
        if state["me_mode"] not in (None, EVENT, CONTINUOUS):
            return f"its Model Exchange mode {state['me_mode']!r} is not one"
        if not state["initialized"] and state["me_mode"] is not None:
            return f"it is not initialized but in Model Exchange mode {state['me_mode']!r}"
        problem = self._derivatives_problem(state["input_derivatives"])
        return problem or self.internal_problem(state)

    def _derivatives_problem(self, derivatives) -> str:
        """'' if `derivatives` ({input: {order: value}}) are input derivatives this FMU takes, else why not."""
        inputs = set(self._real_inputs.values())
        if not isinstance(derivatives, dict) or not all(
                name in inputs and isinstance(orders, dict) for name, orders in derivatives.items()):
            return "its input derivatives are not this FMU's"
        for name, orders in derivatives.items():
            for k, v in orders.items():
                problem = self._order_problem(k)
                if problem:
                    return f"its input derivative of {name} of order {k!r} {problem}"
                if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v):
                    return f"its input derivative of {name} of order {k} = {v!r} is not a finite number"
        return ""

    def _apply_state(self, state: dict) -> None:
        changed = any(self.values[k] != v for k, v in state["values"].items()
                      if self.by_name[k].causality == "parameter")
        self.values.update(state["values"])
        self.time = float(state["time"])
        if state["initialized"] and (changed or not self.initialized):
            self.initialize()
        self.initialized = state["initialized"]
        if self.interface == MODEL_EXCHANGE:       # (a Co-Simulation instance's state: event mode once initialized)
            self.me_mode = state["me_mode"] or (EVENT if self.initialized else None)
        self.input_derivatives = {name: {int(order): float(value) for order, value in orders.items()}
                                  for name, orders in state["input_derivatives"].items()}
        self.inputs_changed()                      # drop what depended on the inputs, then restore the state
        self.restore_internal(state["internal"])
