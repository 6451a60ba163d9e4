"""The FMI 2.0 Model Exchange functions of an emcosim FMU and their state machine (FMI 2.0, section 3.2.3).

The FMU's binary creates every instance in pythonfmu as a Co-Simulation one (pythonfmu has no Model
Exchange) and tells the slave the host's fmuType (`fmi2_set_interface`). In a Model Exchange instance,
after fmi2ExitInitializationMode, the host's solver integrates the slave's continuous states:

    instantiated -> initialization -> event <-> continuous-time -> terminated

`ALLOWED` is the standard's table of the modes each function may be called in (the same as the masks of
the Modelica Association's Reference FMUs and of the FMU SDK): fmi2SetTime in event and continuous-time
mode; fmi2SetContinuousStates in continuous-time mode only (a host's solver sets the states it tries;
after an event the FMU says whether it changed them); fmi2GetDerivatives in event and continuous-time
mode and after fmi2Terminate; fmi2GetEventIndicators and fmi2GetContinuousStates also in initialization
mode; fmi2GetNominalsOfContinuousStates after fmi2Instantiate, in event and continuous-time mode and after
fmi2Terminate; fmi2EnterEventMode in event and continuous-time mode; fmi2NewDiscreteStates and
fmi2EnterContinuousTimeMode in event mode; fmi2CompletedIntegratorStep in continuous-time mode. Of the
common functions, fmi2Terminate (event, continuous-time mode), fmi2GetReal/fmi2GetInteger and
fmi2GetDirectionalDerivative (from initialization mode on) have modes of their own in Model Exchange;
fmi2DoStep and the other Co-Simulation functions are refused in a Model Exchange instance, and every
function of this module in a Co-Simulation one. Every refused call answers fmi2Error with a message that
names the function, the mode and the modes it is allowed in.

The adapter gives the model through the hooks `continuous_states`, `set_continuous_states`,
`state_derivatives`, `event_indicators`, `nominals` and `domain_problem`. The event indicators are the
margins to the boundaries of the model's admissible domain (positive inside): a host's solver that finds
one crossing zero enters event mode there, and fmi2NewDiscreteStates ends the run with fmi2Error and a
message that names the boundary (the model is not defined beyond it), instead of integrating through.
Derivatives at a state the host's solver tries beyond the boundary are still computed where they are
finite (the solver needs them to locate the event); where they are not, fmi2GetDerivatives answers
fmi2Discard, which asks the host for a smaller step.

The hot calls of a host's solver (fmi2SetTime, fmi2SetContinuousStates, fmi2GetDerivatives) test their mode
with one or two attribute reads and build no message unless they refuse.
"""
from __future__ import annotations

import math
from typing import ClassVar

from .status import CO_SIMULATION, DISCARD, ERROR, MODEL_EXCHANGE, OK
from .status import DONE as _OK

INSTANTIATED, INITIALIZATION, EVENT, CONTINUOUS, TERMINATED = (
    "instantiated", "initialization", "event", "continuous", "terminated")
MODE_NAMES = {INSTANTIATED: "after fmi2Instantiate", INITIALIZATION: "initialization mode", EVENT: "event mode",
              CONTINUOUS: "continuous-time mode", TERMINATED: "after fmi2Terminate"}
_FROM_INITIALIZATION = (INITIALIZATION, EVENT, CONTINUOUS, TERMINATED)
# FMI 2.0, section 3.2.3: the modes in which each function may be called in a Model Exchange instance
ALLOWED: dict[str, tuple[str, ...]] = {
    "fmi2SetTime": (EVENT, CONTINUOUS),
    "fmi2SetContinuousStates": (CONTINUOUS,),
    "fmi2GetDerivatives": (EVENT, CONTINUOUS, TERMINATED),
    "fmi2GetEventIndicators": _FROM_INITIALIZATION,
    "fmi2GetContinuousStates": _FROM_INITIALIZATION,
    "fmi2GetNominalsOfContinuousStates": (INSTANTIATED, EVENT, CONTINUOUS, TERMINATED),
    "fmi2EnterEventMode": (EVENT, CONTINUOUS),
    "fmi2NewDiscreteStates": (EVENT,),
    "fmi2EnterContinuousTimeMode": (EVENT,),
    "fmi2CompletedIntegratorStep": (CONTINUOUS,),
    # common functions whose modes differ from Co-Simulation's
    "fmi2Terminate": (EVENT, CONTINUOUS),
    "fmi2GetReal": _FROM_INITIALIZATION,
    "fmi2GetInteger": _FROM_INITIALIZATION,
    "fmi2GetDirectionalDerivative": _FROM_INITIALIZATION,
}
NO_EVENT_INFO = (0, 0, 0, 0, 0, 0.0)   # fmi2EventInfo: nothing discrete changes, no time event


class ModelExchangeFunctions:
    """The Model Exchange functions of EMSlave (slave.py)."""

    number_of_event_indicators: ClassVar[int] = 0

    def init_model_exchange(self) -> None:
        self.me_mode: str | None = None        # EVENT or CONTINUOUS once a Model Exchange instance is initialized
        self.state_names: list[str] = []       # the continuous states, in the order of the state vector

    # ---- the adapter's hooks ----------------------------------------------------------------------
    def continuous_states(self) -> list[float]:
        """The state vector x (in the order of `state_names`)."""
        return []

    def set_continuous_states(self, x: list[float]) -> None:
        """Take the state vector x (finite floats, of the right length)."""

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

    # ---- the state machine --------------------------------------------------------------------------
    def entered_event_mode(self) -> None:
        """fmi2ExitInitializationMode succeeded: a Model Exchange instance is in event mode."""
        if self.interface == MODEL_EXCHANGE:
            self.me_mode = EVENT

    def me_state(self) -> str:
        """The mode of a Model Exchange instance (one of MODE_NAMES)."""
        if self.terminated:
            return TERMINATED
        if self.entered:
            return INITIALIZATION
        return self.me_mode or INSTANTIATED

    def me_refusal(self, function: str) -> str:
        """'' if `function` may be called now (`ALLOWED`; every function there is Model Exchange only, or has
        Model Exchange modes, as the caller knows), else why not."""
        if self.interface == CO_SIMULATION:
            return (f"{self.model_identifier}: {function}: this instance is a Co-Simulation one (fmi2Instantiate's "
                    "fmuType); Model Exchange functions are refused")
        mode = self.me_state()
        if mode in ALLOWED[function]:
            return ""
        allowed = ", ".join(MODE_NAMES[m] for m in ALLOWED[function])
        return f"{self.model_identifier}: {function} is not allowed in {MODE_NAMES[mode]} (allowed: {allowed})"

    def cs_only(self, function: str) -> str:
        """'' in a Co-Simulation instance, else why a Co-Simulation function is refused."""
        if self.interface == CO_SIMULATION:
            return ""
        return (f"{self.model_identifier}: {function}: this instance is a Model Exchange one (fmi2Instantiate's "
                "fmuType); Co-Simulation functions are refused")

    def _checked_vector(self, function: str, values: list[float], n: int) -> tuple[int, list[float], str]:
        """(OK, values, '') if there are n finite values, else (ERROR, [], why not)."""
        if len(values) != n:
            return ERROR, [], f"{self.model_identifier}: {function}: {n} values asked for, the FMU has {len(values)}"
        total = sum(values)
        if not total - total == 0.0 and not all(math.isfinite(v) for v in values):
            bad = ", ".join(f"{name} = {v}" for name, v in zip(self.state_names, values) if not math.isfinite(v))
            return ERROR, [], f"{self.model_identifier}: {function}: not finite: {bad}"
        return OK, values, ""

    # ---- the functions (called by the binary with the GIL held; never raise) -------------------------
    def fmi2_set_time(self, time: float) -> tuple[int, str]:
        if self.me_mode is None or self.terminated:                  # allowed: event, continuous-time mode
            return ERROR, self.me_refusal("fmi2SetTime")
        if not time - time == 0.0:
            return ERROR, f"{self.model_identifier}: fmi2SetTime: time = {time!r} is not finite"
        self.time = time
        return _OK

    def fmi2_set_continuous_states(self, x: list[float]) -> tuple[int, str]:
        """Take the states the host's solver tries (a list of floats from the binary); the state is kept
        when they are refused."""
        if self.me_mode != CONTINUOUS or self.terminated:            # allowed: continuous-time mode
            return ERROR, self.me_refusal("fmi2SetContinuousStates")
        if len(x) != len(self.state_names):
            return ERROR, (f"{self.model_identifier}: fmi2SetContinuousStates: {len(x)} values for "
                           f"{len(self.state_names)} states ({', '.join(self.state_names) or 'none'})")
        total = sum(x)
        if not total - total == 0.0 and not all(math.isfinite(v) for v in x):
            bad = ", ".join(f"{name} = {v}" for name, v in zip(self.state_names, x) if not math.isfinite(v))
            return ERROR, f"{self.model_identifier}: fmi2SetContinuousStates: not finite: {bad}; the state is kept"
        try:
            self.set_continuous_states(x)
        except Exception as exc:                                      # noqa: BLE001 - reported, never raised
            return ERROR, f"{self.model_identifier}: fmi2SetContinuousStates failed: {type(exc).__name__}: {exc}"
        return _OK

    def fmi2_get_continuous_states(self, n: int) -> tuple[int, list[float], str]:
        problem = self.me_refusal("fmi2GetContinuousStates")
        if problem:
            return ERROR, [], problem
        try:
            return self._checked_vector("fmi2GetContinuousStates", [float(v) for v in self.continuous_states()], n)
        except Exception as exc:                                      # noqa: BLE001 - reported, never raised
            return ERROR, [], f"{self.model_identifier}: fmi2GetContinuousStates failed: {type(exc).__name__}: {exc}"

    def fmi2_get_derivatives(self, n: int) -> tuple[int, list[float], str]:
        """dx/dt; fmi2Discard (asks the host's solver for a smaller step) where it is not finite."""
        if self.me_mode is None:                                     # allowed: event, continuous-time, terminated
            return ERROR, [], self.me_refusal("fmi2GetDerivatives")
        try:
            dx = self.state_derivatives()
        except (ValueError, ArithmeticError) as exc:
            return DISCARD, [], f"{self.model_identifier}: fmi2GetDerivatives at t = {self.time:.9g} s: {exc}"
        except Exception as exc:                                      # noqa: BLE001 - reported, never raised
            return ERROR, [], f"{self.model_identifier}: fmi2GetDerivatives failed: {type(exc).__name__}: {exc}"
        if len(dx) != n:
            return ERROR, [], (f"{self.model_identifier}: fmi2GetDerivatives: {n} values asked for, the FMU has "
                               f"{len(dx)} states ({', '.join(self.state_names) or 'none'})")
        total = sum(dx)
        if total - total == 0.0:                                      # all finite (else nan, or an overflow)
            return OK, dx, ""
        if all(math.isfinite(v) for v in dx):
            return OK, dx, ""
        state = ", ".join(f"{name} = {v!r}" for name, v in zip(self.state_names, self.continuous_states()))
        return DISCARD, [], (f"{self.model_identifier}: fmi2GetDerivatives at t = {self.time:.9g} s: not finite "
                             f"at the state {state}")

    def fmi2_get_event_indicators(self, n: int) -> tuple[int, list[float], str]:
        problem = self.me_refusal("fmi2GetEventIndicators")
        if problem:
            return ERROR, [], problem
        try:
            values = [float(v) for v in self.event_indicators()]
        except Exception as exc:                                      # noqa: BLE001 - reported, never raised
            return ERROR, [], f"{self.model_identifier}: fmi2GetEventIndicators failed: {type(exc).__name__}: {exc}"
        if len(values) != n:
            return ERROR, [], (f"{self.model_identifier}: fmi2GetEventIndicators: {n} values asked for, the FMU has "
                               f"{len(values)} (numberOfEventIndicators)")
        return OK, values, ""

    def fmi2_get_nominals_of_continuous_states(self, n: int) -> tuple[int, list[float], str]:
        problem = self.me_refusal("fmi2GetNominalsOfContinuousStates")
        if problem:
            return ERROR, [], problem
        try:
            return self._checked_vector("fmi2GetNominalsOfContinuousStates", [float(v) for v in self.nominals()], n)
        except Exception as exc:                                      # noqa: BLE001 - reported, never raised
            return ERROR, [], (f"{self.model_identifier}: fmi2GetNominalsOfContinuousStates failed: "
                               f"{type(exc).__name__}: {exc}")

    def fmi2_enter_event_mode(self) -> tuple[int, str]:
        problem = self.me_refusal("fmi2EnterEventMode")
        if problem:
            return ERROR, problem
        self.me_mode = EVENT
        return _OK

    def fmi2_new_discrete_states(self) -> tuple[int, tuple, str]:
        """(newDiscreteStatesNeeded, terminateSimulation, nominalsOfContinuousStatesChanged,
        valuesOfContinuousStatesChanged, nextEventTimeDefined, nextEventTime): nothing discrete changes;
        at a state on or past a boundary of the domain, fmi2Error with the boundary (module docstring)."""
        problem = self.me_refusal("fmi2NewDiscreteStates")
        if problem:
            return ERROR, NO_EVENT_INFO, problem
        try:
            reason = self.domain_problem()
        except Exception as exc:                                      # noqa: BLE001 - reported, never raised
            reason = f"{type(exc).__name__}: {exc}"
        if reason:
            return ERROR, (0, 1, 0, 0, 0, 0.0), (f"{self.model_identifier}: at t = {self.time:.9g} s {reason}: the "
                                                  "model is not defined beyond it; the simulation must end here")
        return OK, NO_EVENT_INFO, ""

    def fmi2_enter_continuous_time_mode(self) -> tuple[int, str]:
        problem = self.me_refusal("fmi2EnterContinuousTimeMode")
        if problem:
            return ERROR, problem
        self.me_mode = CONTINUOUS
        return _OK

    def fmi2_completed_integrator_step(self, no_set_prior: int) -> tuple[int, tuple, str]:
        """(enterEventMode, terminateSimulation): never asks for either (the event indicators do)."""
        problem = self.me_refusal("fmi2CompletedIntegratorStep")
        if problem:
            return ERROR, (0, 0), problem
        return OK, (0, 0), ""
