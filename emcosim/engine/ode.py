"""The FMUs of a scenario as one ODE x' = F(t, x), for Model Exchange runs (model_exchange.py).

The state vector x is every FMU's continuous states one after the other, each scaled by its nominal value
(fmi2GetNominalsOfContinuousStates), so that the solver's absolute tolerance rtol means rtol of each state's
typical magnitude. The right-hand side at (t, x):

1. fmi2SetTime on every FMU, fmi2SetContinuousStates on every FMU with states;
2. the connected values resolved in dependency order (plan.py, the same plan as a Co-Simulation run): the
   outputs of level 0 (states, sources), the inputs they feed, the direct-feedthrough outputs of level 1...;
3. fmi2GetDerivatives of every FMU with states.

The Jacobian dF/dx is assembled by the chain rule from the FMUs' directional derivatives (where every FMU
with states or connected inputs provides them): each FMU's d(derivatives, connected outputs)/d(states,
connected inputs), one fmi2GetDirectionalDerivative per known, then the outputs in dependency order,
dy/dx = dy/dx_own + dy/du du/dx with du/dx = factor dy_source/dx along each connection. Otherwise the
solver takes finite differences. Events: `indicators`, `event` (fmi2EnterEventMode, fmi2NewDiscreteStates
until none asks for more, fmi2EnterContinuousTimeMode) and `completed_step`.

Stopping: every evaluation (right-hand side, Jacobian, event indicators, a recorded row) sets the point
first (`set_point`), and that is where a Ctrl-C or SIGTERM stops the run (`stopping.check` raises
`Interrupted`): between two FMU calls, however long a solver step takes; so does every round of an event.

Cost: with native FMUs an evaluation is 8-10 FMI calls of 0.2 us each, and the Python around them is the
rest. So every call of an evaluation is made on arguments built once (the C functions without fmpy's
argument types, fmi.bare; the states, derivatives, indicators and connected values in numpy buffers
passed by address: `_Buffers`), a point the FMUs are at already is not set again (the step's end: its
indicators, then fmi2CompletedIntegratorStep), a row makes only the calls its recorded values need (an
output that is a continuous state, state_references, is taken from the state vector: the paper's loops' rows
call only the controller, 3 calls instead of 6, and a step's rows are made in one loop, `rows`), the
Jacobian's directional derivatives write straight into one matrix (`_JacobianPlan`), and no clock is read
unless `timed`. Measured on the maglev loop of maglev_tracking_D-1_R0.82 (2e4 evaluations at one state,
CPU time, this project's 2-core machine), before this design and after: a right-hand side 14.0 -> 4.4 us
with the native FMUs (31.8 -> 17.9 us with the pythonfmu ones), a Jacobian 55 -> 14 us (189 -> 92), a
recorded row 11.3 -> 3.3 us (25.8 -> 13.9); the rows of maglev_regulation_prop2 with state outputs from the
state vector 2.8 -> 2.2 us a row (docs/scenarios.md).
"""
from __future__ import annotations

import ctypes
import math
import time
from dataclasses import dataclass, field
from typing import Any, Callable

import numpy as np

from . import stopping
from .errors import SimulationError
from .fmi import STATUS, FMICallException, bare, fmi2EventInfo
from .instances import Instance, last_message
from .plan import Plan, n_slots, resolve_values
from .ssd import Scenario
from .transfer import NonFinite, Transfer

MAX_EVENT_ITERATIONS = 100        # fmi2NewDiscreteStates rounds of one event


@dataclass
class Statistics:
    """What the integration cost."""

    solver: str
    rtol: float
    steps: int = 0                # accepted solver steps
    rhs: int = 0                  # right-hand sides (every FMU's derivatives once)
    jacobians: int = 0            # Jacobians assembled from directional derivatives
    events: int = 0               # state and time events handled
    exact_jacobian: bool = False  # from the FMUs' directional derivatives (else finite differences)
    tolerance: float | None = None        # a run with a tolerance: it,
    estimated_error: float | None = None  # the estimated global error of the result
    solves: int = 1                       # and the solves it took (ModelExchangeSimulation)

    def summary(self) -> str:
        jac = (f"{self.jacobians} Jacobians from the FMUs' directional derivatives" if self.exact_jacobian
               else "finite-difference Jacobians")
        events = f", {self.events} events" if self.events else ""
        control = ""
        if self.tolerance is not None:
            control = (f"; tolerance {self.tolerance:g}: {self.solves} solves, estimated error "
                       f"{self.estimated_error:.2g}")
        return (f"Model Exchange: {self.solver} at rtol {self.rtol:.3g}: {self.steps} steps, {self.rhs} right-hand "
                f"sides, {jac}{events}{control}")


@dataclass
class _Unit:
    """One FMU of the ODE: its raw Model Exchange functions and where its states are in x."""

    inst: Instance
    offset: int
    n: int                                          # continuous states
    nz: int                                         # event indicators
    calls: dict = field(default_factory=dict)       # FMI function -> raw ctypes function
    x: Any = None                                   # ctypes arrays of its states, derivatives, indicators
    dx: Any = None
    z: Any = None
    states: dict = field(default_factory=dict)      # value reference of a continuous state -> its index in x


class System:
    """The FMUs of a scenario as one ODE x' = F(t, x) (module docstring), x scaled by the nominals.

    `timed`: measure the time inside the FMUs' calls (`fmu_time`) and in this object's evaluations
    (`engine_time`); off, no clock is read (about 0.1 us a call)."""

    def __init__(self, scenario: Scenario, instances: dict[str, Instance], connections, plan: Plan,
                 timed: bool = False, buffered: bool | None = None):
        self.scenario, self.instances, self.connections, self.plan = scenario, instances, connections, plan
        self.timed = timed
        self.fmu_time = 0.0                          # inside the FMUs' calls (timed; the transfers time theirs)
        self.engine_time = 0.0                       # inside this object's methods the solver and the run call
        self.units: list[_Unit] = []
        offset = 0
        for inst in instances.values():
            md = inst.model_description
            unit = _Unit(inst, offset, len(md.derivatives), int(md.numberOfEventIndicators or 0))
            unit.states = state_references(md, offset)
            for name in ("fmi2SetTime", "fmi2SetContinuousStates", "fmi2GetDerivatives", "fmi2GetEventIndicators",
                         "fmi2GetContinuousStates", "fmi2GetNominalsOfContinuousStates", "fmi2EnterEventMode",
                         "fmi2NewDiscreteStates", "fmi2EnterContinuousTimeMode", "fmi2CompletedIntegratorStep"):
                unit.calls[name] = inst.raw(name)
            unit.x, unit.dx = (ctypes.c_double * unit.n)(), (ctypes.c_double * unit.n)()
            unit.z = (ctypes.c_double * unit.nz)()
            self.units.append(unit)
            offset += unit.n
        self.n = offset
        self.with_states = [u for u in self.units if u.n > 0]
        self.with_indicators = [u for u in self.units if u.nz > 0]
        self.step_reporters = [u for u in self.units if needs_completed_step(u.inst.model_description)]
        self.scale = np.ones(self.n)
        fed = {c.end_element for c in connections}
        knowing = [u for u in self.units if u.n > 0 or u.inst.name in fed]     # FMUs whose unknowns depend on x
        self.statistics: Statistics | None = None
        self.time: float | None = None               # the time the FMUs were last set to (fmi2SetTime)
        self.discarded = ""                          # the last fmi2Discard of fmi2GetDerivatives
        self.failed: Instance | None = None          # the instance whose call failed last
        self._point: bytes | None = None             # the scaled state the FMUs are at, values resolved (time: self.time)
        self._recorded = False                       # ... and the recorded values got too
        self._hot_calls()
        if buffered is None:
            buffered = all(t.real and t.orders is None for t in transfers(plan))
        self.values: _Buffers | _Transfers = _Buffers(self) if buffered else _Transfers(self)
        # a row's calls (_Buffers.row_units): the time and the states of only the FMUs the recorded values need
        row_units = getattr(self.values, "row_units", None)
        self._row_calls = None if row_units is None or row_units == {u.inst.name for u in self.units} else (
            [c for c in self._set_time if c[2].inst.name in row_units],
            [c for c in self._set_states if c[2].inst.name in row_units])
        self.jacobian_plan = _JacobianPlan(self) if all(
            u.inst.model_description.modelExchange.providesDirectionalDerivative for u in knowing) else None

    def bare(self, inst: Instance, function: str):
        """`function` of inst without fmpy's argument types (fmi.bare); timed if the system is."""
        fn = bare(inst.fmu, function)
        if not self.timed:
            return fn

        def timed(*args) -> int:
            tic = time.perf_counter()
            try:
                return fn(*args)
            finally:
                self.fmu_time += time.perf_counter() - tic
        return timed

    def _hot_calls(self) -> None:
        """The calls of every evaluation, their arguments built once: [(function, arguments, unit)] of
        fmi2SetTime (the time in one c_double), fmi2SetContinuousStates, fmi2GetDerivatives and
        fmi2GetEventIndicators, on numpy buffers of all units (`_x`, `_dx`, `_z`) by address."""
        self._t = ctypes.c_double(0.0)
        self._x, self._dx = np.zeros(self.n), np.zeros(self.n)
        self._z = np.zeros(sum(u.nz for u in self.with_indicators))
        self._component = {u.inst.name: ctypes.c_void_p(u.inst.component) for u in self.units}

        def at(buffer: np.ndarray, k: int) -> ctypes.c_void_p:
            return ctypes.c_void_p(buffer.ctypes.data + 8 * k)

        def calls(function: str, units, args) -> list:
            return [(self.bare(u.inst, function), (self._component[u.inst.name], *args(u)), u) for u in units]
        self._set_time = calls("fmi2SetTime", self.units, lambda u: (self._t,))
        self._set_states = calls("fmi2SetContinuousStates", self.with_states,
                                 lambda u: (at(self._x, u.offset), ctypes.c_size_t(u.n)))
        self._get_derivatives = calls("fmi2GetDerivatives", self.with_states,
                                      lambda u: (at(self._dx, u.offset), ctypes.c_size_t(u.n)))
        offsets = np.cumsum([0] + [u.nz for u in self.with_indicators])
        self._get_indicators = [(fn, (c, at(self._z, int(k)), size), u) for (fn, (c, _, size), u), k in
                                zip(calls("fmi2GetEventIndicators", self.with_indicators,
                                          lambda u: (None, ctypes.c_size_t(u.nz))), offsets)]
        self._enter, self._terminate = ctypes.c_int(0), ctypes.c_int(0)
        self._completed = calls("fmi2CompletedIntegratorStep", self.step_reporters,
                                lambda u: (ctypes.c_int(1), ctypes.byref(self._enter), ctypes.byref(self._terminate)))

    # ---- FMI calls ----------------------------------------------------------------------------------
    def call(self, unit: _Unit, function: str, *args) -> int:
        """One FMI call outside the evaluations (events, initialization): the FMUs may change, so the point
        is set again at the next evaluation."""
        self._point = None
        tic = time.perf_counter()
        status = unit.calls[function](unit.inst.component, *args)
        self.fmu_time += time.perf_counter() - tic
        if status > 2 or (status == 2 and function != "fmi2GetDerivatives"):
            raise self.failure(unit.inst, function, status)
        return status

    def failure(self, inst: Instance, function: str, status: int | None = None) -> SimulationError:
        """The error of a failed call of inst (remembered as `failed`)."""
        self.failed = inst
        what = "" if status is None else f" (status {STATUS[status] if 0 <= status < 6 else status})"
        t = self.time if self.time is not None else float("nan")
        return SimulationError(f"{inst.path.name}: component '{inst.name}' failed in {function}{what} at t = "
                               f"{t:.9g} s{last_message(inst)}")

    def set_point(self, t: float, xi: np.ndarray, record: bool = False) -> None:
        """The FMUs at time t and scaled state xi, their connected values resolved (and the recorded ones).
        A stop asked for by a signal ends the run here (module docstring). The point the FMUs are at already
        (the end of a step: its indicators, then fmi2CompletedIntegratorStep; Radau's last right-hand side)
        is not set again."""
        stopping.check()
        point = xi.tobytes()
        if point == self._point and t == self.time:
            if record and not self._recorded:
                self.values.resolve(t, record=True, connected=False)
                self._recorded = True
            return
        if record and self._row_calls is not None:
            self._row_point(t, xi)
            return
        self._point = None
        if t != self.time:
            self.time = t
            self._t.value = t
            for fn, args, unit in self._set_time:
                if fn(*args) > 1:
                    raise self.failure(unit.inst, "fmi2SetTime")
        np.multiply(xi, self.scale, out=self._x)
        for fn, args, unit in self._set_states:
            if fn(*args) > 1:
                raise self.failure(unit.inst, "fmi2SetContinuousStates")
        if self.values.resolve(t, record):
            self._point, self._recorded = point, record

    def _row_point(self, t: float, xi: np.ndarray) -> None:
        """A row's point where some FMUs are not needed (_Buffers: a recorded output that is a continuous state
        is the solver's value, an FMU nobody reads is not called): fmi2SetTime and fmi2SetContinuousStates only
        on the FMUs the row calls, then the row's values. The FMUs are then at different points: the next
        evaluation sets every FMU again."""
        self._point, self.time = None, None
        set_time, set_states = self._row_calls
        self._t.value = t
        for fn, args, unit in set_time:
            if fn(*args) > 1:
                raise self.failure(unit.inst, "fmi2SetTime")
        np.multiply(xi, self.scale, out=self._x)
        for fn, args, unit in set_states:
            if fn(*args) > 1:
                raise self.failure(unit.inst, "fmi2SetContinuousStates")
        self.values.resolve(t, record=True)

    def rows(self, times: list[float], xis: np.ndarray, append: Callable[[float, list], None]) -> None:
        """The rows at `times` (a step's grid points) of the scaled states xis[:, k] (the dense output's):
        append(t, the recorded values) for each. Where a row needs only some FMUs (_row_point), the states of
        all rows are unscaled in one product and each row makes only its calls."""
        if self._row_calls is None:
            for t, xi in zip(times, np.ascontiguousarray(xis.T)):
                self.set_point(t, xi, record=True)
                append(t, self.values.row())
            return
        self._point, self.time = None, None
        set_time, set_states = self._row_calls
        x, t_, values = self._x, self._t, self.values
        assert isinstance(values, _Buffers)
        slots, columns = values.slots, values.columns
        states = np.multiply(xis.T, self.scale, order="C")
        if values.row_states is not None and not set_states:
            # the row's FMUs have no states: the state outputs of all rows picked at once, one copy a row
            target, index = values.row_states
            picked = states[:, index]
            if np.isfinite(picked).all():
                steps = values.row_calls
                for t, state in zip(times, picked):
                    t_.value = t
                    for fn, args, unit in set_time:
                        if fn(*args) > 1:
                            raise self.failure(unit.inst, "fmi2SetTime")
                    slots[target] = state
                    for fn, args, check, transfer in steps:
                        if fn(*args) > 1:
                            raise self.failure(transfer.inst, transfer.function)
                        if check is not None and not math.isfinite(sum(check)):
                            values.not_finite(transfer, check, t)
                    append(t, slots[columns].tolist())
                return
        steps = values.row_sequence
        # _row_point and _Buffers.resolve unrolled (2.6 -> 2.2 us a row); append checks for a stop between rows
        for t, state in zip(times, states):
            t_.value = t
            for fn, args, unit in set_time:
                if fn(*args) > 1:
                    raise self.failure(unit.inst, "fmi2SetTime")
            x[:] = state
            for fn, args, unit in set_states:
                if fn(*args) > 1:
                    raise self.failure(unit.inst, "fmi2SetContinuousStates")
            for fn, args, check, transfer in steps:
                if fn(*args) > 1:
                    raise self.failure(transfer.inst, transfer.function)
                if check is not None and not math.isfinite(sum(check)):
                    values.not_finite(transfer, check, t)
            append(t, slots[columns].tolist())

    def resolve(self, t: float, record: bool = False) -> None:
        """The connected values at the current point (outside the evaluations: initialization, events)."""
        self._point = None
        self.values.resolve(t, record)

    # ---- the ODE -------------------------------------------------------------------------------------
    def rhs(self, t: float, xi: np.ndarray) -> np.ndarray:
        """F(t, x) in scaled states: NaN where an FMU discards the evaluation (fmi2Discard: the solver then
        takes a smaller step)."""
        if not self.timed:
            return self._rhs(t, xi)
        tic = time.perf_counter()
        try:
            return self._rhs(t, xi)
        finally:
            self.engine_time += time.perf_counter() - tic

    def _rhs(self, t: float, xi: np.ndarray) -> np.ndarray:
        self.set_point(t, xi)
        for fn, args, unit in self._get_derivatives:
            status = fn(*args)
            if status > 1:
                if status > 2:
                    raise self.failure(unit.inst, "fmi2GetDerivatives", status)
                self.discarded = last_message(unit.inst)
                return np.full(self.n, math.nan)
        self.statistics.rhs += 1
        return self._dx / self.scale

    def jacobian(self, t: float, xi: np.ndarray) -> np.ndarray:
        if not self.timed:
            return self._jacobian(t, xi)
        tic = time.perf_counter()
        try:
            return self._jacobian(t, xi)
        finally:
            self.engine_time += time.perf_counter() - tic

    def _jacobian(self, t: float, xi: np.ndarray) -> np.ndarray:
        self.set_point(t, xi)
        self.statistics.jacobians += 1
        return self.jacobian_plan.assemble()

    def indicators(self, t: float, xi: np.ndarray) -> np.ndarray:
        if not self.timed:
            return self._indicators(t, xi)
        tic = time.perf_counter()
        try:
            return self._indicators(t, xi)
        finally:
            self.engine_time += time.perf_counter() - tic

    def _indicators(self, t: float, xi: np.ndarray) -> np.ndarray:
        self.set_point(t, xi)
        for fn, args, unit in self._get_indicators:
            if fn(*args) > 1:
                raise self.failure(unit.inst, "fmi2GetEventIndicators")
        return self._z.copy()

    def states(self) -> np.ndarray:
        x = np.empty(self.n)
        for unit in self.with_states:
            self.call(unit, "fmi2GetContinuousStates", unit.x, unit.n)
            x[unit.offset:unit.offset + unit.n] = unit.x
        return x

    def nominals(self) -> np.ndarray:
        s = np.ones(self.n)
        for unit in self.with_states:
            self.call(unit, "fmi2GetNominalsOfContinuousStates", unit.x, unit.n)
            s[unit.offset:unit.offset + unit.n] = [v if math.isfinite(v) and v > 0 else 1.0 for v in unit.x]
        return s

    def row(self) -> list[float]:
        """The recorded values at the point last set with record=True."""
        return self.values.row()

    # ---- events ----------------------------------------------------------------------------------------
    def event(self, t: float) -> tuple[bool, float | None]:
        """Every FMU through event mode at t (the FMUs already at t's state): (the states changed, the next
        time event or None). An FMU that asks to terminate ends the run."""
        for unit in self.units:
            self.call(unit, "fmi2EnterEventMode")
        changed, next_time = self.discrete_states(t)
        for unit in self.units:
            self.call(unit, "fmi2EnterContinuousTimeMode")
        return changed, next_time

    def event_reason(self) -> SimulationError | None:
        """After an FMU failed at a point where an event indicator changed domain (a controller evaluated
        on the plant's domain boundary): the error of the first FMU with event indicators that refuses
        its event there (fmi2EnterEventMode, fmi2NewDiscreteStates at the states already set), or None.
        Only a diagnosis: the run ends either way, and that FMU's reason names the cause. None if the
        failure was one of theirs (an FMU in its error state refuses every call)."""
        if self.failed is None or any(u.inst is self.failed for u in self.with_indicators):
            return None
        for unit in self.with_indicators:
            try:
                self.call(unit, "fmi2EnterEventMode")
                self.call(unit, "fmi2NewDiscreteStates", ctypes.byref(fmi2EventInfo()))
            except SimulationError as exc:
                return exc
        return None

    def discrete_states(self, t: float) -> tuple[bool, float | None]:
        """fmi2NewDiscreteStates of every FMU until none needs another round (values resolved between)."""
        info = fmi2EventInfo()
        changed, next_time = False, None
        for _ in range(MAX_EVENT_ITERATIONS):
            stopping.check()
            again = False
            next_time = None
            for unit in self.units:
                self.call(unit, "fmi2NewDiscreteStates", ctypes.byref(info))
                if info.terminateSimulation:
                    raise SimulationError(f"{unit.inst.path.name}: component '{unit.inst.name}' asked to terminate "
                                          f"the simulation at t = {t:.9g} s{last_message(unit.inst)}")
                again = again or bool(info.newDiscreteStatesNeeded)
                changed = changed or bool(info.valuesOfContinuousStatesChanged)
                if info.nextEventTimeDefined:
                    next_time = info.nextEventTime if next_time is None else min(next_time, info.nextEventTime)
            self.resolve(t)
            if not again:
                return changed, next_time
        raise SimulationError(f"the event at t = {t:.9g} s did not settle within {MAX_EVENT_ITERATIONS} rounds of "
                              "fmi2NewDiscreteStates")

    def completed_step(self, t: float, xi: np.ndarray) -> bool:
        """fmi2CompletedIntegratorStep of the FMUs that need it: True if one asks for event mode."""
        if not self.timed:
            return self._completed_step(t, xi)
        tic = time.perf_counter()
        try:
            return self._completed_step(t, xi)
        finally:
            self.engine_time += time.perf_counter() - tic

    def _completed_step(self, t: float, xi: np.ndarray) -> bool:
        if not self._completed:
            return False
        self.set_point(t, xi)
        wanted = False
        for fn, args, unit in self._completed:
            if fn(*args) > 1:
                raise self.failure(unit.inst, "fmi2CompletedIntegratorStep")
            if self._terminate.value:
                raise SimulationError(f"{unit.inst.path.name}: component '{unit.inst.name}' asked to terminate "
                                      f"the simulation at t = {t:.9g} s{last_message(unit.inst)}")
            wanted = wanted or bool(self._enter.value)
        return wanted


def state_references(model_description, offset: int = 0) -> dict[int, int]:
    """{value reference: index in x} of an FMU's continuous states, x's part from `offset` on: the Real
    variables that the `derivative` attributes of its <ModelStructure><Derivatives> point at (FMI 2.0,
    section 2.2.8: the order of <Derivatives> is the order of fmi2GetContinuousStates; fmpy resolves the
    attribute to the variable). A variable with such a value reference IS the state (an alias has its
    value), so its value at a point is the state set there; any other variable, even one whose equation
    copies a state, is read by fmi2GetReal."""
    return {d.variable.derivative.valueReference: offset + j for j, d in enumerate(model_description.derivatives)
            if d.variable.derivative is not None}


def needs_completed_step(model_description) -> bool:
    """Whether the FMU asks for fmi2CompletedIntegratorStep after every step (completedIntegratorStepNotNeeded
    false or absent). Works around fmpy (0.3.32): for FMI 2.0 its read_model_description stores that attribute
    inverted as ModelExchange.needsCompletedIntegratorStep and leaves completedIntegratorStepNotNeeded at its
    default, false, whatever the XML says (checked on build/ and build/native's FMUs, which declare "true":
    fmpy gave completedIntegratorStepNotNeeded False for all 14). Reading only that field, the engine made
    every FMU's call after every step: three calls a step for the paper's loops, none of them needed."""
    me = model_description.modelExchange
    if hasattr(me, "needsCompletedIntegratorStep"):
        return bool(me.needsCompletedIntegratorStep)
    return not me.completedIntegratorStepNotNeeded


class _Transfers:
    """The connected values of any plan, resolved by its transfers (plan.resolve_values) into a list."""

    def __init__(self, system: System):
        self.system, self.plan = system, system.plan
        self.slots: list = [0.0] * n_slots(system.plan)

    def resolve(self, t: float, record: bool, connected: bool = True) -> bool:
        """As _Buffers.resolve; every connected value is set."""
        try:
            if connected:
                resolve_values(self.plan, self.slots, record)
            elif record:
                resolve_values(Plan([], self.plan.record, [], []), self.slots, True)
        except FMICallException as exc:
            raise self.system.failure(exc.transfer.inst, exc.function) from None
        except NonFinite as exc:
            raise SimulationError(exc.message(t)) from None
        return True

    def row(self) -> list[float]:
        slots = self.slots
        return [slots[s] for s in self.plan.column_slots]


class _Buffers:
    """The connected values of a plan of Real transfers (the Model Exchange case: no derivative orders),
    resolved through one numpy buffer of the plan's slots: each get writes its values into the buffer (its
    slots are consecutive), and each set of values connected one to one reads them from there, by address;
    a set through linear transformations (or from slots that are not consecutive) gathers its values first.
    The same checks as the transfers': a value got or to be set that is not finite is an error naming it
    (a set of values got and checked in the same resolution is not checked again). Plan.resolve_values does
    the same through Python lists and Transfer objects: 10-20 us per evaluation where this costs 3-5.

    A row (record=True) makes only the calls its recorded values need: a get whose values are recorded or
    set on an FMU that is read after it, a set on an FMU read after it (for the paper's loops: all but the
    plant's input u, one call of nine)."""

    def __init__(self, system: System):
        self.system, plan = system, system.plan
        self.slots = np.zeros(max(1, n_slots(plan)))
        self.columns = np.array(plan.column_slots, dtype=np.intp)
        shown = set(plan.column_slots)
        self.units = {u.inst.name: u for u in system.units}
        self._states: dict[int, tuple[list[int], list[int]]] = {}    # id of a state step: (its slots, x's indices)
        groups: list[tuple] = []     # (transfer, slots it writes, slots it reads, its steps, it calls its FMU)
        for gets, sets in plan.stages:
            for t, _ in gets:
                states = self._from_states(t)
                groups.append((t, t.slots, [], states or self._get(t), not states))
            groups += [(t, t.slots, [s for s, _, _ in sources], self._set(t, sources, shown), True)
                       for t, sources in sets]
        self.connected = [step for *_, steps, _ in groups for step in steps]
        record = [(t, self._from_states(t)) for t, _ in plan.record]
        self.recorded = [step for t, states in record for step in states or self._get(t)]
        # the steps a row needs, found backwards from the recorded slots, and the FMUs they call
        needed, read = set(plan.column_slots), {t.inst.name for t, states in record if not states}
        kept = []
        self.row_units = set(read)
        for transfer, writes, reads, steps, calls in reversed(groups):
            if transfer.getter and needed.intersection(writes) or not transfer.getter and (
                    transfer.inst.name in read or needed.intersection(writes)):
                kept.append(steps)
                needed.update(reads)
                if calls:
                    self.row_units.add(transfer.inst.name)
                    if transfer.getter:
                        read.add(transfer.inst.name)
        self.row_steps = [step for steps in reversed(kept) for step in steps]
        self.complete_rows = len(self.row_steps) == len(self.connected)
        self.row_sequence = self.row_steps + self.recorded
        # a row's state outputs at once (System.rows): where their slots are consecutive, one copy per row from
        # the unscaled states into them, and the row's other steps
        copies = [self._states[id(step)] for step in self.row_sequence if id(step) in self._states]
        dst = [k for slots_, _ in copies for k in slots_]
        index = [i for _, indices in copies for i in indices]
        self.row_states: tuple[slice, Any] | None = None
        if dst and dst == list(range(dst[0], dst[0] + len(dst))):
            self.row_states = (slice(dst[0], dst[0] + len(dst)), _slice_if_consecutive(index))
        self.row_calls = [step for step in self.row_sequence if id(step) not in self._states]

    def _from_states(self, transfer: Transfer) -> list[tuple]:
        """The steps of a get whose every variable is a continuous state of its FMU (state_references): its
        values are the point's states (the system's _x, the very doubles fmi2SetContinuousStates gets), copied
        into the buffer without calling the FMU; [] for any other transfer (read by its call)."""
        states = self.units[transfer.inst.name].states
        vrs = list(transfer.vr)
        if not (transfer.getter and transfer.function == "fmi2GetReal" and all(vr in states for vr in vrs)):
            return []
        x, slots, n = self.system._x, self.slots, transfer.n
        index, first = [states[vr] for vr in vrs], transfer.slots[0]
        if index == list(range(index[0], index[0] + n)) and transfer.slots == list(range(first, first + n)):
            dst, src = slots[first:first + n], x[index[0]:index[0] + n]

            def copy() -> int:
                dst[:] = src
                return 0
            step: tuple = (copy, (), slots.data[first:first + n], transfer)
        else:
            own, source, target = (np.ctypeslib.as_array(transfer.values), np.array(index, dtype=np.intp),
                                   np.array(transfer.slots, dtype=np.intp))

            def gather() -> int:
                own[:] = x[source]
                slots[target] = own
                return 0
            step = (gather, (), transfer.view, transfer)
        self._states[id(step)] = (list(transfer.slots), index)
        return [step]

    def _address(self, slot: int) -> ctypes.c_void_p:
        return ctypes.c_void_p(self.slots.ctypes.data + 8 * slot)

    def _call(self, transfer: Transfer, values, check) -> tuple:
        """The step (function, arguments, values to check after it or None, transfer) of transfer's call."""
        return (self.system.bare(transfer.inst, transfer.function),
                (ctypes.c_void_p(transfer.inst.component), transfer.vr, ctypes.c_size_t(transfer.n), values),
                check, transfer)

    def _get(self, transfer: Transfer) -> list[tuple]:
        """The steps of a get: its call into the buffer, or into its own array and then to the buffer."""
        first = transfer.slots[0]
        if transfer.slots == list(range(first, first + transfer.n)):
            return [self._call(transfer, self._address(first), self.slots.data[first:first + transfer.n])]
        own = np.ctypeslib.as_array(transfer.values)
        return [self._call(transfer, transfer.values, transfer.view),
                (_step(np.put, self.slots, transfer.slots, own), (), None, transfer)]

    def _set(self, transfer: Transfer, sources: list, shown: set) -> list[tuple]:
        """The steps of a set: its call on the buffer (and the values copied to the input's slots if they are
        recorded), or the values gathered and transformed into its own array, checked, and its call."""
        slots = self.slots
        src = [s for s, _, _ in sources]
        changed = [i for i, (_, factor, offset) in enumerate(sources) if factor != 1.0 or offset != 0.0]
        first = src[0]
        if not changed and src == list(range(first, first + transfer.n)):
            copy = ([(_step(np.put, slots, transfer.slots, slots[first:first + transfer.n]), (), None, transfer)]
                    if shown.intersection(transfer.slots) else [])
            return copy + [self._call(transfer, self._address(first), None)]
        own = np.ctypeslib.as_array(transfer.values)
        index, dst = np.array(src, dtype=np.intp), np.array(transfer.slots, dtype=np.intp)
        factor = np.array([sources[i][1] for i in changed])
        offset = np.array([sources[i][2] for i in changed])

        def gather() -> int:
            np.take(slots, index, out=own)
            if changed:
                own[changed] = factor * own[changed] + offset
            slots[dst] = own
            return 0
        return [(gather, (), transfer.view if changed else None, transfer), self._call(transfer, transfer.values, None)]

    def resolve(self, t: float, record: bool, connected: bool = True) -> bool:
        """The values at the current point (record: the recorded ones too; not connected: only those).
        Returns whether every connected value was set (a row's resolution may leave some out)."""
        steps = (self.row_sequence if record else self.connected) if connected else self.recorded if record else []
        for fn, args, check, transfer in steps:
            if fn(*args) > 1:
                raise self.system.failure(transfer.inst, transfer.function)
            if check is not None and not math.isfinite(sum(check)):
                self.not_finite(transfer, check, t)
        return not record or self.complete_rows

    @staticmethod
    def not_finite(transfer: Transfer, values, t: float) -> None:
        """A value of `values` (transfer's, in its order) is not finite, or their sum overflowed."""
        for i, v in enumerate(values):
            if not math.isfinite(v):
                raise SimulationError(NonFinite(transfer, i, v).message(t))

    def row(self) -> list[float]:
        return self.slots[self.columns].tolist()


def _step(function: Callable, *args) -> Callable[[], int]:
    """function(*args) as a step of _Buffers: returns 0 (fmi2OK) for the status check."""
    def step() -> int:
        function(*args)
        return 0
    return step


class _JacobianPlan:
    """dF/dx by the chain rule over the connections, from every FMU's directional derivatives (module
    docstring). Built once: for each FMU with unknowns (state derivatives and connected outputs) and knowns
    (states and connected inputs), one fmi2GetDirectionalDerivative per known that can depend on x (an input
    fed by an FMU whose outputs cannot is left out: its column would be multiplied by zero), each writing its
    column of the FMU's block straight into G = [[A, B], [C, D]]: rows the derivatives of all states (in x's
    order) and the connected outputs, columns the states and the connected inputs. With M the connections
    (du = M dy, the factors), the outputs' gradients Y = C + D M Y (in dependency order: Y = (I - D M)^-1 C,
    reached by as many substitutions as the plan has levels) and dF/dx = A + B M Y."""

    def __init__(self, system: System):
        self.system = system
        starts = {c.start for c in system.connections}
        ends = {c.end for c in system.connections}
        n = system.n
        blocks = []                      # (unit, unknown variables, derivatives, outputs, states, inputs)
        # the FMUs with states first: with one such FMU, G's rows of derivatives and of outputs are two slices
        for unit in sorted(system.units, key=lambda u: u.n == 0):
            inst = unit.inst
            md = inst.model_description
            derivatives = [d.variable for d in md.derivatives]
            states = [d.variable.derivative for d in md.derivatives]
            outputs = [v for v in md.modelVariables if f"{inst.name}.{v.name}" in starts]
            inputs = [v for v in md.modelVariables if f"{inst.name}.{v.name}" in ends]
            if derivatives + outputs and states + inputs:
                blocks.append((unit, derivatives, outputs, states, inputs))
        out_names = [f"{u.inst.name}.{v.name}" for u, _, outputs, _, _ in blocks for v in outputs]
        source = {c.end: c for c in system.connections}
        in_names = [f"{u.inst.name}.{v.name}" for u, _, _, _, inputs in blocks for v in inputs
                    if source[f"{u.inst.name}.{v.name}"].start in out_names]
        self.M = np.zeros((len(in_names), len(out_names)))
        for i, name in enumerate(in_names):
            self.M[i, out_names.index(source[name].start)] = source[name].factor
        rows = sum(len(d) + len(o) for _, d, o, _, _ in blocks)
        self.G = np.zeros((rows, n + len(in_names)), order="F")
        self.calls = []
        der_rows, out_rows = [0] * n, []  # type: list[int], list[int]
        row, itemsize, base = 0, self.G.itemsize, self.G.ctypes.data
        seed = (ctypes.c_double * 1)(1.0)
        for unit, derivatives, outputs, states, inputs in blocks:
            inst = unit.inst
            unknowns = derivatives + outputs
            vu = (ctypes.c_uint * len(unknowns))(*[v.valueReference for v in unknowns])
            fn = system.bare(inst, "fmi2GetDirectionalDerivative")
            known = [(v, unit.offset + i) for i, v in enumerate(states)]
            known += [(v, n + in_names.index(f"{inst.name}.{v.name}")) for v in inputs
                      if f"{inst.name}.{v.name}" in in_names]
            for v, column in known:
                target = ctypes.c_void_p(base + itemsize * (column * self.G.shape[0] + row))
                self.calls.append((fn, (ctypes.c_void_p(inst.component), vu, ctypes.c_size_t(len(unknowns)),
                                        (ctypes.c_uint * 1)(v.valueReference), ctypes.c_size_t(1), seed, target), inst))
            for i in range(len(derivatives)):
                der_rows[unit.offset + i] = row + i
            out_rows += range(row + len(derivatives), row + len(unknowns))
            row += len(unknowns)
        self.der_rows, self.out_rows = _slice_if_consecutive(der_rows), _slice_if_consecutive(out_rows)
        self.has_outputs = bool(out_rows) and self.M.size > 0
        self.substitutions = max(system.plan.level.values(), default=0)
        self.n = n
        self._scale: np.ndarray | None = None
        self._ratio = np.ones((n, n))

    def assemble(self) -> np.ndarray:
        """dF/dxi in scaled states (J_ij s_j / s_i) at the point the FMUs are at."""
        for fn, args, inst in self.calls:
            if fn(*args) > 1:
                raise self.system.failure(inst, "fmi2GetDirectionalDerivative")
        n = self.n
        top = self.G[self.der_rows]
        J = top[:, :n]
        if self.has_outputs:
            bottom = self.G[self.out_rows]
            C, DM = bottom[:, :n], bottom[:, n:] @ self.M
            Y = C
            for _ in range(self.substitutions):
                Y = C + DM @ Y
            J = J + top[:, n:] @ (self.M @ Y)
        scale = self.system.scale
        if scale is not self._scale:
            self._scale, self._ratio = scale, scale[None, :] / scale[:, None]
        return J * self._ratio


def _slice_if_consecutive(index: list[int]) -> slice | np.ndarray:
    """index as a slice where it is consecutive (numpy then takes a view, not a copy)."""
    if index == list(range(index[0] if index else 0, (index[0] if index else 0) + len(index))):
        return slice(index[0] if index else 0, (index[0] if index else 0) + len(index))
    return np.array(index, dtype=np.intp)


def transfers(plan: Plan) -> list:
    """Every transfer of a plan (their `elapsed` is time inside the FMUs)."""
    return [t for gets, sets in plan.stages for t, _ in gets + sets] + [t for t, _ in plan.record]
