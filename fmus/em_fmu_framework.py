"""FMI plumbing shared by the emcosim FMUs (pythonfmu 0.7.0): nothing here knows physics.

- Variables are declared with unit and description; `to_xml` completes pythonfmu's modelDescription
  with UnitDefinitions, units, ModelStructure dependencies and InitialUnknowns, and a GUID derived
  from the content (reproducible builds).
- FMU state: a snapshot of every variable plus what an adapter keeps outside them (`save_internal` /
  `restore_internal`), so a master can roll a step back exactly. A state is checked before it is
  applied (this FMU's, this build's, every variable with a number), and applied all or nothing;
  serialized states carry a header, a format version and a sha256 checksum that deserialization
  checks.
- Errors never escape into the host as crashes, and every FMI call gets its proper status. pythonfmu
  0.7.0 turns any Python exception into fmi2Fatal and then releases the slave object (once at the
  exception, once more in fmi2FreeInstance), returns fmi2OK whatever a setter logs, and forwards log
  messages only to hosts that instantiated with loggingOn. So the FMU's binary (the loader,
  emcosim_fmu_loader.c) answers the FMI calls itself through the `fmi2_*` methods below, which return
  (status, ..., message) and never raise: fmi2Error for a bad argument or a call in the wrong state
  (unknown or wrong value reference, an output set, a fixed parameter set after initialization, doStep
  before initialization or after fmi2Terminate, a non-finite output, an FMU state that is not this
  FMU's), fmi2Discard for a step that failed with the state kept at its start; the loader logs the
  message through the host's logger, and forwards warnings and errors whatever loggingOn says. The
  pythonfmu entry points (`do_step`, `exit_initialization_mode`, ...) remain for pythonfmu's own
  calls.
- pythonfmu 0.7.0 also releases the script module's namespace once per fmi2Instantiate; every FMU
  script calls `hold_script_globals(globals())` so that a second instance does not crash the host.
  (Its exit-time heap corruption is worked around by the loader, which registers the library's
  finalizePythonInterpreter as an exit handler.)
- FMI 2.0 derivatives: pythonfmu 0.7.0 does not implement fmi2SetRealInputDerivatives,
  fmi2GetRealOutputDerivatives and fmi2GetDirectionalDerivative; the FMU's binary (the loader,
  emcosim_fmu_loader.c) answers them by calling the `fmi2_*` methods below on the slave it takes with
  `take_new_slave` (contract: validation here, physics in the adapters' hooks `output_derivative` (or
  `output_derivatives`, a whole request at once) and `directional_derivative`; the capabilities are class
  attributes written into modelDescription.xml). A derivative request (value references and orders)
  is checked once; a master repeats it at every communication point.
- Layout: this module, the adapters and a copy of components/ and of pythonfmu's Python package live in
  the FMU's bundle package `emcosim_fmu_<build tag>` (build.py), and import each other relatively. All
  Python FMUs of a process share one interpreter and its sys.modules; names unique to the build keep
  FMUs of other builds and other vendors apart, and the loader refuses a module of these names that is
  already loaded from another build.
"""
from __future__ import annotations

import ctypes
import hashlib
import json
import math
import threading
import uuid
from dataclasses import dataclass, field
from typing import Callable, ClassVar
from xml.etree.ElementTree import Element, SubElement, tostring

from . import BUILD
from .pythonfmu import DefaultExperiment, Fmi2Causality, Fmi2Slave, Fmi2Variability, Integer, Real
from .pythonfmu._version import __version__ as PYTHONFMU_VERSION
from .pythonfmu.enums import Fmi2Status

# pythonfmu versions whose exception handling was measured to drop the slave's references as described above
REFCOUNT_COMPENSATED_VERSIONS = {"0.7.0"}

# SI base-unit exponents (kg, m, s, A) of every unit the FMUs use (FMI 2.0 UnitDefinitions / BaseUnit)
UNITS: dict[str, dict[str, int]] = {
    "1": {},
    "s": {"s": 1},
    "m": {"m": 1},
    "m/s": {"m": 1, "s": -1},
    "m/s2": {"m": 1, "s": -2},
    "m/s3": {"m": 1, "s": -3},
    "kg": {"kg": 1},
    "kg.m/s": {"kg": 1, "m": 1, "s": -1},
    "N": {"kg": 1, "m": 1, "s": -2},
    "N/m": {"kg": 1, "s": -2},
    "N/m3": {"kg": 1, "m": -2, "s": -2},
    "N.s/m": {"kg": 1, "s": -1},
    "J": {"kg": 1, "m": 2, "s": -2},
    "C": {"s": 1, "A": 1},
    "C/m": {"m": -1, "s": 1, "A": 1},
    "V": {"kg": 1, "m": 2, "s": -3, "A": -1},
    "Ohm": {"kg": 1, "m": 2, "s": -3, "A": -2},
    "F/m": {"kg": -1, "m": -3, "s": 4, "A": 2},
    "Wb": {"kg": 1, "m": 2, "s": -2, "A": -1},
    "Wb/m": {"kg": 1, "m": 1, "s": -2, "A": -1},
    "H.m": {"kg": 1, "m": 3, "s": -2, "A": -2},
    "rad": {"rad": 1},
    "rad/s": {"rad": 1, "s": -1},
}

# the reference jet: outputs of the Reference FMU, inputs of the tracking controllers (name, unit, description)
REFERENCE_JET = (("q_star", "m", "reference position q*"),
                 ("q_star_dot", "m/s", "first derivative of the reference position, q*'"),
                 ("q_star_ddot", "m/s2", "second derivative of the reference position, q*''"),
                 ("q_star_dddot", "m/s3", "third derivative of the reference position, q*'''"))

# FMI 2.0 status codes returned by the fmi2_* methods to the loader
OK, WARNING, DISCARD, ERROR = 0, 1, 2, 3
_OK = (OK, "")

# serialized FMU state: header, format version (1 byte), sha256 of the payload (32 bytes), JSON payload
STATE_HEADER = b"emcosim FMU state\n"
STATE_FORMAT = 1
STATE_KEYS = {"model", "build", "values", "time", "initialized", "input_derivatives", "internal"}


@dataclass
class Variable:
    """One FMI variable of an emcosim FMU.

    causality      "parameter" (fixed), "input" or "output" (continuous, calculated)
    dependencies   outputs only: names of the inputs the output depends on in Step Mode
    initial_deps   outputs only: names of the knowns (inputs, parameters) it depends on at initialization
    """

    name: str
    causality: str
    unit: str | None
    description: str
    start: float | int | None = None
    integer: bool = False
    getter: Callable[[], float] | None = None
    dependencies: list[str] = field(default_factory=list)
    initial_deps: list[str] | None = None


def hold_script_globals(namespace: dict) -> None:
    """Call at the top level of every FMU script with globals().

    pythonfmu 0.7.0 finds the slave class by re-executing the script in the module's namespace at each
    fmi2Instantiate and then releases that namespace (a borrowed reference) once too often; a script
    without functions of its own loses its globals after the first instance is freed, and the next
    fmi2Instantiate crashes the host. Each execution of the script therefore takes one reference here:
    the re-executions are balanced, the first import keeps one (the module lives for the process)."""
    if PYTHONFMU_VERSION in REFCOUNT_COMPENSATED_VERSIONS:
        ctypes.pythonapi.Py_IncRef(ctypes.py_object(namespace))


_PINNED_THREADS: set[int] = set()


def keep_thread_state() -> None:
    """Keep the calling thread's Python thread state alive between FMI calls, if the host created the
    thread (a C host calls from its own threads: Python sees a threading._DummyThread).

    pythonfmu enters Python with PyGILState_Ensure and leaves with PyGILState_Release in every FMI
    call; for a thread Python did not create, that creates and destroys a thread state each time
    (measured in a C host: a controller's doStep took 12.7 us, 2.0 us with the thread state kept).
    One more PyGILState_Ensure, never released, keeps the thread state; pythonfmu's Release still
    releases the GIL after each call (CPython's gilstate counter stays above zero). Done for the
    thread that instantiates the FMU (other threads keep working, at the higher cost). Cost: one
    thread state per host thread, freed by Py_Finalize."""
    thread = threading.current_thread()
    if not isinstance(thread, threading._DummyThread) or thread.ident in _PINNED_THREADS:
        return
    ctypes.pythonapi.PyGILState_Ensure()
    _PINNED_THREADS.add(thread.ident)


_NEW_SLAVES: dict[int, "EMSlave"] = {}


def take_new_slave() -> "EMSlave | None":
    """The EMSlave constructed last on the calling thread and not taken yet, or None.

    The loader calls this right after forwarding fmi2Instantiate and fmi2Reset to pythonfmu (which
    constructs the slave on the calling thread, and a new one on reset), to know the Python object of
    the instance for the FMI functions it answers itself."""
    return _NEW_SLAVES.pop(threading.get_ident(), None)


class EMSlave(Fmi2Slave):
    """Base of the emcosim slaves. Subclasses set the class attributes and implement `declare`,
    `initialize` (build the components objects; raise ValueError with the reason), `step` (return
    True, or log and return False) and, if they keep state outside the variables, `save_internal` /
    `restore_internal`."""

    model_identifier: ClassVar[str] = ""
    summary: ClassVar[str] = ""
    experiment: ClassVar[tuple[float, float, float]] = (0.0, 1.0, 1e-3)   # start, stop, step
    # FMI 2.0 derivative capabilities (CoSimulation attributes of modelDescription.xml, see `to_xml`)
    can_interpolate_inputs: ClassVar[bool] = False          # canInterpolateInputs
    max_input_derivative_order: ClassVar[int] = 0           # highest order fmi2SetRealInputDerivatives accepts
    max_output_derivative_order: ClassVar[int] = 0          # maxOutputDerivativeOrder
    provides_directional_derivative: ClassVar[bool] = False  # providesDirectionalDerivative
    author = "emcosim"
    license = "MIT"
    version = "0.1.0"

    def __init__(self, **kwargs):
        super().__init__(**kwargs)
        self.modelName = self.model_identifier
        self.description = self.summary
        start, stop, step = self.experiment
        self.default_experiment = DefaultExperiment(start_time=start, stop_time=stop, step_size=step)
        self.values: dict[str, float] = {}
        self.variables: list[Variable] = []
        self.by_name: dict[str, Variable] = {}
        self._getters: list[Callable[[], float] | None] = []
        self._real_vrs: set[int] = set()                            # value references of Real variables
        self._real_inputs: dict[int, str] = {}                      # value reference -> name
        self.initialized = False
        self.entered = False                                        # in initialization mode
        self.terminated = False
        self.time = 0.0
        self.tolerance: float | None = None      # fmi2SetupExperiment's tolerance, if the master defined one
        self._set_names: tuple[list[int], list[str]] = ([], [])     # the last Real inputs set: vrs, names
        self.input_derivatives: dict[str, dict[int, float]] = {}     # input name -> {order: value}
        # validated derivative requests: (vrs, orders) -> names (set) or [(name, order)] (get); a master
        # repeats the same request at every communication point, so it is checked once
        self._derivative_sets: dict[tuple, list[str]] = {}
        self._derivative_gets: dict[tuple, list[tuple[str, int]]] = {}
        self.declare()
        keep_thread_state()
        _NEW_SLAVES[threading.get_ident()] = self

    # ---- declaration ----------------------------------------------------------------------------
    def declare(self) -> None:
        raise NotImplementedError

    def parameter(self, name: str, start: float, unit: str | None, description: str, integer: bool = False) -> None:
        self._add(Variable(name, "parameter", unit, description, start, integer))

    def input(self, name: str, start: float, unit: str, description: str) -> None:
        self._add(Variable(name, "input", unit, description, start))

    def output(self, name: str, unit: str, description: str, getter: Callable[[], float],
               dependencies: list[str], initial_deps: list[str] | None) -> None:
        self._add(Variable(name, "output", unit, description, None, False, getter, list(dependencies),
                           None if initial_deps is None else list(initial_deps)))

    def _add(self, var: Variable) -> None:
        if var.unit is not None and var.unit not in UNITS:
            raise ValueError(f"{self.model_identifier}: unit {var.unit!r} of {var.name} has no UnitDefinition")
        if var.name in self.by_name:
            raise ValueError(f"{self.model_identifier}: variable {var.name} declared twice")
        self.variables.append(var)
        self.by_name[var.name] = var
        name = var.name
        if var.causality == "output":
            getter = var.getter
        else:
            self.values[name] = var.start
            getter = (lambda: self.values[name])
        kind = Integer if var.integer else Real
        causality = {"parameter": Fmi2Causality.parameter, "input": Fmi2Causality.input,
                     "output": Fmi2Causality.output}[var.causality]
        variability = {"parameter": Fmi2Variability.fixed, "input": Fmi2Variability.continuous,
                       "output": Fmi2Variability.continuous}[var.causality]
        if var.integer and var.causality != "parameter":
            raise ValueError("only parameters may be Integer")
        # values are set by fmi2_set_real / fmi2_set_integer (every FMI path leads there), never through
        # pythonfmu's per-variable setters
        self.register_variable(kind(name, causality=causality, variability=variability,
                                    description=var.description, getter=getter))
        if var.causality == "input":
            self._real_inputs[len(self._getters)] = name
        if not var.integer:
            self._real_vrs.add(len(self._getters))
        self._getters.append(getter)

    def inputs_changed(self) -> None:
        """Hook: an input was set (controllers drop their cached output)."""

    # ---- life cycle (the adapters' part) ---------------------------------------------------------
    def initialize(self) -> None:
        raise NotImplementedError

    def step(self, t: float, h: float) -> bool:
        raise NotImplementedError

    def log_error(self, message: str) -> None:
        """Log with status error (the loader forwards it to the host's logger whatever loggingOn says)."""
        self.log(message, Fmi2Status.error)

    # ---- pythonfmu's entry points (the loader calls the fmi2_* methods below instead) ------------------
    def get_real(self, vrs):
        return self._values_or_log(self.fmi2_get_real(vrs))

    def set_real(self, vrs, values):
        self._log_status(self.fmi2_set_real(vrs, values))

    def get_integer(self, vrs):
        return self._values_or_log(self.fmi2_get_integer(vrs))

    def set_integer(self, vrs, values):
        self._log_status(self.fmi2_set_integer(vrs, values))

    def setup_experiment(self, start_time, stop_time=None, tolerance=None):
        self._log_status(self.fmi2_setup_experiment(tolerance is not None, tolerance or 0.0, start_time,
                                                    stop_time is not None, stop_time or 0.0))

    def enter_initialization_mode(self):
        self._log_status(self.fmi2_enter_initialization_mode())

    def exit_initialization_mode(self):
        status, message = self.fmi2_exit_initialization_mode()
        if status > WARNING:
            self._raise_to_host(RuntimeError(message), message)

    def do_step(self, current_time, step_size):
        status, message = self.fmi2_do_step(current_time, step_size)
        self._log_status((status, message))
        return status == OK

    def terminate(self):
        self._log_status(self.fmi2_terminate())

    def _log_status(self, answer: tuple) -> None:
        if answer[-1]:
            self.log(answer[-1], Fmi2Status(answer[0]))

    def _values_or_log(self, answer: tuple) -> list:
        self._log_status(answer)
        return answer[1]

    def _raise_to_host(self, exc: Exception, message: str) -> None:
        """Fail the current pythonfmu call (pythonfmu reports fmi2Fatal) with `message`, keeping this
        instance valid: pythonfmu 0.7.0 releases the slave's references once more than it holds after an
        exception, so it gets the extra references first. Versions of pythonfmu not measured get a log
        entry instead."""
        if PYTHONFMU_VERSION not in REFCOUNT_COMPENSATED_VERSIONS:
            self.log_error(message)
            return
        for obj in (self, type(self), self.log_queue):
            ctypes.pythonapi.Py_IncRef(ctypes.py_object(obj))
        raise RuntimeError(message) from exc

    # ---- FMI calls answered by the loader: (status, ..., message), never an exception -----------------
    def fmi2_setup_experiment(self, tolerance_defined: int, tolerance: float, start_time: float,
                              stop_time_defined: int, stop_time: float) -> tuple[int, str]:
        where = f"{self.model_identifier}: fmi2SetupExperiment"
        if self.entered or self.initialized or self.terminated:
            return ERROR, f"{where} is allowed only after fmi2Instantiate or fmi2Reset"
        if not math.isfinite(start_time):
            return ERROR, f"{where}: startTime = {start_time!r} is not finite"
        if stop_time_defined and not stop_time >= start_time:
            return ERROR, f"{where}: stopTime = {stop_time!r} is before startTime = {start_time!r}"
        if tolerance_defined and not tolerance > 0:
            return ERROR, f"{where}: tolerance = {tolerance!r} is not > 0"
        self.time = float(start_time)
        self.tolerance = float(tolerance) if tolerance_defined else None
        return _OK

    def fmi2_enter_initialization_mode(self) -> tuple[int, str]:
        if self.entered or self.initialized or self.terminated:
            return ERROR, (f"{self.model_identifier}: fmi2EnterInitializationMode is allowed only after "
                           "fmi2Instantiate or fmi2Reset")
        self.entered = True
        return _OK

    def fmi2_exit_initialization_mode(self) -> tuple[int, str]:
        """Build the model from the parameters; on failure fmi2Error with the reason, and the instance stays
        in initialization mode (parameters can be corrected and the call repeated)."""
        if not self.entered:
            return ERROR, (f"{self.model_identifier}: fmi2ExitInitializationMode is allowed only in "
                           "initialization mode (after fmi2EnterInitializationMode)")
        try:
            self.initialize()
        except Exception as exc:                                      # noqa: BLE001 - reported as the status
            reason = str(exc)
            if isinstance(exc, ArithmeticError):                      # name the suspects
                changed = [f"{v.name} = {self.values[v.name]!r}" for v in self.variables
                           if v.causality == "parameter" and self.values[v.name] != v.start]
                reason = (f"{type(exc).__name__} ({exc}) evaluating the model with the parameters changed "
                          f"from their defaults: {', '.join(changed) or 'none'}")
            return ERROR, f"{self.model_identifier}: initialization failed: {reason}"
        self.initialized, self.entered = True, False
        return _OK

    def fmi2_terminate(self) -> tuple[int, str]:
        if self.terminated:
            return ERROR, f"{self.model_identifier}: fmi2Terminate called twice"
        self.terminated = True
        return _OK

    def fmi2_do_step(self, current_time: float, step_size: float) -> tuple[int, str]:
        """fmi2OK after a successful step; fmi2Discard when the adapter refuses the step (it logged why;
        the state stays at the start of the step); fmi2Error for a call in the wrong state or a step
        that is not finite and positive."""
        where = f"{self.model_identifier}: fmi2DoStep"
        if self.terminated:
            return ERROR, f"{where} after fmi2Terminate"
        if not self.initialized:
            return ERROR, f"{where} before a successful initialization (fmi2ExitInitializationMode)"
        if not (math.isfinite(current_time) and math.isfinite(step_size) and step_size > 0):
            return ERROR, (f"{where}: currentCommunicationPoint = {current_time!r}, communicationStepSize = "
                           f"{step_size!r}: both must be finite and the step > 0")
        try:
            ok = bool(self.step(current_time, step_size))
        except Exception as exc:                                      # noqa: BLE001 - the state is kept
            return DISCARD, f"{where} at t = {current_time:.9g} s failed: {type(exc).__name__}: {exc}"
        if not ok:
            return DISCARD, ""
        self.time = current_time + step_size
        self.input_derivatives.clear()                               # set again by the master for the next step
        return _OK

    def fmi2_set_real(self, vrs: list[int], values: list[float]) -> tuple[int, str]:
        if not self.terminated:                                       # fast path: Real inputs
            cached_vrs, names = self._set_names
            if vrs != cached_vrs:
                inputs = self._real_inputs
                if not all(vr in inputs for vr in vrs):
                    return self._set_checked(vrs, values, False)
                names = [inputs[vr] for vr in vrs]
                self._set_names = (list(vrs), names)
            store = self.values
            for name, value in zip(names, values):
                store[name] = value
            self.inputs_changed()
            return _OK
        return self._set_checked(vrs, values, False)

    def fmi2_set_integer(self, vrs: list[int], values: list[int]) -> tuple[int, str]:
        return self._set_checked(vrs, values, True)

    def _set_checked(self, vrs: list[int], values: list, integer: bool) -> tuple[int, str]:
        """Set all or nothing: every value reference must be a settable variable of the call's type."""
        where = f"{self.model_identifier}: fmi2Set{'Integer' if integer else 'Real'}"
        if self.terminated:
            return ERROR, f"{where} after fmi2Terminate"
        for vr in vrs:
            var = self._variable(vr)
            if var is None:
                return ERROR, f"{where}: valueReference {vr} is not a variable of this FMU"
            if var.causality == "output":
                return ERROR, f"{where}: {var.name} is an output; it cannot be set"
            if var.integer != integer:
                return ERROR, f"{where}: {var.name} is {'an Integer' if var.integer else 'a Real'} variable"
            if var.causality == "parameter" and self.initialized:
                return ERROR, f"{where}: parameter {var.name} is fixed after initialization"
        inputs = False
        for vr, value in zip(vrs, values):
            var = self.variables[vr]
            self.values[var.name] = int(value) if integer else float(value)
            inputs = inputs or var.causality == "input"
        if inputs:
            self.inputs_changed()
        return _OK

    def fmi2_get_real(self, vrs: list[int]) -> tuple[int, list[float], str]:
        """The values; fmi2Error naming the variable for a value reference that is not a Real variable,
        a value that cannot be computed or a value that is not finite (the FMUs never return a
        non-finite output with fmi2OK)."""
        if self._real_vrs.issuperset(vrs):                            # fast path
            getters = self._getters
            try:
                values = [float(getters[vr]()) for vr in vrs]
            except Exception:                                         # noqa: BLE001 - found again below
                pass
            else:
                total = sum(values)
                if total - total == 0.0:                              # all finite (else nan, or an overflow)
                    return OK, values, ""
        return self._get_checked(vrs, False)

    def fmi2_get_integer(self, vrs: list[int]) -> tuple[int, list[int], str]:
        return self._get_checked(vrs, True)

    def _get_checked(self, vrs: list[int], integer: bool) -> tuple[int, list, str]:
        where = f"{self.model_identifier}: fmi2Get{'Integer' if integer else 'Real'}"
        values, problems = [], []
        for vr in vrs:
            var = self._variable(vr)
            if var is None or var.integer != integer:
                problems.append(f"{self._describe_vr(vr)} is not {'an Integer' if integer else 'a Real'} variable")
                values.append(0 if integer else math.nan)
                continue
            try:
                value = self._getters[vr]()
                value = int(value) if integer else float(value)
            except Exception as exc:                                  # noqa: BLE001 - reported as the status
                problems.append(f"{var.name} cannot be computed: {type(exc).__name__}: {exc}")
                value = 0 if integer else math.nan
            if not integer and not math.isfinite(value):
                problems.append(f"{var.name} = {value} is not finite")
            values.append(value)
        if problems:
            return ERROR, values, f"{where}: " + "; ".join(problems)
        return OK, values, ""

    # ---- FMU state -----------------------------------------------------------------------------
    def save_internal(self) -> dict:
        return {}

    def restore_internal(self, internal: dict) -> None:
        pass

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
        return OK, STATE_HEADER + bytes([STATE_FORMAT]) + hashlib.sha256(payload).digest() + payload, ""

    def fmi2_deserialize_fmu_state(self, data: bytes) -> tuple[int, dict | None, str]:
        """The state of serialized bytes, after checking header, format version, checksum and content."""
        where = f"{self.model_identifier}: fmi2DeSerializeFMUstate"
        start = len(STATE_HEADER) + 1 + 32
        if len(data) < start or not data.startswith(STATE_HEADER):
            return ERROR, None, f"{where}: {len(data)} bytes that are not a serialized emcosim FMU state"
        if data[len(STATE_HEADER)] != STATE_FORMAT:
            return ERROR, None, (f"{where}: format version {data[len(STATE_HEADER)]} of the serialized state; "
                                 f"this FMU reads version {STATE_FORMAT}")
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
                "initialized": self.initialized,
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
        derivatives = state["input_derivatives"]
        inputs = set(self._real_inputs.values())
        if not isinstance(derivatives, dict) or not all(
                name in inputs and isinstance(orders, dict)
                and all(isinstance(k, int) and isinstance(v, (int, float)) for k, v in orders.items())
                for name, orders in derivatives.items()):
            return "its input derivatives are not this FMU's"
        return ""

    def _apply_state(self, state: dict) -> None:
        changed = any(self.values[k] != v for k, v in state["values"].items()
                      if self.by_name[k].causality == "parameter")
        self.values.update(state["values"])
        self.time = float(state["time"])
        if state["initialized"] and (changed or not self.initialized):
            self.initialize()
        self.initialized = state["initialized"]
        self.input_derivatives = {name: {int(order): float(value) for order, value in orders.items()}
                                  for name, orders in state["input_derivatives"].items()}
        self.inputs_changed()                      # drop what depended on the inputs, then restore the state
        self.restore_internal(state["internal"])

    def _get_fmu_state(self):
        answer = self.fmi2_get_fmu_state()
        self._log_status(answer)
        return answer[1] or {}

    def _set_fmu_state(self, state):
        self._log_status(self.fmi2_set_fmu_state(state))

    # ---- FMI 2.0 derivatives (called by the loader with the GIL held; never raise) ----------------------
    def fmi2_set_real_input_derivatives(self, vrs: list[int], orders: list[int],
                                        values: list[float]) -> tuple[int, str]:
        """Store d^order(input)/dt^order at the current communication point for the next doStep
        (`input_derivatives`; all or nothing). Returns (fmi2Status, message)."""
        try:
            names = self._derivative_sets.get((tuple(vrs), tuple(orders)))
            if names is not None:                                     # fast path: a request checked before
                total = sum(values)
                if total - total == 0.0:                              # all finite (else nan, or an overflow)
                    store = self.input_derivatives
                    for name, order, value in zip(names, orders, values):
                        rates = store.get(name)
                        if rates is None:
                            store[name] = rates = {}
                        rates[order] = float(value)
                    return _OK
        except Exception:                                             # noqa: BLE001 - found again below
            pass
        where = f"{self.model_identifier}: fmi2SetRealInputDerivatives"
        try:
            if not self.can_interpolate_inputs:
                return ERROR, f"{where}: this FMU does not interpolate inputs (canInterpolateInputs = false)"
            staged: dict[str, dict[int, float]] = {}
            for vr, order, value in zip(vrs, orders, values):
                name = self._real_inputs.get(vr)
                if name is None:
                    return ERROR, f"{where}: {self._describe_vr(vr)} is not a Real input"
                if not 1 <= order <= self.max_input_derivative_order:
                    return ERROR, (f"{where}: order {order} for input {name} is not in 1.."
                                   f"{self.max_input_derivative_order}")
                if not math.isfinite(value):
                    return ERROR, f"{where}: derivative of order {order} of input {name} = {value} is not finite"
                staged.setdefault(name, {})[order] = float(value)
            for name, derivatives in staged.items():
                self.input_derivatives.setdefault(name, {}).update(derivatives)
            self._derivative_sets[(tuple(vrs), tuple(orders))] = [self._real_inputs[vr] for vr in vrs]
            return OK, ""
        except Exception as exc:                                      # noqa: BLE001 - reported, never raised
            return ERROR, f"{where} failed: {type(exc).__name__}: {exc}"

    def fmi2_get_real_output_derivatives(self, vrs: list[int], orders: list[int]) -> tuple[int, list[float], str]:
        """d^order(output)/dt^order at the current communication point, from the hook
        `output_derivatives` (`output_derivative` for each entry). A request checked once (value references
        and orders) is not checked again. Returns (fmi2Status, values, message)."""
        key = None
        try:
            key = (tuple(vrs), tuple(orders))
            requests = self._derivative_gets.get(key)
            if requests is not None:                                  # fast path: a request checked before
                values = self.output_derivatives(requests)
                total = sum(values)
                if total - total == 0.0:                              # all finite (else nan, or an overflow)
                    return OK, values, ""
        except Exception:                                             # noqa: BLE001 - found again below
            pass
        where = f"{self.model_identifier}: fmi2GetRealOutputDerivatives"
        name, order = "", 0
        try:
            requests = []
            for vr, order in zip(vrs, orders):
                var = self._variable(vr)
                if var is None or var.causality != "output":
                    return ERROR, [], f"{where}: {self._describe_vr(vr)} is not a Real output"
                if not 1 <= order <= self.max_output_derivative_order:
                    return ERROR, [], (f"{where}: order {order} for output {var.name} is not in 1.."
                                       f"{self.max_output_derivative_order} (maxOutputDerivativeOrder)")
                requests.append((var.name, order))
            values = []
            for name, order in requests:
                value = float(self.output_derivative(name, order))
                if not math.isfinite(value):
                    return ERROR, [], f"{where}: derivative of order {order} of {name} = {value} is not finite"
                values.append(value)
            if key is not None:
                self._derivative_gets[key] = requests
            return OK, values, ""
        except (ValueError, ArithmeticError) as exc:
            return ERROR, [], f"{where}: derivative of order {order} of {name}: {exc}"
        except Exception as exc:                                      # noqa: BLE001 - reported, never raised
            return ERROR, [], f"{where} failed: {type(exc).__name__}: {exc}"

    def fmi2_get_directional_derivative(self, unknowns: list[int], knowns: list[int],
                                        seeds: list[float]) -> tuple[int, list[float], str]:
        """sum_j d(unknown_i)/d(known_j) seeds_j for outputs (unknowns) with respect to inputs (knowns),
        from the hook `directional_derivative`. Returns (fmi2Status, values, message)."""
        where = f"{self.model_identifier}: fmi2GetDirectionalDerivative"
        try:
            if not self.provides_directional_derivative:
                return ERROR, [], f"{where}: not provided by this FMU (providesDirectionalDerivative = false)"
            unknown_names, known_names = [], []
            for vr in unknowns:
                var = self._variable(vr)
                if var is None or var.causality != "output":
                    return ERROR, [], f"{where}: unknown {self._describe_vr(vr)} is not a Real output"
                unknown_names.append(var.name)
            for vr, seed in zip(knowns, seeds):
                name = self._real_inputs.get(vr)
                if name is None:
                    return ERROR, [], f"{where}: known {self._describe_vr(vr)} is not a Real input"
                if not math.isfinite(seed):
                    return ERROR, [], f"{where}: seed {seed} for input {name} is not finite"
                known_names.append(name)
            values = [float(v) for v in self.directional_derivative(unknown_names, known_names, [float(x) for x in seeds])]
            if len(values) != len(unknown_names):
                return ERROR, [], f"{where}: {len(values)} values for {len(unknown_names)} unknowns"
            for name, value in zip(unknown_names, values):
                if not math.isfinite(value):
                    return ERROR, [], f"{where}: directional derivative of {name} = {value} is not finite"
            return OK, values, ""
        except (ValueError, ArithmeticError) as exc:
            return ERROR, [], f"{where}: {exc}"
        except Exception as exc:                                      # noqa: BLE001 - reported, never raised
            return ERROR, [], f"{where} failed: {type(exc).__name__}: {exc}"

    def output_derivative(self, name: str, order: int) -> float:
        """Hook: d^order(output `name`)/dt^order at the current communication point. Raise ValueError
        (or ArithmeticError) with the reason when it cannot be computed."""
        raise ValueError(f"output derivatives are not provided by {self.model_identifier}")

    def output_derivatives(self, requests: list[tuple[str, int]]) -> list[float]:
        """Hook: the floats `output_derivative(name, order)` for a checked request [(name, order), ...],
        all at once (an adapter computes what the entries share once). Any exception, or a value that
        is not finite, makes the caller ask `output_derivative` entry by entry to report it."""
        return [float(self.output_derivative(name, order)) for name, order in requests]

    def directional_derivative(self, unknowns: list[str], knowns: list[str], seeds: list[float]) -> list[float]:
        """Hook: for each output in `unknowns`, sum_j d(output)/d(knowns_j) * seeds_j."""
        raise ValueError(f"directional derivatives are not provided by {self.model_identifier}")

    def _variable(self, vr: int) -> Variable | None:
        return self.variables[vr] if isinstance(vr, int) and 0 <= vr < len(self.variables) else None

    def _describe_vr(self, vr: int) -> str:
        var = self._variable(vr)
        return f"valueReference {vr} ({var.causality} {var.name})" if var is not None else f"valueReference {vr} (unknown)"

    # ---- modelDescription ------------------------------------------------------------------------
    def to_xml(self, model_options=dict()):
        root = super().to_xml(model_options)
        root.attrib.pop("generationDateAndTime", None)
        index = {v.name: i + 1 for i, v in enumerate(self.variables)}

        # units on Real variables, unit definitions
        for sv in root.find("ModelVariables"):
            var = self.by_name[sv.get("name")]
            if var.unit is not None:
                sv.find("Real").set("unit", var.unit)
        used = sorted({v.unit for v in self.variables if v.unit is not None})
        unit_defs = Element("UnitDefinitions")
        for name in used:
            unit = SubElement(unit_defs, "Unit", {"name": name})
            SubElement(unit, "BaseUnit", {k: str(e) for k, e in UNITS[name].items()})
        children = list(root)
        position = children.index(root.find("CoSimulation")) + 1
        root.insert(position, unit_defs)

        # ModelStructure: outputs with their Step Mode dependencies, and the initial unknowns
        structure = root.find("ModelStructure")
        for child in list(structure):
            structure.remove(child)
        outputs = [v for v in self.variables if v.causality == "output"]
        if outputs:
            node = SubElement(structure, "Outputs")
            for v in outputs:
                SubElement(node, "Unknown", {"index": str(index[v.name]),
                                             "dependencies": " ".join(str(index[d]) for d in v.dependencies)})
            node = SubElement(structure, "InitialUnknowns")
            for v in outputs:
                attrib = {"index": str(index[v.name])}
                if v.initial_deps is not None:
                    attrib["dependencies"] = " ".join(str(index[d]) for d in sorted(v.initial_deps, key=index.get))
                SubElement(node, "Unknown", attrib)

        # FMI 2.0 derivatives (answered by the loader)
        cosim = root.find("CoSimulation")
        cosim.set("canInterpolateInputs", str(self.can_interpolate_inputs).lower())
        cosim.set("maxOutputDerivativeOrder", str(int(self.max_output_derivative_order)))
        cosim.set("providesDirectionalDerivative", str(self.provides_directional_derivative).lower())

        # a GUID that changes exactly when the description or the build (every source, pythonfmu, the
        # loader, the Python recorded) changes
        root.set("guid", "")
        digest = hashlib.sha256(tostring(root) + BUILD.encode()).hexdigest()
        root.set("guid", "{%s}" % uuid.uuid5(uuid.NAMESPACE_URL, "emcosim:" + digest))
        return root
