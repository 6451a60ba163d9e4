"""The FMI 2.0 Model Exchange functions of an emcosim FMU and their state machine (FMI 2.0, section 3.2.3).

The FMU's binary creates every instance in pythonfmu as a Co-Simulation one (pythonfmu has no Model
Exchange) and tells the slave the host's fmuType (`fmi2_set_interface`). In a Model Exchange instance,
after fmi2ExitInitializationMode, the host's solver integrates the slave's continuous states:

    instantiated -> initialization -> event <-> continuous -> terminated

- fmi2SetTime: event and continuous-time mode; fmi2SetContinuousStates: event and continuous-time mode (FMI
  2.0 allows continuous-time mode; hosts that re-initialize states after an event also set them in event
  mode);
- fmi2GetDerivatives, fmi2GetEventIndicators, fmi2GetContinuousStates: initialization, event, continuous-time
  mode and after fmi2Terminate; fmi2GetNominalsOfContinuousStates: any time after fmi2Instantiate;
- fmi2EnterEventMode: event and continuous-time mode; fmi2NewDiscreteStates and fmi2EnterContinuousTimeMode:
  event mode; fmi2CompletedIntegratorStep: continuous-time mode;
- fmi2DoStep is refused, as every function of this module in a Co-Simulation instance.

Every other call is refused with fmi2Error and a message. The adapter gives the model through the hooks
`continuous_states`, `set_continuous_states`, `state_derivatives`, `event_indicators`, `nominals` and
`domain_problem`. The event indicators are the margins to the boundaries of the model's admissible domain
(positive inside): a host's solver that finds one crossing zero enters event mode there, and
fmi2NewDiscreteStates ends the run with fmi2Error and a message that names the boundary (the model is
not defined beyond it), instead of integrating through. Derivatives at a state the host's solver tries
beyond the boundary are still computed where they are finite (the solver needs them to locate the
event); where they are not, fmi2GetDerivatives answers fmi2Discard, which asks the host for a smaller
step.
"""
from __future__ import annotations

import math
from typing import ClassVar

from .status import CO_SIMULATION, DISCARD, ERROR, OK
from .status import DONE as _OK

EVENT, CONTINUOUS = "event", "continuous"


class ModelExchangeFunctions:
    """The Model Exchange functions of EMSlave (slave.py)."""

    number_of_event_indicators: ClassVar[int] = 0

    def init_model_exchange(self) -> None:
        self.me_mode: str | None = None         # EVENT or CONTINUOUS once a Model Exchange instance is initialized
        self.state_names: list[str] = []       # the continuous states, in the order of the state vector
        self._no_info = (0, 0, 0, 0, 0, 0.0)

    # ---- the adapter's hooks ----------------------------------------------------------------------
    def continuous_states(self) -> list[float]:
        """The state vector x (in the order of `state_names`)."""
        return []

    def set_continuous_states(self, x: list[float]) -> None:
        """Take the state vector x (finite, of the right length)."""

    def state_derivatives(self) -> list[float]:
        """dx/dt at the current time, state and inputs (ValueError or ArithmeticError with the reason)."""
        return []

    def event_indicators(self) -> list[float]:
        """The margins to the domain's boundaries at the current state (positive inside)."""
        return []

    def nominals(self) -> list[float]:
        """The typical magnitude of each state (for the host's absolute tolerances)."""
        return []

    def domain_problem(self) -> str:
        """'' if the current state is inside the admissible domain, else which boundary it reached."""
        return ""

    def time_changed(self) -> None:
        """Hook: fmi2SetTime moved the time (sources drop what depended on it)."""

    # ---- the state machine --------------------------------------------------------------------------
    def entered_event_mode(self) -> None:
        """fmi2ExitInitializationMode succeeded: a Model Exchange instance is in event mode."""
        if self.interface != CO_SIMULATION:
            self.me_mode = EVENT

    def _refused(self, function: str, allowed: tuple[str, ...]) -> str:
        """'' if `function` may be called now (in one of the modes `allowed`), else why not."""
        where = f"{self.model_identifier}: {function}"
        if self.interface == CO_SIMULATION:
            return (f"{where}: this instance is a Co-Simulation one (fmi2Instantiate's fmuType); Model Exchange "
                    "functions are refused")
        mode = ("terminated" if self.terminated else "initialization" if self.entered
                else self.me_mode if self.me_mode is not None else "instantiated")
        if mode in allowed:
            return ""
        names = {"instantiated": "after fmi2Instantiate", "initialization": "initialization mode",
                 EVENT: "event mode", CONTINUOUS: "continuous-time mode", "terminated": "after fmi2Terminate"}
        return f"{where} is not allowed in {names[mode]} (allowed: {', '.join(names[m] for m in allowed)})"

    def _vector(self, function: str, values: list[float], n: int) -> tuple[int, list[float], str]:
        if len(values) != n:
            return ERROR, [], f"{self.model_identifier}: {function}: {n} values asked for, the FMU has {len(values)}"
        if not math.isfinite(sum(values)):
            bad = [f"{name} = {v}" for name, v in zip(self.state_names or range(n), values) if not math.isfinite(v)]
            return ERROR, [], f"{self.model_identifier}: {function}: not finite: {', '.join(map(str, bad)) or values}"
        return OK, values, ""

    # ---- the functions (called by the binary with the GIL held; never raise) -------------------------
    def fmi2_set_time(self, time: float) -> tuple[int, str]:
        problem = self._refused("fmi2SetTime", (EVENT, CONTINUOUS))
        if problem:
            return ERROR, problem
        if not math.isfinite(time):
            return ERROR, f"{self.model_identifier}: fmi2SetTime: time = {time!r} is not finite"
        if time != self.time:
            self.time = float(time)
            self.time_changed()
        return _OK

    def fmi2_set_continuous_states(self, x: list[float]) -> tuple[int, str]:
        problem = self._refused("fmi2SetContinuousStates", (EVENT, CONTINUOUS))
        if problem:
            return ERROR, problem
        n = len(self.state_names)
        if len(x) != n:
            return ERROR, f"{self.model_identifier}: fmi2SetContinuousStates: {len(x)} values for {n} states"
        if not math.isfinite(sum(x)):
            bad = [f"{name} = {v}" for name, v in zip(self.state_names, x) if not math.isfinite(v)]
            return ERROR, f"{self.model_identifier}: fmi2SetContinuousStates: not finite: {', '.join(bad)}; the state is kept"
        try:
            self.set_continuous_states([float(v) for v in x])
        except Exception as exc:                                      # noqa: BLE001 - reported, never raised
            return ERROR, f"{self.model_identifier}: fmi2SetContinuousStates failed: {type(exc).__name__}: {exc}"
        return _OK

    def fmi2_get_continuous_states(self, n: int) -> tuple[int, list[float], str]:
        problem = self._refused("fmi2GetContinuousStates", ("initialization", EVENT, CONTINUOUS, "terminated"))
        if problem:
            return ERROR, [], problem
        try:
            return self._vector("fmi2GetContinuousStates", [float(v) for v in self.continuous_states()], n)
        except Exception as exc:                                      # noqa: BLE001 - reported, never raised
            return ERROR, [], f"{self.model_identifier}: fmi2GetContinuousStates failed: {type(exc).__name__}: {exc}"

    def fmi2_get_derivatives(self, n: int) -> tuple[int, list[float], str]:
        """dx/dt; fmi2Discard (asks the host's solver for a smaller step) where it is not finite."""
        problem = self._refused("fmi2GetDerivatives", ("initialization", EVENT, CONTINUOUS, "terminated"))
        if problem:
            return ERROR, [], problem
        where = f"{self.model_identifier}: fmi2GetDerivatives"
        try:
            dx = self.state_derivatives()
        except (ValueError, ArithmeticError) as exc:
            return DISCARD, [], f"{where} at t = {self.time:.9g} s: {exc}"
        except Exception as exc:                                      # noqa: BLE001 - reported, never raised
            return ERROR, [], f"{where} failed: {type(exc).__name__}: {exc}"
        if len(dx) != n:
            return ERROR, [], f"{where}: {n} values asked for, the FMU has {len(dx)}"
        if not math.isfinite(sum(dx)):
            state = ", ".join(f"{name} = {v!r}" for name, v in zip(self.state_names, self.continuous_states()))
            return DISCARD, [], f"{where} at t = {self.time:.9g} s: not finite at the state {state}"
        return OK, dx, ""

    def fmi2_get_event_indicators(self, n: int) -> tuple[int, list[float], str]:
        problem = self._refused("fmi2GetEventIndicators", ("initialization", EVENT, CONTINUOUS, "terminated"))
        if problem:
            return ERROR, [], problem
        try:
            values = [float(v) for v in self.event_indicators()]
        except Exception as exc:                                      # noqa: BLE001 - reported, never raised
            return ERROR, [], f"{self.model_identifier}: fmi2GetEventIndicators failed: {type(exc).__name__}: {exc}"
        if len(values) != n:
            return ERROR, [], f"{self.model_identifier}: fmi2GetEventIndicators: {n} values asked for, the FMU has {len(values)}"
        return OK, values, ""

    def fmi2_get_nominals_of_continuous_states(self, n: int) -> tuple[int, list[float], str]:
        problem = self._refused("fmi2GetNominalsOfContinuousStates",
                                ("instantiated", "initialization", EVENT, CONTINUOUS, "terminated"))
        if problem:
            return ERROR, [], problem
        try:
            return self._vector("fmi2GetNominalsOfContinuousStates", [float(v) for v in self.nominals()], n)
        except Exception as exc:                                      # noqa: BLE001 - reported, never raised
            return ERROR, [], f"{self.model_identifier}: fmi2GetNominalsOfContinuousStates failed: {type(exc).__name__}: {exc}"

    def fmi2_enter_event_mode(self) -> tuple[int, str]:
        problem = self._refused("fmi2EnterEventMode", (EVENT, CONTINUOUS))
        if problem:
            return ERROR, problem
        self.me_mode = EVENT
        return _OK

    def fmi2_new_discrete_states(self) -> tuple[int, tuple, str]:
        """(newDiscreteStatesNeeded, terminateSimulation, nominalsOfContinuousStatesChanged,
        valuesOfContinuousStatesChanged, nextEventTimeDefined, nextEventTime): nothing discrete changes;
        at a state on or past a boundary of the domain, fmi2Error with the boundary (module docstring)."""
        problem = self._refused("fmi2NewDiscreteStates", (EVENT,))
        if problem:
            return ERROR, self._no_info, problem
        try:
            reason = self.domain_problem()
        except Exception as exc:                                      # noqa: BLE001 - reported, never raised
            reason = f"{type(exc).__name__}: {exc}"
        if reason:
            return ERROR, (0, 1, 0, 0, 0, 0.0), (f"{self.model_identifier}: at t = {self.time:.9g} s {reason}: the "
                                                  "model is not defined beyond it; the simulation must end here")
        return OK, self._no_info, ""

    def fmi2_enter_continuous_time_mode(self) -> tuple[int, str]:
        problem = self._refused("fmi2EnterContinuousTimeMode", (EVENT,))
        if problem:
            return ERROR, problem
        self.me_mode = CONTINUOUS
        return _OK

    def fmi2_completed_integrator_step(self, no_set_prior: int) -> tuple[int, tuple, str]:
        """(enterEventMode, terminateSimulation): never asks for either (the event indicators do)."""
        problem = self._refused("fmi2CompletedIntegratorStep", (CONTINUOUS,))
        if problem:
            return ERROR, (0, 0), problem
        return OK, (0, 0), ""
