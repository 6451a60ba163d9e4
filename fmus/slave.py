"""EMSlave: the base of every emcosim FMU's Python slave, and the FMI calls the FMU's binary answers through it.

The binary (fmus/emcosim_fmu_loader.c) calls the `fmi2_*` methods of the slave with the GIL held. They
return (status, ..., message) and never raise: fmi2Error for a bad argument or a call in the wrong state
(an unknown or wrong value reference, an output set, a fixed parameter set after initialization, doStep
before initialization or after fmi2Terminate, a non-finite output, an FMU state that is not this FMU's),
fmi2Discard for a step that failed with the state kept at its start; the binary logs the message
through the host's logger and forwards warnings and errors whatever loggingOn says. The jobs live in
their own modules, mixed in here:

- variables.py, model_description.py: what the FMU declares (units, dependencies, both interfaces);
- state.py: FMU state (get, set, serialize), checked before it is applied;
- derivatives.py: the FMI 2.0 derivative functions (input and output derivatives, directional derivatives);
- model_exchange.py: the Model Exchange functions and their state machine;
- pythonfmu_workarounds.py: pythonfmu 0.7.0, and what is worked around in it.

An adapter (plant.py, controller.py, reference.py) subclasses EMSlave and implements `declare`,
`initialize` (build the components objects; raise ValueError with the reason), `step` (return True, or
log and return False) and the hooks of the other modules. Nothing here knows physics.
"""
from __future__ import annotations

import math
from typing import Callable, ClassVar

from . import BUILD
from .derivatives import DerivativeFunctions
from .model_description import model_description
from .model_exchange import ModelExchangeFunctions
from .pythonfmu_workarounds import DefaultExperiment, Fmi2Slave, Fmi2Status, keep_thread_state, raise_to_host, register_new_slave
from .state import StateFunctions
from .status import CO_SIMULATION, DISCARD, ERROR, MODEL_EXCHANGE, OK, WARNING
from .status import DONE as _OK
from .variables import Variable

# fmi2DoStep's currentCommunicationPoint must be the FMU's time (the end of its last step, the start time,
# or the time of a restored FMU state) to within this fraction of the largest time magnitude involved
# (start time, the FMU's time, the communication point, the step): the rounding of t0 + n h, of an
# accumulated sum or of a master's integer clock is a few ulps (2.2e-16 each), a step is many orders of
# magnitude more (a step of 1e-12 of the time is below what the master's clock resolves anyway)
COMMUNICATION_POINT_TOLERANCE = 1e-12


class EMSlave(StateFunctions, DerivativeFunctions, ModelExchangeFunctions, Fmi2Slave):
    """Base of the emcosim slaves (module docstring)."""

    model_identifier: ClassVar[str] = ""
    summary: ClassVar[str] = ""
    experiment: ClassVar[tuple[float, float, float]] = (0.0, 1.0, 1e-3)   # start, stop, step
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
        self._getters: list[Callable[[], float]] = []
        self._real_vrs: set[int] = set()                            # value references of Real variables
        self._real_inputs: dict[int, str] = {}                      # value reference -> name
        self.interface = CO_SIMULATION                               # fmi2Instantiate's fmuType (the binary sets it)
        self.initialized = False
        self.entered = False                                        # in initialization mode
        self.terminated = False
        self.time = 0.0
        self.start_time = 0.0                    # fmi2SetupExperiment's startTime
        self.tolerance: float | None = None      # fmi2SetupExperiment's tolerance, if the master defined one
        self._set_names: tuple[list[int], list[str]] = ([], [])     # the last Real inputs set: vrs, names
        self.init_derivatives()
        self.init_model_exchange()
        self.declare()
        keep_thread_state()
        register_new_slave(self)

    # ---- declaration ----------------------------------------------------------------------------
    def declare(self) -> None:
        raise NotImplementedError

    def parameter(self, name: str, start: float, unit: str | None, description: str, integer: bool = False) -> None:
        self._add(Variable(name, "parameter", unit, description, start, integer))

    def input(self, name: str, start: float, unit: str, description: str) -> None:
        self._add(Variable(name, "input", unit, description, start))

    def output(self, name: str, unit: str, description: str, getter: Callable[[], float],
               dependencies: list[str], initial_deps: list[str] | None, nominal: float | None = None) -> None:
        self._add(Variable(name, "output", unit, description, None, False, getter, list(dependencies),
                           None if initial_deps is None else list(initial_deps), nominal=nominal))

    def independent_time(self) -> None:
        """The independent variable `time` [s] (the current time: fmi2SetupExperiment, fmi2DoStep, fmi2SetTime),
        for an FMU whose outputs depend on time: FMI 2.0 lists it among the knowns of their dependencies."""
        self._add(Variable("time", "independent", "s", "simulation time", None, False, lambda: self.time))

    def state_derivative(self, state: str, unit: str, getter: Callable[[], float], dependencies: list[str],
                         initial_deps: list[str] | None) -> None:
        """der(state): the time derivative of a continuous state (Model Exchange), a local variable; the
        states are numbered in the order their derivatives are declared."""
        self.state_names.append(state)
        self._add(Variable(f"der({state})", "local", unit, f"time derivative of {state}", None, False, getter,
                           list(dependencies), None if initial_deps is None else list(initial_deps),
                           derivative_of=state))

    def _add(self, var: Variable) -> None:
        var.check(self.model_identifier)
        if var.name in self.by_name:
            raise ValueError(f"{self.model_identifier}: variable {var.name} declared twice")
        self.variables.append(var)
        self.by_name[var.name] = var
        name = var.name
        if var.getter is not None:
            getter = var.getter
        else:
            self.values[name] = var.start

            def getter() -> float:
                return self.values[name]
        if var.causality == "input":
            self._real_inputs[len(self._getters)] = name
        if not var.integer:
            self._real_vrs.add(len(self._getters))
        self._getters.append(getter)

    def inputs_changed(self) -> None:
        """Hook: an input was set (controllers drop their cached output)."""

    def to_xml(self, model_options=dict()):
        """The modelDescription (model_description.py); pythonfmu's builder calls this name."""
        return model_description(self, BUILD, dict(model_options))

    # ---- life cycle (the adapters' part) ---------------------------------------------------------
    def initialize(self) -> None:
        raise NotImplementedError

    def step(self, t: float, h: float) -> bool:
        raise NotImplementedError

    def log_error(self, message: str) -> None:
        """Log with status error (the binary forwards it to the host's logger whatever loggingOn says)."""
        self.log(message, Fmi2Status.error)

    # ---- pythonfmu's entry points: used only if the binary could not take the slave ------------------
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
            raise_to_host(self, RuntimeError(message), message)

    def do_step(self, current_time, step_size):
        status, message = self.fmi2_do_step(current_time, step_size)
        self._log_status((status, message))
        return status == OK

    def terminate(self):
        self._log_status(self.fmi2_terminate())

    def _get_fmu_state(self):
        answer = self.fmi2_get_fmu_state()
        self._log_status(answer)
        return answer[1] or {}

    def _set_fmu_state(self, state):
        self._log_status(self.fmi2_set_fmu_state(state))

    def _log_status(self, answer: tuple) -> None:
        if answer[-1]:
            self.log(answer[-1], Fmi2Status(answer[0]))

    def _values_or_log(self, answer: tuple) -> list:
        self._log_status(answer)
        return answer[1]

    # ---- FMI calls answered by the binary: (status, ..., message), never an exception -----------------
    def fmi2_set_interface(self, fmu_type: int) -> tuple[int, str]:
        """fmi2Instantiate's fmuType (the binary creates every instance as Co-Simulation in pythonfmu)."""
        if fmu_type not in (MODEL_EXCHANGE, CO_SIMULATION):
            return ERROR, (f"{self.model_identifier}: fmi2Instantiate: fmuType {fmu_type} is neither fmi2ModelExchange "
                           "nor fmi2CoSimulation")
        self.interface = fmu_type
        return _OK

    def fmi2_get_sizes(self) -> tuple[int, tuple[int, int, int, int, int], str]:
        """What the binary checks the counts of every FMI call against before it reads the host's arrays
        (fmi2Instantiate, fmi2Reset): the numbers of continuous states and of event indicators (nx and ni
        must equal them), of Real and of Integer variables (nvr may not exceed them) and
        maxOutputDerivativeOrder (fmi2GetRealOutputDerivatives: at most that many orders per variable)."""
        n_reals = len(self._real_vrs)
        return OK, (len(self.state_names), self.number_of_event_indicators, n_reals,
                    len(self.variables) - n_reals, self.max_output_derivative_order), ""

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
        self.time = self.start_time = float(start_time)
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
        in initialization mode (parameters can be corrected and the call repeated). Model Exchange: the
        instance is then in Event Mode."""
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
        self.entered_event_mode()
        return _OK

    def fmi2_terminate(self) -> tuple[int, str]:
        if self.terminated:
            return ERROR, f"{self.model_identifier}: fmi2Terminate called twice"
        if self.interface == MODEL_EXCHANGE:                          # event or continuous-time mode only
            problem = self.me_refusal("fmi2Terminate")
            if problem:
                return ERROR, problem
        self.terminated = True
        return _OK

    def fmi2_do_step(self, current_time: float, step_size: float) -> tuple[int, str]:
        """fmi2OK after a successful step; fmi2Discard when the adapter refuses the step (it logged why;
        the state stays at the start of the step); fmi2Error for a call in the wrong state, a step that is
        not finite and positive, an end time that overflows (issue 40), or a currentCommunicationPoint that is
        not the FMU's time (issue 26, item 8: the time jumped before; within COMMUNICATION_POINT_TOLERANCE it is
        the FMU's time)."""
        where = f"{self.model_identifier}: fmi2DoStep"
        if self.interface != CO_SIMULATION:
            return ERROR, self.cs_only("fmi2DoStep")
        if self.terminated:
            return ERROR, f"{where} after fmi2Terminate"
        if not self.initialized:
            return ERROR, f"{where} before a successful initialization (fmi2ExitInitializationMode)"
        if not (math.isfinite(current_time) and math.isfinite(step_size) and step_size > 0):
            return ERROR, (f"{where}: currentCommunicationPoint = {current_time!r}, communicationStepSize = "
                           f"{step_size!r}: both must be finite and the step > 0")
        if not math.isfinite(current_time + step_size):              # the time would become inf (issue 40)
            return ERROR, (f"{where}: currentCommunicationPoint + communicationStepSize = {current_time!r} + "
                           f"{step_size!r} overflows")
        if current_time != self.time and not self._at_time(current_time, step_size):
            return ERROR, (f"{where}: currentCommunicationPoint = {current_time!r} s is not this FMU's time "
                           f"{self.time!r} s (the end of its last step, its start time or the time of the FMU "
                           "state set last): a step starts where the FMU is (fmi2SetFMUstate takes it back)")
        try:
            ok = bool(self.step(current_time, step_size))
        except Exception as exc:                                      # noqa: BLE001 - the state is kept
            return DISCARD, f"{where} at t = {current_time:.9g} s failed: {type(exc).__name__}: {exc}"
        if not ok:
            return DISCARD, ""
        self.time = current_time + step_size
        self.input_derivatives.clear()                               # set again by the master for the next step
        return _OK

    def _at_time(self, current_time: float, step_size: float) -> bool:
        """Is `current_time` the FMU's time, to within the rounding of the master's clock?"""
        scale = max(abs(self.time), abs(current_time), abs(self.start_time), step_size)
        return abs(current_time - self.time) <= COMMUNICATION_POINT_TOLERANCE * scale

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
            if var.causality in ("output", "local", "independent"):
                kind = {"output": "an output", "local": "calculated", "independent": "the independent variable"}
                return ERROR, f"{where}: {var.name} is {kind[var.causality]}; it cannot be set"
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
        non-finite output with fmi2OK). Model Exchange: from initialization mode on."""
        if self.me_mode is None and self.interface == MODEL_EXCHANGE and not self.entered and not self.terminated:
            return ERROR, [math.nan] * len(vrs), self.me_refusal("fmi2GetReal")
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
        if self.me_mode is None and self.interface == MODEL_EXCHANGE and not self.entered and not self.terminated:
            return ERROR, [0] * len(vrs), self.me_refusal("fmi2GetInteger")
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

    def _variable(self, vr: int) -> Variable | None:
        return self.variables[vr] if isinstance(vr, int) and 0 <= vr < len(self.variables) else None

    def _describe_vr(self, vr: int) -> str:
        var = self._variable(vr)
        return f"valueReference {vr} ({var.causality} {var.name})" if var is not None else f"valueReference {vr} (unknown)"
