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
"""
from __future__ import annotations

import ctypes
import math
import time
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from . import stopping
from .errors import SimulationError
from .fmi import STATUS, FMICallException, fmi2EventInfo
from .instances import Instance, last_message
from .plan import Plan, n_slots, resolve_values
from .ssd import Scenario
from .transfer import NonFinite

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


class System:
    """The FMUs of a scenario as one ODE x' = F(t, x) (module docstring), x scaled by the nominals."""

    def __init__(self, scenario: Scenario, instances: dict[str, Instance], connections, plan: Plan):
        self.scenario, self.instances, self.connections, self.plan = scenario, instances, connections, plan
        self.slots = [0.0] * n_slots(plan)
        self.units: list[_Unit] = []
        offset = 0
        for inst in instances.values():
            md = inst.model_description
            unit = _Unit(inst, offset, len(md.derivatives), int(md.numberOfEventIndicators or 0))
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
        self.step_reporters = [u for u in self.units
                               if not u.inst.model_description.modelExchange.completedIntegratorStepNotNeeded]
        self.scale = np.ones(self.n)
        fed = {c.end_element for c in connections}
        knowing = [u for u in self.units if u.n > 0 or u.inst.name in fed]     # FMUs whose unknowns depend on x
        self.jacobian_plan = _JacobianPlan(self) if all(
            u.inst.model_description.modelExchange.providesDirectionalDerivative for u in knowing) else None
        self.statistics: Statistics | None = None
        self.fmu_time = 0.0                          # inside the FMUs' raw calls (the transfers time theirs)
        self.engine_time = 0.0                       # inside this object's methods the solver and the run call
        self.time: float | None = None               # the time the FMUs were last set to (fmi2SetTime)
        self.discarded = ""                          # the last fmi2Discard of fmi2GetDerivatives
        self.failed: Instance | None = None          # the instance whose call failed last

    # ---- FMI calls ----------------------------------------------------------------------------------
    def call(self, unit: _Unit, function: str, *args) -> int:
        tic = time.perf_counter()
        status = unit.calls[function](unit.inst.component, *args)
        self.fmu_time += time.perf_counter() - tic
        if status > 2 or (status == 2 and function != "fmi2GetDerivatives"):
            self.failed = unit.inst
            raise SimulationError(f"{unit.inst.path.name}: component '{unit.inst.name}' failed in {function} "
                                  f"(status {STATUS[status] if status < 6 else status}) at t = "
                                  f"{self.time if self.time is not None else float('nan'):.9g} s{last_message(unit.inst)}")
        return status

    def set_point(self, t: float, xi: np.ndarray, record: bool = False) -> None:
        """The FMUs at time t and scaled state xi, their connected values resolved (and the recorded ones).
        A stop asked for by a signal ends the run here (module docstring)."""
        stopping.check()
        if t != self.time:
            self.time = t
            for unit in self.units:
                self.call(unit, "fmi2SetTime", ctypes.c_double(t))
        x = xi * self.scale
        for unit in self.with_states:
            buf = unit.x
            for i in range(unit.n):
                buf[i] = x[unit.offset + i]
            self.call(unit, "fmi2SetContinuousStates", buf, unit.n)
        self.resolve(t, record)

    def resolve(self, t: float, record: bool = False) -> None:
        """The connected values at the current point (plan.resolve_values; its transfers time their calls)."""
        try:
            resolve_values(self.plan, self.slots, record)
        except FMICallException as exc:
            inst = self.failed = exc.transfer.inst
            raise SimulationError(f"{inst.path.name}: component '{inst.name}' failed in {exc.function} at "
                                  f"t = {t:.9g} s{last_message(inst)}") from None
        except NonFinite as exc:
            raise SimulationError(exc.message(t)) from None

    # ---- the ODE -------------------------------------------------------------------------------------
    def rhs(self, t: float, xi: np.ndarray) -> np.ndarray:
        """F(t, x) in scaled states: NaN where an FMU discards the evaluation (fmi2Discard: the solver then
        takes a smaller step)."""
        tic = time.perf_counter()
        try:
            return self._rhs(t, xi)
        finally:
            self.engine_time += time.perf_counter() - tic

    def _rhs(self, t: float, xi: np.ndarray) -> np.ndarray:
        self.set_point(t, xi)
        out = np.empty(self.n)
        for unit in self.with_states:
            if self.call(unit, "fmi2GetDerivatives", unit.dx, unit.n) == 2:
                self.discarded = last_message(unit.inst)
                out[:] = math.nan
                return out
            out[unit.offset:unit.offset + unit.n] = unit.dx
        self.statistics.rhs += 1
        return out / self.scale

    def jacobian(self, t: float, xi: np.ndarray) -> np.ndarray:
        tic = time.perf_counter()
        try:
            return self._jacobian(t, xi)
        finally:
            self.engine_time += time.perf_counter() - tic

    def _jacobian(self, t: float, xi: np.ndarray) -> np.ndarray:
        self.set_point(t, xi)
        self.statistics.jacobians += 1
        tic = time.perf_counter()
        J = self.jacobian_plan.assemble()
        self.fmu_time += time.perf_counter() - tic
        return J * self.scale[None, :] / self.scale[:, None]

    def indicators(self, t: float, xi: np.ndarray) -> np.ndarray:
        tic = time.perf_counter()
        try:
            return self._indicators(t, xi)
        finally:
            self.engine_time += time.perf_counter() - tic

    def _indicators(self, t: float, xi: np.ndarray) -> np.ndarray:
        self.set_point(t, xi)
        out: list[float] = []
        for unit in self.with_indicators:
            self.call(unit, "fmi2GetEventIndicators", unit.z, unit.nz)
            out.extend(unit.z)
        return np.array(out)

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
        slots = self.slots
        return [slots[s] for s in self.plan.column_slots]

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
        tic = time.perf_counter()
        try:
            return self._completed_step(t, xi)
        finally:
            self.engine_time += time.perf_counter() - tic

    def _completed_step(self, t: float, xi: np.ndarray) -> bool:
        if not self.step_reporters:
            return False
        self.set_point(t, xi)
        enter, terminate = ctypes.c_int(0), ctypes.c_int(0)
        wanted = False
        for unit in self.step_reporters:
            self.call(unit, "fmi2CompletedIntegratorStep", 1, ctypes.byref(enter), ctypes.byref(terminate))
            if terminate.value:
                raise SimulationError(f"{unit.inst.path.name}: component '{unit.inst.name}' asked to terminate "
                                      f"the simulation at t = {t:.9g} s{last_message(unit.inst)}")
            wanted = wanted or bool(enter.value)
        return wanted


class _JacobianPlan:
    """dF/dx by the chain rule over the connections, from every FMU's directional derivatives (module
    docstring). Built once: for each FMU the value references of its unknowns (state derivatives and
    connected outputs) and knowns (states and connected inputs)."""

    def __init__(self, system: System):
        self.system = system
        starts = {c.start for c in system.connections}
        ends = {c.end: c for c in system.connections}
        self.blocks = []
        for unit in system.units:
            inst = unit.inst
            md = inst.model_description
            derivatives = [d.variable for d in md.derivatives]
            states = [d.variable.derivative for d in md.derivatives]
            outputs = [v for v in md.modelVariables if f"{inst.name}.{v.name}" in starts]
            inputs = [v for v in md.modelVariables if f"{inst.name}.{v.name}" in ends]
            unknowns = derivatives + outputs
            knowns = states + inputs
            if not unknowns or not knowns:
                continue
            vu = (ctypes.c_uint * len(unknowns))(*[v.valueReference for v in unknowns])
            columns = []
            for k in knowns:
                columns.append(((ctypes.c_uint * 1)(k.valueReference), (ctypes.c_double * 1)(1.0)))
            self.blocks.append((unit, [f"{inst.name}.{v.name}" for v in outputs], len(derivatives), vu,
                                (ctypes.c_double * len(unknowns))(), columns, len(states),
                                [f"{inst.name}.{v.name}" for v in inputs], inst.raw("fmi2GetDirectionalDerivative")))
        self.level = system.plan.level
        self.feeds: dict[str, list] = {}                 # output -> [(input, factor)]
        for c in system.connections:
            self.feeds.setdefault(c.start, []).append((c.end, c.factor))

    def assemble(self) -> np.ndarray:
        n = self.system.n
        local = {}
        for unit, outputs, nd, vu, out, columns, ns, inputs, call in self.blocks:
            L = np.empty((len(vu), len(columns)))
            for j, (vk, seed) in enumerate(columns):
                status = call(unit.inst.component, vu, len(vu), vk, 1, seed, out)
                if status > 1:
                    raise SimulationError(f"{unit.inst.path.name}: component '{unit.inst.name}' failed in "
                                          f"fmi2GetDirectionalDerivative{last_message(unit.inst)}")
                L[:, j] = out
            local[unit.inst.name] = (unit, outputs, nd, L, ns, inputs)
        d_input: dict[str, np.ndarray] = {}
        d_output: dict[str, np.ndarray] = {}

        def row(unit, L_row, ns, inputs) -> np.ndarray:
            r = np.zeros(n)
            r[unit.offset:unit.offset + ns] = L_row[:ns]
            for value, name in zip(L_row[ns:], inputs):
                if value != 0.0 and name in d_input:
                    r += value * d_input[name]
            return r

        names = {o: name for name, (_, outputs, _, _, _, _) in local.items() for o in outputs}
        for output in sorted(names, key=lambda o: self.level.get(o, 0)):
            unit, outputs, nd, L, ns, inputs = local[names[output]]
            r = row(unit, L[nd + outputs.index(output)], ns, inputs)
            d_output[output] = r
            for end, factor in self.feeds.get(output, ()):
                d_input[end] = factor * r
        J = np.zeros((n, n))
        for unit, outputs, nd, L, ns, inputs in local.values():
            for i in range(nd):
                J[unit.offset + i] = row(unit, L[i], ns, inputs)
        return J


def transfers(plan: Plan) -> list:
    """Every transfer of a plan (their `elapsed` is time inside the FMUs)."""
    return [t for gets, sets in plan.stages for t, _ in gets + sets] + [t for t, _ in plan.record]
