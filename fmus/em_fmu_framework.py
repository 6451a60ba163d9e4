"""FMI plumbing shared by the emcosim FMUs (pythonfmu 0.7.0): nothing here knows physics.

- Variables are declared with unit and description; `to_xml` completes pythonfmu's modelDescription
  with UnitDefinitions, units, ModelStructure dependencies and InitialUnknowns, and a GUID derived
  from the content (reproducible builds).
- FMU state: `_get_fmu_state` / `_set_fmu_state` save every variable plus what an adapter keeps
  outside them (`save_internal` / `restore_internal`), so a master can roll a step back exactly.
- Errors never escape into the host as crashes. pythonfmu 0.7.0 turns any Python exception into
  fmi2Fatal and then releases the slave object (once at the exception, once more in fmi2FreeInstance).
  So: a failed doStep logs the reason and returns False (fmi2Discard, state unchanged); a failed
  initialization logs the reason and raises, after giving pythonfmu the extra reference it will drop
  (`_raise_to_host`), so the instance stays valid and can be freed. fmi2Error is not reachable from a
  pythonfmu 0.7.0 slave. pythonfmu forwards log messages only to hosts that instantiated with
  loggingOn, so errors are also echoed to stderr.
- pythonfmu 0.7.0 also releases the script module's namespace once per fmi2Instantiate; every FMU
  script calls `hold_script_globals(globals())` so that a second instance does not crash the host.
  (Its exit-time heap corruption is worked around by the loader, which registers the library's
  finalizePythonInterpreter as an exit handler.)
- FMI 2.0 derivatives: pythonfmu 0.7.0 does not implement fmi2SetRealInputDerivatives,
  fmi2GetRealOutputDerivatives and fmi2GetDirectionalDerivative; the FMU's binary (the loader,
  emcosim_fmu_loader.c) answers them by calling the `fmi2_*` methods below on the slave it takes with
  `take_new_slave` (contract: validation here, physics in the adapters' hooks `output_derivative` and
  `directional_derivative`; the capabilities are class attributes written into modelDescription.xml).
- Layout: this module, the adapters and a copy of components/ and of pythonfmu's Python package live in
  the FMU's bundle package `emcosim_fmu_<build tag>` (build.py), and import each other relatively. All
  Python FMUs of a process share one interpreter and its sys.modules; names unique to the build keep
  FMUs of other builds and other vendors apart, and the loader refuses a module of these names that is
  already loaded from another build.
"""
from __future__ import annotations

import ctypes
import hashlib
import math
import sys
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
        self._setters: list[Callable[[float], None] | None] = []
        self._real_vrs: set[int] = set()                            # value references by type
        self._integer_vrs: set[int] = set()
        self._real_inputs: dict[int, str] = {}                      # value reference -> name
        self.initialized = False
        self.time = 0.0
        self.input_derivatives: dict[str, dict[int, float]] = {}     # input name -> {order: value}
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
            getter, setter = var.getter, None
        else:
            self.values[name] = var.start
            getter = (lambda: self.values[name])
            setter = self._make_setter(var)
        kind = Integer if var.integer else Real
        causality = {"parameter": Fmi2Causality.parameter, "input": Fmi2Causality.input,
                     "output": Fmi2Causality.output}[var.causality]
        variability = {"parameter": Fmi2Variability.fixed, "input": Fmi2Variability.continuous,
                       "output": Fmi2Variability.continuous}[var.causality]
        if var.integer and var.causality != "parameter":
            raise ValueError("only parameters may be Integer")
        self.register_variable(kind(name, causality=causality, variability=variability,
                                    description=var.description, getter=getter, setter=setter))
        if var.causality == "input":
            self._real_inputs[len(self._getters)] = name
        self._getters.append(getter)
        self._setters.append(setter)
        (self._integer_vrs if var.integer else self._real_vrs).add(len(self._getters) - 1)

    def _make_setter(self, var: Variable) -> Callable[[float], None]:
        name, is_input, integer = var.name, var.causality == "input", var.integer

        if is_input:
            values, changed = self.values, self.inputs_changed

            def set_input(value):
                values[name] = float(value)
                changed()
            return set_input

        def setter(value):
            if self.initialized:
                self.log(f"{self.model_identifier}: parameter {name} is fixed after initialization; "
                         f"the value {value!r} is ignored", Fmi2Status.warning)
                return
            self.values[name] = int(value) if integer else float(value)
        return setter

    def inputs_changed(self) -> None:
        """Hook: an input was set (controllers drop their cached output)."""

    # ---- FMI get/set (never raise into the host) --------------------------------------------------
    def _check_type(self, vr: int, integer: bool) -> None:
        if vr not in (self._integer_vrs if integer else self._real_vrs):
            what = f"variable {self.vars[vr].name}" if vr in self.vars else f"valueReference {vr}"
            raise TypeError(f"{what} is not of type {'Integer' if integer else 'Real'}")

    def _get(self, vrs, integer: bool) -> list:
        getters = self._getters
        if (self._integer_vrs if integer else self._real_vrs).issuperset(vrs):   # fast path: all valid
            try:
                return [int(getters[vr]()) for vr in vrs] if integer else [float(getters[vr]()) for vr in vrs]
            except Exception:                                         # noqa: BLE001 - retried one by one below
                pass
        out = []
        for vr in vrs:
            try:
                self._check_type(vr, integer)
                value = getters[vr]()
                out.append(int(value) if integer else float(value))
            except Exception as exc:                                  # noqa: BLE001 - must not reach the host
                self.log_error(f"get of valueReference {vr} failed: {exc}")
                out.append(0 if integer else math.nan)
        return out

    def _set(self, vrs, values, integer: bool) -> None:
        if not integer:                                               # fast path: Real inputs only
            inputs, store = self._real_inputs, self.values
            try:
                for vr, value in zip(vrs, values):
                    store[inputs[vr]] = float(value)
            except KeyError:                                          # not all inputs: set one by one below
                pass
            else:
                self.inputs_changed()
                return
        for vr, value in zip(vrs, values):
            try:
                self._check_type(vr, integer)
                setter = self._setters[vr]
                if setter is None:
                    raise TypeError(f"variable {self.vars[vr].name} is an output and cannot be set")
                setter(value)
            except Exception as exc:                                  # noqa: BLE001
                self.log_error(f"set of valueReference {vr} failed: {exc}")

    def get_real(self, vrs):
        return self._get(vrs, False)

    def set_real(self, vrs, values):
        self._set(vrs, values, False)

    def get_integer(self, vrs):
        return self._get(vrs, True)

    def set_integer(self, vrs, values):
        self._set(vrs, values, True)

    # ---- life cycle -----------------------------------------------------------------------------
    def setup_experiment(self, start_time, stop_time=None, tolerance=None):
        self.time = float(start_time)

    def exit_initialization_mode(self):
        try:
            self.initialize()
        except Exception as exc:                                      # noqa: BLE001
            self.initialized = False
            reason = str(exc)
            if isinstance(exc, ArithmeticError):                      # name the suspects
                changed = [f"{v.name} = {self.values[v.name]!r}" for v in self.variables
                           if v.causality == "parameter" and self.values[v.name] != v.start]
                reason = (f"{type(exc).__name__} ({exc}) evaluating the model with the parameters changed "
                          f"from their defaults: {', '.join(changed) or 'none'}")
            self._raise_to_host(exc, f"{self.model_identifier}: initialization failed: {reason}")
        self.initialized = True

    def initialize(self) -> None:
        raise NotImplementedError

    def do_step(self, current_time, step_size):
        try:
            if not self.initialized:
                self.log_error(f"{self.model_identifier}: doStep before a successful initialization")
                return False
            ok = bool(self.step(float(current_time), float(step_size)))
        except Exception as exc:                                      # noqa: BLE001
            self.log_error(f"{self.model_identifier}: doStep at t = {current_time:.9g} s failed: {exc}")
            return False
        if ok:
            self.time = current_time + step_size
            self.input_derivatives.clear()                           # set again by the master for the next step
        return ok

    def step(self, t: float, h: float) -> bool:
        raise NotImplementedError

    def log_error(self, message: str) -> None:
        """Log with status error, and echo to stderr: pythonfmu 0.7.0 forwards log messages to the host
        only when it instantiated the FMU with loggingOn, and a failure must never pass unnoticed."""
        self.log(message, Fmi2Status.error)
        print(f"[{self.instance_name}] error: {message}", file=sys.stderr, flush=True)

    def _raise_to_host(self, exc: Exception, message: str) -> None:
        """Fail the current FMI call (pythonfmu reports fmi2Fatal) with `message`, keeping this instance
        valid: see the module docstring. Versions of pythonfmu not measured get a log entry and the
        failure is reported by the next doStep (fmi2Discard) instead."""
        if PYTHONFMU_VERSION not in REFCOUNT_COMPENSATED_VERSIONS:
            self.log_error(message)
            return
        for obj in (self, type(self), self.log_queue):
            ctypes.pythonapi.Py_IncRef(ctypes.py_object(obj))
        # pythonfmu logs the exception itself (and loses it if the log queue is not empty); echo to stderr
        print(f"[{self.instance_name}] error: {message}", file=sys.stderr, flush=True)
        raise RuntimeError(message) from exc

    # ---- FMU state -----------------------------------------------------------------------------
    def save_internal(self) -> dict:
        return {}

    def restore_internal(self, internal: dict) -> None:
        pass

    def _get_fmu_state(self):
        try:
            return {"values": dict(self.values), "time": self.time, "initialized": self.initialized,
                    "input_derivatives": {k: dict(v) for k, v in self.input_derivatives.items()},
                    "internal": self.save_internal()}
        except Exception as exc:                                      # noqa: BLE001
            self.log_error(f"{self.model_identifier}: getFMUstate failed: {exc}")
            return {}

    def _set_fmu_state(self, state):
        try:
            changed = any(self.values.get(k) != v for k, v in state["values"].items()
                          if self.by_name[k].causality == "parameter")
            self.values.update(state["values"])
            self.time = state["time"]
            if state["initialized"] and (changed or not self.initialized):
                self.initialize()
            self.initialized = state["initialized"]
            self.input_derivatives = {name: {int(order): float(value) for order, value in orders.items()}
                                      for name, orders in state.get("input_derivatives", {}).items()}
            self.restore_internal(state["internal"])
            self.inputs_changed()
        except Exception as exc:                                      # noqa: BLE001
            self.log_error(f"{self.model_identifier}: setFMUstate failed: {exc}")

    # ---- FMI 2.0 derivatives (called by the loader with the GIL held; never raise) ----------------------
    def fmi2_set_real_input_derivatives(self, vrs: list[int], orders: list[int],
                                        values: list[float]) -> tuple[int, str]:
        """Store d^order(input)/dt^order at the current communication point for the next doStep
        (`input_derivatives`; all or nothing). Returns (fmi2Status, message)."""
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
            return OK, ""
        except Exception as exc:                                      # noqa: BLE001 - reported, never raised
            return ERROR, f"{where} failed: {type(exc).__name__}: {exc}"

    def fmi2_get_real_output_derivatives(self, vrs: list[int], orders: list[int]) -> tuple[int, list[float], str]:
        """d^order(output)/dt^order at the current communication point, from the hook
        `output_derivative`. Returns (fmi2Status, values, message)."""
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
