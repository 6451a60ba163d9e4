"""The co-simulation master: runs an SSP scenario of FMI 2.0 co-simulation FMUs with fmpy.

At each communication point t_n the master

1. resolves outputs in the order of the dependency graph (`dependencies.levels`): it gets the
   outputs of level 0 (states, sources), sets the inputs they feed, gets the outputs of level 1
   (direct feedthrough of those inputs), and so on; a static controller thus acts on the plant
   state of the same instant, with no extra delay (Gauss-Seidel within the instant);
2. where both ends of a connection declare it, resolves the output derivatives in the same order
   and hands them to the inputs (coupling.py: the target then follows a polynomial over the step
   instead of holding the value); FMUs that declare none hold their inputs (zero-order hold);
3. records the chosen variables at t_n;
4. steps every FMU from t_n to t_{n+1}.

Initialization: parameter values are set after instantiation, then in initialization mode the
outputs are propagated to the inputs in the same order, and initialization mode is left.

Communication points: fixed, t_n = t0 + n h; or, with a tolerance, chosen by stepcontrol.py so that
the recorded variables keep that relative error over the run (FMU-state rollback, a shadow copy of
the FMUs for the global error estimate).

Every Real value the master gets from an FMU or sets on one is checked: a NaN or infinity ends the
run with a SimulationError naming the variable and the time (an FMU may return one with fmi2OK).

The master knows nothing of the models: any FMI 2.0 co-simulation FMU and any SSP scenario runs.
"""
from __future__ import annotations

import ctypes
import dataclasses
import math
import shutil
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Callable, Sequence

from fmpy import read_model_description
from fmpy.fmi1 import FMICallException
from fmpy.fmi2 import (FMU2Slave, fmi2CallbackAllocateMemoryTYPE, fmi2CallbackFreeMemoryTYPE,
                       fmi2CallbackFunctions, fmi2CallbackLoggerTYPE)
from fmpy import calloc, free

from . import coupling, dependencies, stepcontrol, tempdirs, units
from . import implicit as implicit_                 # `implicit` is the run's flag
from .errors import ScenarioError, SimulationError
from .fmustate import States
from .results import Result, ResultFile
from .ssd import Scenario, extract_archive, parse_value

C_TYPES = {"Real": ctypes.c_double, "Integer": ctypes.c_int, "Boolean": ctypes.c_int}
STATUS = ["ok", "warning", "discard", "error", "fatal", "pending"]
INT_MIN, INT_MAX = -2**31, 2**31 - 1     # fmi2Integer is a 32-bit int
INTERNAL_TOLERANCE = 0.01               # error-controlled runs: the FMUs' integrators get this times the tolerance
MAX_STEPS = 10**8                        # more communication steps must be confirmed (max_steps, --max-steps)


@dataclass
class Instance:
    """One FMU instance of the scenario."""

    name: str
    path: Path
    model_description: object
    variables: dict                                  # name -> fmpy ModelVariable
    slave: FMU2Slave | None = None
    messages: list[str] = field(default_factory=list)
    callbacks: object = None

    def variable(self, name: str, scenario: Scenario):
        try:
            return self.variables[name]
        except KeyError:
            raise ScenarioError(f"{scenario.path}: unknown variable '{self.name}.{name}' "
                                f"(not in {self.path.name})") from None


class _Transfer:
    """Get a batch of values of one type from one FMU (raw fmi2Get*, preallocated arrays)."""

    def __init__(self, inst: Instance, names: list[str], type_: str, getter: bool):
        self.inst, self.names, self.type = inst, names, type_
        vrs = [inst.variables[n].valueReference for n in names]
        self.vr = (ctypes.c_uint * len(vrs))(*vrs)
        self.values = (C_TYPES[type_] * len(vrs))()
        prefix = "fmi2Get" if getter else "fmi2Set"
        self.function = f"{prefix}{type_}"
        self.call = inst.slave._functions[self.function]     # the raw ctypes function
        self.n = len(vrs)
        self.args = (inst.slave.component, self.vr, self.n, self.values)   # plans are rebuilt with the instances
        self.elapsed = 0.0                                     # wall time inside the FMU
        self.getter = getter
        self.real = type_ == "Real"
        # the values as plain doubles: summing this view is about 5x cheaper than summing the ctypes
        # array (whose items are boxed one by one), measured in benchmarks/bench_integrity.py
        self.view = memoryview(self.values).cast("B").cast("d") if self.real else None

    def __call__(self) -> None:
        if self.real and not self.getter:
            self._check_finite()
        tic = time.perf_counter()
        status = self.call(*self.args)
        self.elapsed += time.perf_counter() - tic
        if status > 1:
            raise FMICallException(self.function, status)
        if self.real and self.getter:
            self._check_finite()

    def _check_finite(self) -> None:
        if math.isfinite(sum(self.view)):                     # a NaN or inf anywhere makes the sum one
            return
        for name, v in zip(self.names, self.values):
            if not math.isfinite(v):
                raise NonFiniteValue(self, name, v)


class NonFiniteValue(Exception):
    """A NaN or infinity got from (or about to be set on) an FMU variable."""

    def __init__(self, transfer: _Transfer, name: str, value: float):
        super().__init__(name)
        self.transfer, self.name, self.value = transfer, name, value

    def message(self, t: float) -> str:
        inst = self.transfer.inst
        if self.transfer.getter:
            return (f"{inst.name}.{self.name} = {self.value} at t = {t:.9g} s: {inst.path.name} (component "
                    f"'{inst.name}') returned a value that is not finite{_last_message(inst)}")
        return (f"{inst.name}.{self.name} = {self.value} at t = {t:.9g} s: the value to set on this input "
                f"(after the connection's transformation) is not finite")


class _Mirror:
    """A get of the shadow copy (stepcontrol.py) from a source it shares with the main copy: the
    values the main copy read at the same communication point, copied instead of asked again."""

    def __init__(self, transfer, source: list, source_slots: list[int]):
        self.inst, self.slots, self.function = transfer.inst, transfer.slots, transfer.function
        self.values = [0.0] * len(source_slots)
        self.source, self.source_slots = source, source_slots
        self.elapsed = 0.0

    def __call__(self) -> None:
        values, source = self.values, self.source
        for i, s in enumerate(self.source_slots):
            values[i] = source[s]


@dataclass
class Plan:
    """What the master does at a communication point, precomputed."""

    stages: list                     # [(gets, sets)] per level; see `_plan`
    record: list                     # extra gets for recorded variables that are not connected outputs
    columns: list[str]               # recorded full names
    column_slots: list[int]          # slot of each column in the value buffer
    level: dict = field(default_factory=dict)      # connected output -> dependency level
    depends: dict = field(default_factory=dict)    # full output name -> full inputs it depends on
    input_slots: list = field(default_factory=list)  # [(connected input full name, value slot)]
    dynamic: set = field(default_factory=set)      # components with an output not fed through from an input
    slot: dict = field(default_factory=dict)       # full name -> slot in the value buffer


def simulate(scenario: Scenario, stop_time: float | None = None, step_size: float | None = None,
             start_values: dict[str, str | float] | None = None, record: Sequence[str] | None = None,
             progress: Callable[[float], None] | None = None, tolerance: float | None = None,
             timing: dict | None = None, coupling_order: int | None = None,
             max_step: float | None = None, sink: ResultFile | None = None,
             max_steps: float = MAX_STEPS, implicit: bool | None = None) -> Result:
    """Run `scenario` once and return the recorded values at every communication point.

    start_values: "component.variable" -> value (text or number), overriding the .ssv values.
    record: full variable names to record; default: every connector of the scenario.
    progress: called with the fraction done (0..1) now and then.
    tolerance: if given, the communication steps are chosen so that the recorded variables keep
        this relative error over the run (stepcontrol.py); step_size is then the first step and
        max_step (default: a fiftieth of the run) the largest. `result.step_control` reports the
        steps taken and rejected and the estimated error.
    coupling_order: derivatives passed on the connections (coupling.py): None (default) for as
        many as both ends of a connection declare (up to coupling.MAX_ORDER), 0 for a zero-order
        hold everywhere, k to use at most k.
    implicit: iterate every communication step until the inputs of the FMUs with states agree with
        their sources at its end (implicit.py: stable on stiff loops at any step, third order;
        `result.implicit` gives the trial steps); takes no coupling_order (it sets the inputs' polynomials
        itself: Hermite parabolas, chords where a source gives no derivatives).
        None (default): the scenario's choice (its emcosim:Coupling annotation), explicit if it makes
        none or if a coupling_order is given.
    timing: if a dict is given, the master fills in the wall time of the run ('total', from
        initialization to the end), the part spent inside FMU calls ('fmu'), the number of
        communication steps ('steps') and FMUs ('fmus'), the time inside each FMU ('per_fmu',
        by component name), and 'overhead_per_fmu_step' =
        (total - fmu) / (steps * fmus): the master's own cost.
    sink: a `results.ResultFile`: every row is written to it as it is produced and the returned
        Result keeps only the last row in memory (without a sink, every row stays in memory).
    max_steps: refuse a run of more communication steps than this (a typing error such as a step
        of 1e-15 s would otherwise run for years); raise it to confirm a long run.
    Raises ScenarioError for a scenario that cannot run, SimulationError (with `.result`, the
    values recorded so far) for an FMU that fails during the run (or a value that is not finite),
    `errors.Interrupted` when stopped by a signal (see `stopping`).
    """
    experiment(scenario, stop_time, step_size, max_steps)       # refuse a bad horizon before loading
    with Simulation(scenario) as simulation:
        return simulation.run(stop_time=stop_time, step_size=step_size, start_values=start_values,
                              record=record, progress=progress, tolerance=tolerance, timing=timing,
                              coupling_order=coupling_order, max_step=max_step, sink=sink, max_steps=max_steps,
                              implicit=implicit)


def experiment(scenario: Scenario, stop_time: float | None, step_size: float | None,
               max_steps: float = MAX_STEPS) -> tuple[float, float, float]:
    """(start time, stop time, step size) of a run: the scenario's, overridden by the arguments;
    a ScenarioError if they do not make a run (or make more than max_steps communication steps)."""
    t0 = scenario.start_time
    t_stop = scenario.stop_time if stop_time is None else stop_time
    h = scenario.step_size if step_size is None else step_size
    if t_stop is None or h is None:
        raise ScenarioError(f"{scenario.path}: no stop time / step size (give --stop-time and --step-size)")
    if not (math.isfinite(t_stop) and t_stop > t0):
        raise ScenarioError(f"{scenario.path}: stop time {t_stop} must be after the start time {t0}")
    if not (math.isfinite(h) and h > 0):
        raise ScenarioError(f"{scenario.path}: step size {h} must be positive")
    steps = (t_stop - t0) / h
    if not math.isfinite(steps):
        raise ScenarioError(f"{scenario.path}: stop time {t_stop:g} s with step size {h:g} s: too many "
                            "communication steps to count")
    if h < 4 * math.ulp(max(abs(t0), abs(t_stop))):
        raise ScenarioError(f"{scenario.path}: step size {h:g} s is below the resolution of time near "
                            f"t = {max(abs(t0), abs(t_stop)):g} s (double precision: {math.ulp(max(abs(t0), abs(t_stop))):.3g} s)")
    if steps > max_steps:
        raise ScenarioError(f"{scenario.path}: stop time {t_stop:g} s with step size {h:g} s makes {steps:.3g} "
                            f"communication steps, more than the limit of {max_steps:.3g}; give --max-steps "
                            f"{math.ceil(steps)} (max_steps) to run it anyway")
    return t0, t_stop, h


class Simulation:
    """One scenario's FMUs, unpacked and instantiated once; `run` as often as needed.

    Between runs every FMU is reset with fmi2Reset (it returns to its freshly instantiated state);
    if an FMU refuses the reset (e.g. after a fatal error), all are freed and instantiated again.
    `call` runs the instantiation (default: directly); a caller whose FMUs must be instantiated on a
    particular thread passes a function that does that (see `session.on_main_thread`).
    Not thread-safe: one Simulation per thread.
    """

    def __init__(self, scenario: Scenario, call: Callable[[Callable[[], None]], None] | None = None):
        self.scenario = scenario
        self.runs = 0                         # runs made with the current instances
        self.instantiations = 0               # how often the FMUs were instantiated (1 unless a reset failed)
        self._call = call or (lambda fn: fn())
        self._workdirs: list[str] = []
        self._plans: dict = {}
        self._shadow: dict[str, Instance] | None = None     # the copy for error estimation (stepcontrol)
        self._shadow_own: list[str] = []                     # its own instances (the others are shared)
        self._shadow_used = False
        self._accepted: dict[str, int] = {}                  # input derivative orders found accepted
        self.instances = load(scenario)
        self.connections = check_connections(scenario, self.instances)
        try:
            self._instantiate()
        except BaseException:
            self.close()
            raise

    def _instantiate(self) -> None:
        def instantiate_all() -> None:
            for inst in self.instances.values():
                _instantiate(inst, self._workdirs)
        self._call(instantiate_all)
        self.instantiations += 1
        self._plans.clear()                   # plans hold the instances' C handles
        self._free_shadow()
        self.runs = 0

    def _reset(self) -> None:
        try:
            for inst in self.instances.values():
                inst.slave.reset()
                inst.messages.clear()
        except Exception:                     # noqa: BLE001 - any failure: start from scratch
            for inst in self.instances.values():
                _free(inst)
                inst.messages.clear()
            self._instantiate()

    def run(self, stop_time: float | None = None, step_size: float | None = None,
            start_values: dict[str, str | float] | None = None, record: Sequence[str] | None = None,
            progress: Callable[[float], None] | None = None, tolerance: float | None = None,
            timing: dict | None = None, coupling_order: int | None = None,
            max_step: float | None = None, sink: ResultFile | None = None,
            max_steps: float = MAX_STEPS, implicit: bool | None = None) -> Result:
        """Run the scenario once; the arguments and errors are those of `simulate`."""
        t0, t_stop, h = experiment(self.scenario, stop_time, step_size, max_steps)
        if implicit is None:
            implicit = self.scenario.coupling == "implicit" and coupling_order is None
        if implicit:
            if coupling_order is not None:
                raise ScenarioError(f"coupling order {coupling_order}: implicit coupling chooses its inputs' "
                                    "polynomials itself (from the sources' values and first derivatives at the end "
                                    "of each step); give one or the other")
            coupling_order = 1                        # the sources' first derivatives, for the Hermite polynomial
        if max_step is not None and tolerance is None:
            raise ScenarioError("a maximum step bounds the steps that a tolerance chooses; without a tolerance the "
                                "steps are fixed: give the step size")
        if tolerance is not None:
            stepcontrol.check_tolerance(tolerance)
            max_step = (t_stop - t0) / 50 if max_step is None else max_step
            if not (math.isfinite(max_step) and max_step > 0):
                raise ScenarioError(f"maximum step {max_step} must be positive")
        parameters = parameter_values(self.scenario, self.instances, start_values or {})
        tic = time.perf_counter()
        steppers, mains, level, first = [], [], None, None
        for attempt in range(1 if tolerance is None else 2):
            if self.runs > 0:
                self._reset()
            self.runs += 1
            plan = self._plan(record, self.instances)
            orders = coupling.connection_orders(self.instances, self.connections, plan.level, plan.depends,
                                                coupling_order, self._accepted)
            if attempt and sink is not None:
                sink.rewind()                         # the second pass replaces the first's rows
            result = Result(plan.columns, sink=sink)
            stepper = _Stepper(self.scenario, self.instances, plan, [0.0] * _n_slots(plan),
                               self._derivatives(plan, orders, self.instances, coupling_order, implicit))
            steppers.append(stepper)
            mains.append(stepper)
            _initialize(self.scenario, self.instances, parameters, t0, t_stop, stepper, tolerance)
            orders = self._settle_orders(stepper, plan, orders, coupling_order, t0, implicit)
            if implicit:
                stepper.implicit = self._implicit(stepper, plan, halve=tolerance is None)
                if steppers[:-1] and steppers[0].implicit is not None:      # a second run: count both
                    stepper.implicit.statistics = steppers[0].implicit.statistics
                result.implicit = stepper.implicit.statistics
            first_step = h if tolerance is None else min(h, max_step)
            if stepper.derivatives is not None:
                stepper.derivatives.first_step = first_step       # coupling._Guard's first decision
            result.warnings = [f"{name}: {' '.join(m.split())[len('[warning] '):]}"
                               for name, inst in self.instances.items() for m in inst.messages
                               if m.startswith("[warning]")]
            result.coupling_orders = dict(stepper.derivatives.orders) if stepper.derivatives is not None else dict(orders)
            if tolerance is None:
                _run_fixed(stepper, result, t0, t_stop, h, progress)
                break
            _check_state_support(self.instances)
            if attempt == 0:
                stepcontrol.check_rollback(stepper, t0, min(h, max_step))
            shadow = self._shadow_stepper(plan.columns if record is None else record, orders, parameters, t0, t_stop,
                                          coupling_order, tolerance, implicit)
            steppers.append(shadow)
            if implicit:
                shadow.implicit = self._implicit(shadow, shadow.plan)
            if shadow.derivatives is not None:
                shadow.derivatives.first_step = 2 * first_step
            shadow.mirror(stepper, set(self.instances) - set(self._shadow_own))
            degree = stepper.implicit.degree if implicit else _degree(result.coupling_orders, plan.dynamic)
            report = stepcontrol.run(stepper, shadow, result, t0, t_stop, tolerance, h, max_step,
                                     degree, progress, level)
            if first is not None:                     # the second run: report both
                report.passes = 2
                report.accepted += first.accepted
                report.rejected += first.rejected
            result.step_control = report
            if report.next_level is None:
                break
            level, first = report.next_level, report
        if timing is not None:
            total = time.perf_counter() - tic
            fmu = sum(s.fmu_time() for s in steppers)
            per_fmu: dict[str, float] = {}
            for s in steppers:
                for name, v in s.fmu_times().items():
                    per_fmu[name] = per_fmu.get(name, 0.0) + v
            n_steps = sum(s.n_steps for s in mains)
            timing.update(total=total, fmu=fmu, steps=n_steps, fmus=len(self.instances), per_fmu=per_fmu,
                          overhead_per_fmu_step=(total - fmu) / max(1, n_steps * len(self.instances)))
        return result

    def _settle_orders(self, stepper: "_Stepper", plan: Plan, orders: dict[str, int], requested: int | None,
                       t0: float, implicit: bool = False) -> dict[str, int]:
        """FMI 2.0 declares canInterpolateInputs but not up to which derivative order: at the first
        communication point a target that refuses an order k > 1 of fmi2SetRealInputDerivatives
        (fmi2Error) is restored to its state before the call (fmi2SetFMUstate) and coupled at order
        k - 1 from then on (`result.coupling_orders` gives the orders used; the FMU's refusal is not
        kept among its messages)."""
        while stepper.derivatives is not None:
            fmus = States([inst for inst in self.instances.values()
                           if inst.model_description.coSimulation.canGetAndSetFMUstate],
                          "the master tries which input derivative orders the FMUs take")
            states = fmus.save(t0)
            try:
                stepper.t = t0
                stepper.resolve(with_derivatives=False)
                failure = stepper.derivatives_resolve()
                # a target that refuses an input derivative order k > 1 (and can be restored) is retried at k - 1
                retry = failure is not None and failure[0].function == "fmi2SetRealInputDerivatives" and \
                    max(failure[0].order) > 1 and failure[0].inst.model_description.coSimulation.canGetAndSetFMUstate
                if retry:
                    fmus.restore(states, t0)
            finally:
                fmus.free(states)
            if failure is None:
                break
            transfer, exc = failure
            if not retry:
                stepper.failed(transfer, exc)
            k = max(transfer.order)
            self._accepted[transfer.inst.name] = k - 1
            messages = transfer.inst.messages
            while messages and not messages[-1].startswith("[ok]"):
                messages.pop()
            orders = coupling.connection_orders(self.instances, self.connections, plan.level, plan.depends,
                                                requested, self._accepted)
            stepper.derivatives = self._derivatives(plan, orders, self.instances, requested, implicit)
            stepper.reset_counters()
        return orders

    def _implicit(self, stepper: "_Stepper", plan: Plan, halve: bool = False) -> implicit_.Implicit:
        """Implicit coupling of the inputs of the FMUs with states: Hermite polynomials where every
        source gives its first derivative (stepper's derivative plan), else chords. halve: a step that
        does not converge is retried as halves (fixed steps; the step control retries shorter itself)."""
        connections = implicit_.implicit_inputs(stepper.instances, self.connections, plan.dynamic)
        d = stepper.derivatives
        derivative_slot = None
        if d is not None and all(d.orders.get(c.end, 0) >= 1 for c in connections):
            derivative_slot = {c.end: (d.slot[(c.start, 1)], c.factor) for c in connections}
        return implicit_.Implicit(stepper, connections, plan.slot, derivative_slot,
                                  halvings=implicit_.MAX_HALVINGS if halve else 0)

    def _plan(self, record, instances) -> Plan:
        key = (None if record is None else tuple(record), instances is self._shadow)
        if key not in self._plans:
            self._plans[key] = _plan(self.scenario, instances, self.connections, record)
        return self._plans[key]

    def _derivatives(self, plan: Plan, orders: dict[str, int], instances,
                     requested: int | None, implicit: bool = False) -> coupling.DerivativePlan | None:
        """The derivative transfers; implicit coupling reads the sources' derivatives only (no order
        added by extrapolation, no guard: implicit.py sets the inputs' polynomials itself)."""
        extra = {} if implicit else coupling.extrapolated_orders(instances, self.connections, orders, requested,
                                                                  self._accepted)
        if not any(orders.values()) and not extra:
            return None
        key = ("derivatives", tuple(sorted(orders.items())), tuple(sorted(extra.items())), implicit,
               instances is self._shadow)
        if key not in self._plans:
            read_only = {c.end for c in implicit_.implicit_inputs(instances, self.connections, plan.dynamic)} \
                if implicit else None
            self._plans[key] = coupling.plan_derivatives(instances, self.connections, plan.level, orders, extra,
                                                         None if implicit else plan.slot, read_only)
        return self._plans[key]

    def _shadow_stepper(self, record, orders, parameters, t0: float, t_stop: float, requested: int | None,
                        tolerance: float, implicit: bool = False) -> "_Stepper":
        """The shadow copy for error estimation (stepcontrol.py): a second instance of every FMU with
        connected inputs, sharing the sources (FMUs without connected inputs) with the main copy."""
        fed = {c.end_element for c in self.connections}
        if self._shadow is not None and self._shadow_used:
            try:
                for name in self._shadow_own:
                    self._shadow[name].slave.reset()
                    self._shadow[name].messages.clear()
            except Exception:                 # noqa: BLE001 - any failure: a fresh shadow copy
                self._free_shadow()
        if self._shadow is None:
            own = {name: inst for name, inst in load(self.scenario).items() if name in fed}

            def instantiate_all() -> None:
                for inst in own.values():
                    _instantiate(inst, self._workdirs)
            self._shadow = {name: own.get(name, inst) for name, inst in self.instances.items()}
            self._shadow_own = list(own)
            self._call(instantiate_all)
        self._shadow_used = True
        shadow = self._shadow
        plan = self._plan(record, shadow)
        own = self._shadow_own
        stepper = _Stepper(self.scenario, shadow, plan, [0.0] * _n_slots(plan),
                           self._derivatives(plan, orders, shadow, requested, implicit), stepped=own)
        _initialize(self.scenario, {name: shadow[name] for name in own}, parameters, t0, t_stop, stepper, tolerance)
        return stepper

    def _free_shadow(self) -> None:
        for key in [k for k in self._plans if k[-1] is True]:     # plans over the shadow's instances
            del self._plans[key]
        for name in self._shadow_own:
            _free(self._shadow[name])
        self._shadow, self._shadow_own, self._shadow_used = None, [], False

    def close(self) -> None:
        """Free the FMU instances and delete their unpacked files."""
        for inst in self.instances.values():
            _free(inst)
        self._free_shadow()
        for d in self._workdirs:
            shutil.rmtree(d, ignore_errors=True)
        self._workdirs.clear()

    def __enter__(self) -> "Simulation":
        return self

    def __exit__(self, *exc) -> None:
        self.close()


# ---- loading and checking -------------------------------------------------------------------------

def load(scenario: Scenario) -> dict[str, Instance]:
    """Read every component's modelDescription and check its connectors against it."""
    instances = {}
    for comp in scenario.components:
        if "." in comp.name:
            raise ScenarioError(f"{scenario.path}: component name '{comp.name}' must not contain '.'")
        if not comp.source.is_file():
            raise ScenarioError(f"{scenario.path}: component '{comp.name}': FMU not found: {comp.source}")
        try:
            md = read_model_description(str(comp.source), validate=False)
        except Exception as exc:                      # fmpy raises several kinds for broken FMUs
            raise ScenarioError(f"{comp.source}: cannot read modelDescription.xml "
                                f"({' '.join(str(exc).split())})") from None
        if md.coSimulation is None or not md.fmiVersion.startswith("2."):
            raise ScenarioError(f"{comp.source}: not an FMI 2.0 co-simulation FMU")
        inst = Instance(comp.name, comp.source, md, {v.name: v for v in md.modelVariables})
        for conn in comp.connectors:
            var = inst.variable(conn.name, scenario)
            if var.type != conn.type:
                raise ScenarioError(f"{scenario.path}: type mismatch: connector {comp.name}.{conn.name} is "
                                    f"{conn.type} but {comp.source.name} declares {var.type}")
            if conn.kind != var.causality and not (conn.kind == "parameter" and var.causality == "parameter"):
                raise ScenarioError(f"{scenario.path}: causality mismatch: connector {comp.name}.{conn.name} is "
                                    f"'{conn.kind}' but {comp.source.name} declares '{var.causality}'")
        instances[comp.name] = inst
    return instances


def check_connections(scenario: Scenario, instances: dict[str, Instance]) -> list:
    """Each connection must run from an output to an input of the same type; an input has one source.
    Returns the connections to run, with the unit conversion between the two ends (SSP: converted
    to the end's unit, then the connection's LinearTransformation) folded into factor and offset."""
    fed = {}
    out = []
    for c in scenario.connections:
        for element in (c.start_element, c.end_element):
            if element not in instances:
                raise ScenarioError(f"{scenario.path}: connection {c.start} -> {c.end}: no component '{element}'")
        src = instances[c.start_element].variable(c.start_connector, scenario)
        dst = instances[c.end_element].variable(c.end_connector, scenario)
        if src.causality != "output":
            raise ScenarioError(f"{scenario.path}: causality mismatch: connection starts at {c.start}, "
                                f"which is '{src.causality}', not an output")
        if dst.causality != "input":
            raise ScenarioError(f"{scenario.path}: causality mismatch: connection ends at {c.end}, "
                                f"which is '{dst.causality}', not an input")
        if src.type != dst.type:
            raise ScenarioError(f"{scenario.path}: type mismatch: connection {c.start} ({src.type}) -> "
                                f"{c.end} ({dst.type})")
        if src.type not in C_TYPES:
            raise ScenarioError(f"{scenario.path}: connection {c.start} -> {c.end}: {src.type} "
                                "connections are not supported")
        if (c.factor != 1.0 or c.offset != 0.0) and src.type != "Real":
            raise ScenarioError(f"{scenario.path}: connection {c.start} -> {c.end}: a linear "
                                "transformation needs Real variables")
        if c.end in fed:
            raise ScenarioError(f"{scenario.path}: input {c.end} is fed by both {fed[c.end]} and {c.start}")
        fed[c.end] = c.start
        out.append(_with_unit_conversion(scenario, instances, c) if src.type == "Real" else c)
    return out


def _end_unit(scenario: Scenario, inst: Instance, connector: str) -> units.Unit | None:
    """The unit of one end of a connection: the FMU variable's (from its UnitDefinitions), else the
    .ssd connector's, else None (unitless)."""
    var = inst.variables[connector]
    name = units.unit_of_variable(var)
    fmu_units = units.of_model_description(inst.model_description)
    conn = next((k for k in scenario.component(inst.name).connectors if k.name == connector), None)
    if conn is not None and conn.unit:
        declared = conn.unit_definition or fmu_units.get(conn.unit) or units.Unit(conn.unit, None)
        if name is not None:
            fmu = fmu_units.get(name) or units.Unit(name, None)
            if units.conversion(declared, fmu) is None:
                raise ScenarioError(f"{scenario.path}: unit mismatch: connector {inst.name}.{connector} is "
                                    f"[{conn.unit}] ({declared.dimension()}) but {inst.path.name} declares "
                                    f"[{name}] ({fmu.dimension()})")
        else:
            return declared
    if name is None:
        return None
    return fmu_units.get(name) or units.Unit(name, None)


def _with_unit_conversion(scenario: Scenario, instances: dict[str, Instance], c):
    src = _end_unit(scenario, instances[c.start_element], c.start_connector)
    dst = _end_unit(scenario, instances[c.end_element], c.end_connector)
    if c.suppress_unit_conversion or src is None or dst is None:
        return c
    ab = units.conversion(src, dst)
    if ab is None:
        raise ScenarioError(f"{scenario.path}: unit mismatch: connection {c.start} [{src.name}] "
                            f"({src.dimension()}) -> {c.end} [{dst.name}] ({dst.dimension()}): "
                            "the dimensions differ (suppressUnitConversion=\"true\" on the connection "
                            "to connect them anyway)")
    a, b = ab
    if a == 1.0 and b == 0.0:
        return c
    return dataclasses.replace(c, factor=c.factor * a, offset=c.factor * b + c.offset)


def parameter_values(scenario: Scenario, instances: dict[str, Instance],
                     overrides: dict[str, str | float]) -> dict[str, list[tuple[object, object]]]:
    """(variable, value) pairs to set per component: .ssv values (converted to the FMU variable's
    unit), then overrides, all checked: the variable can be set and is not a connected input, the
    value has its type, an Integer fits in 32 bits, and values are within a declared min/max."""
    values: dict[str, dict[str, tuple[object, object]]] = {name: {} for name in instances}
    fed = {c.end: c.start for c in scenario.connections}
    for comp in scenario.components:
        inst = instances[comp.name]
        where = f"{scenario.path.parent / (comp.parameter_sources[-1] if comp.parameter_sources else scenario.path.name)}"
        for p in comp.parameters.values():
            if p.name not in inst.variables:
                raise ScenarioError(f"{where}: unknown parameter '{comp.name}.{p.name}' (not in {inst.path.name})")
            var = inst.variables[p.name]
            what = f"{where}: parameter '{comp.name}.{p.name}'"
            _check_settable(var, what, inst, fed.get(f"{comp.name}.{p.name}"))
            if var.type != p.type and not (var.type == "Real" and p.type == "Integer"):
                raise ScenarioError(f"{where}: type mismatch: parameter '{comp.name}.{p.name}' is {p.type} "
                                    f"but {inst.path.name} declares {var.type}")
            value = float(p.value) if var.type == "Real" else p.value
            if p.unit and var.type == "Real":
                value = _convert_unit(value, p, var, inst, what)
            values[comp.name][p.name] = (var, _check_range(value, var, what, inst))
    for full, raw in overrides.items():
        comp_name, _, var_name = full.partition(".")
        if comp_name not in instances or not var_name:
            raise ScenarioError(f"--set {full}: no component '{comp_name}' in {scenario.path.name} "
                                f"(components: {', '.join(instances)})")
        inst = instances[comp_name]
        if var_name not in inst.variables:
            raise ScenarioError(f"--set {full}: unknown variable '{var_name}' (not in {inst.path.name})")
        var = inst.variables[var_name]
        _check_settable(var, f"--set {full}", inst, fed.get(full))
        value = parse_value(str(raw), var.type, f"--set {full}") if isinstance(raw, str) else raw
        if var.type == "Real":
            value = float(value)
        values[comp_name][var_name] = (var, _check_range(value, var, f"--set {full}", inst))
    return {name: list(v.values()) for name, v in values.items()}


def _convert_unit(value: float, p, var, inst: Instance, what: str) -> float:
    """An .ssv value in the parameter's unit, converted to the unit of the FMU variable."""
    fmu_units = units.of_model_description(inst.model_description)
    source = p.unit_definition or fmu_units.get(p.unit)
    if source is None:
        raise ScenarioError(f"{what}: unit '{p.unit}' is defined neither in the file's ssv:Units nor in "
                            f"{inst.path.name}'s UnitDefinitions")
    name = units.unit_of_variable(var)
    target = (fmu_units.get(name) or units.Unit(name, None)) if name else units.Unit("1", (0.0,) * len(units.BASE))
    ab = units.conversion(source, target)
    if ab is None:
        raise ScenarioError(f"{what}: unit mismatch: the value is in [{p.unit}] ({source.dimension()}) but "
                            f"{inst.path.name} declares {var.name} in [{name or 'no unit'}] ({target.dimension()})")
    return ab[0] * value + ab[1]


def _check_range(value, var, what: str, inst: Instance):
    """Refuse an Integer outside 32 bits (fmi2Integer would wrap it) and a value outside the
    variable's declared min/max."""
    if var.type == "Integer" and not isinstance(value, bool) and not INT_MIN <= value <= INT_MAX:
        raise ScenarioError(f"{what}: value {value} does not fit an FMI Integer (32 bits: {INT_MIN} .. {INT_MAX})")
    if var.type in ("Real", "Integer"):
        for bound, ok in ((var.min, lambda b: value >= b), (var.max, lambda b: value <= b)):
            if bound is not None and not ok(float(bound)):
                raise ScenarioError(f"{what}: value {value} is outside [{var.min if var.min is not None else '-inf'}, "
                                    f"{var.max if var.max is not None else 'inf'}] declared by {inst.path.name}")
    return value


def _check_settable(var, where: str, inst: Instance, source: str | None = None) -> None:
    if var.causality not in ("parameter", "input") or var.variability == "constant":
        raise ScenarioError(f"{where}: causality mismatch: {inst.path.name} declares it "
                            f"{var.causality} ({var.variability}); only parameters and inputs can be set")
    if var.causality == "input" and source is not None:
        raise ScenarioError(f"{where}: input is connected (fed by {source}); the master sets it from the "
                            "connection, a start value would be ignored")


# ---- instantiation --------------------------------------------------------------------------------

def _instantiate(inst: Instance, workdirs: list) -> None:
    unzipdir = str(tempdirs.make(inst.name))          # emcosim-PID-...: removed at the next start if killed
    workdirs.append(unzipdir)
    extract_archive(inst.path, unzipdir)             # within the archive limits (a zip bomb is refused)
    md = inst.model_description

    def logger(component, instance_name, status, category, message):
        text = message.decode("utf-8", "replace") if message else ""
        inst.messages.append(f"[{STATUS[status] if 0 <= status < 6 else status}] {text}")

    callbacks = fmi2CallbackFunctions()
    callbacks.logger = fmi2CallbackLoggerTYPE(logger)
    callbacks.allocateMemory = fmi2CallbackAllocateMemoryTYPE(calloc)
    callbacks.freeMemory = fmi2CallbackFreeMemoryTYPE(free)
    inst.callbacks = callbacks                        # keep the ctypes callbacks alive
    slave = FMU2Slave(guid=md.guid, unzipDirectory=unzipdir, modelIdentifier=md.coSimulation.modelIdentifier,
                      instanceName=inst.name)
    try:
        slave.instantiate(callbacks=callbacks, loggingOn=True)
    except Exception:
        raise ScenarioError(f"{inst.path}: component '{inst.name}' could not be instantiated"
                            f"{_last_message(inst)}") from None
    inst.slave = slave


def _free(inst: Instance) -> None:
    if inst.slave is None:
        return
    try:
        inst.slave.terminate()
    except Exception:
        pass
    try:
        inst.slave.freeInstance()
    except Exception:
        pass
    inst.slave = None


def _last_message(inst: Instance) -> str:
    errors = [m for m in inst.messages if not m.startswith("[ok]")]
    return f": {' '.join(errors[-1].split())}" if errors else ""


# ---- the plan of a communication point ------------------------------------------------------------

def _plan(scenario: Scenario, instances: dict[str, Instance], connections, record) -> Plan:
    depends = {}
    for name, inst in instances.items():
        for out, ins in dependencies.feedthrough(inst.model_description).items():
            depends[f"{name}.{out}"] = {f"{name}.{i}" for i in ins}
    pairs = [(c.start, c.end) for c in connections]
    level = dependencies.levels(pairs, depends)
    slot: dict[str, int] = {}

    def slot_of(full: str) -> int:
        return slot.setdefault(full, len(slot))

    stages = []
    for k in range(max(level.values(), default=-1) + 1):
        outs = [o for o in level if level[o] == k]
        gets = _batches(instances, outs, slot_of, getter=True)
        ins = [(c, c.end) for c in connections if level[c.start] == k]
        sets = []
        for transfer, names in _batches(instances, [e for _, e in ins], slot_of, getter=False):
            conn_of = {c.end: c for c, _ in ins}
            sources = [(slot_of(conn_of[n].start), conn_of[n].factor, conn_of[n].offset) for n in names]
            sets.append((transfer, sources))
        stages.append((gets, sets))
    if record is None:
        columns = [f"{c.name}.{k.name}" for c in scenario.components for k in c.connectors
                   if k.kind in ("input", "output")]
        if not columns:
            columns = [c.start for c in connections] + [c.end for c in connections]
        columns = list(dict.fromkeys(columns))
    else:
        columns = list(record)
    for full in columns:
        comp_name, _, var_name = full.partition(".")
        if comp_name not in instances or var_name not in instances[comp_name].variables:
            raise ScenarioError(f"{scenario.path}: cannot record unknown variable '{full}'")
        if instances[comp_name].variables[var_name].type not in C_TYPES:
            raise ScenarioError(f"{scenario.path}: cannot record {full}: only Real, Integer and Boolean")
    fetched = set(level) | {c.end for c in connections}
    extra = [f for f in columns if f not in fetched]
    record_gets = _batches(instances, extra, slot_of, getter=True)
    dynamic = {name for name, inst in instances.items() if dependencies.has_state(inst.model_description)}
    return Plan(stages, record_gets, columns, [slot_of(f) for f in columns], level, depends,
                [(c.end, slot_of(c.end)) for c in connections], dynamic, slot)


def _batches(instances, fulls: list[str], slot_of, getter: bool):
    """Group full names by (component, type) into transfers; returns [(transfer, names)]."""
    groups: dict[tuple[str, str], list[str]] = {}
    for full in fulls:
        comp_name, _, var_name = full.partition(".")
        var = instances[comp_name].variables[var_name]
        groups.setdefault((comp_name, var.type), []).append(full)
    out = []
    for (comp_name, type_), names in groups.items():
        local = [n.partition(".")[2] for n in names]
        transfer = _Transfer(instances[comp_name], local, type_, getter)
        transfer.slots = [slot_of(n) for n in names]
        out.append((transfer, names))
    return out


def _n_slots(plan: Plan) -> int:
    n = 0
    for gets, sets in plan.stages:
        for t, _ in gets:
            n = max([n] + [s + 1 for s in t.slots])
        for t, _ in sets:
            n = max([n] + [s + 1 for s in t.slots])
    for t, _ in plan.record:
        n = max([n] + [s + 1 for s in t.slots])
    return max([n] + [s + 1 for s in plan.column_slots])


# ---- running --------------------------------------------------------------------------------------

class _Stepper:
    """Resolve, record and step; the hot loop of the master.

    derivatives: the output-derivative transfers (coupling.DerivativePlan) resolved after the values
    at every communication point, or None (zero-order hold). stepped: the components this stepper
    steps (default: all; a shadow copy for error estimation leaves the shared sources out)."""

    def __init__(self, scenario: Scenario, instances: dict[str, Instance], plan: Plan, slots: list,
                 derivatives: coupling.DerivativePlan | None = None, stepped: list[str] | None = None):
        self.scenario, self.instances, self.plan, self.slots = scenario, instances, plan, slots
        self.derivatives = derivatives
        self.order = [inst for name, inst in instances.items() if stepped is None or name in stepped]
        self.do_step = [(inst, inst.slave._functions["fmi2DoStep"], inst.slave.component) for inst in self.order]
        self.implicit: implicit_.Implicit | None = None   # implicit coupling (implicit.py), set by the run
        self.reset_counters()
        self.step_time = 0.0
        self.step_times = {inst.name: 0.0 for inst in self.order}
        self.n_steps = 0
        self.t = scenario.start_time
        self._values_at: float | None = None              # the values are resolved at this time already

    def resolve(self, with_derivatives: bool = True) -> None:
        slots = self.slots
        if self._values_at == self.t:                     # an implicit step resolved them at its end
            self._values_at = None
            return
        self._values_at = None
        try:
            for gets, sets in self.plan.stages:
                for transfer, _ in gets:
                    transfer()
                    values = transfer.values
                    for i, s in enumerate(transfer.slots):
                        slots[s] = values[i]
                for transfer, sources in sets:
                    values = transfer.values
                    for i, (src, factor, offset) in enumerate(sources):
                        v = slots[src] if factor == 1.0 and offset == 0.0 else factor * slots[src] + offset
                        values[i] = v
                        slots[transfer.slots[i]] = v
                    transfer()
            for transfer, _ in self.plan.record:
                transfer()
                values = transfer.values
                for i, s in enumerate(transfer.slots):
                    slots[s] = values[i]
        except FMICallException as exc:
            self.failed(transfer, exc)
        except NonFiniteValue as exc:
            raise SimulationError(exc.message(self.t)) from None
        if self.derivatives is not None and with_derivatives:
            self._check_failure(self.derivatives_resolve())

    def derivatives_resolve(self):
        """Resolve the output derivatives at self.t (after the values): None, or (the transfer that
        failed, its FMICallException); a derivative that is not finite ends the run."""
        try:
            return self.derivatives.resolve(self.t, self.slots)
        except coupling.NonFiniteDerivative as exc:
            raise SimulationError(exc.message(self.t)) from None

    def _check_failure(self, failure) -> None:
        if failure is not None:
            self.failed(*failure)

    def failed(self, transfer, exc: FMICallException):
        inst = transfer.inst
        raise SimulationError(f"{inst.path.name}: component '{inst.name}' failed in {exc.function} "
                              f"at t = {self.t:.9g} s{_last_message(inst)}") from None

    def row(self) -> list:
        slots = self.slots
        return [slots[s] for s in self.plan.column_slots]

    def reset_counters(self) -> None:
        """Plans (their transfers and extrapolation histories) are reused across runs: start afresh."""
        for transfer in self.transfers():
            transfer.elapsed = 0.0
        for extrapolation in self.derivatives.extrapolations if self.derivatives is not None else []:
            extrapolation.history.clear()
        if self.derivatives is not None and self.derivatives.guard is not None:
            self.derivatives.guard.history.clear()

    def mirror(self, main: "_Stepper", shared: set[str]) -> None:
        """Read the outputs (and output derivatives) of the components `shared` with `main` from
        main's buffers; main resolves each communication point first."""
        def values(gets):
            return [(_Mirror(t, main.slots, [main.plan.slot[n] for n in names]) if t.inst.name in shared else t, names)
                    for t, names in gets]
        plan = self.plan
        self.plan = dataclasses.replace(plan, stages=[(values(gets), sets) for gets, sets in plan.stages],
                                        record=values(plan.record))
        d, md = self.derivatives, main.derivatives
        if d is not None and md is not None:
            def derivatives(gets):
                return [_Mirror(t, md.values, [md.slot[(f"{t.inst.name}.{v}", k)] for v, k in t.entries])
                        if t.inst.name in shared else t for t in gets]
            self.derivatives = dataclasses.replace(d, passes=[[(derivatives(gets), sets) for gets, sets in levels]
                                                              for levels in d.passes])

    def transfers(self) -> list:
        """Every get/set transfer of a communication point (values, records, derivatives)."""
        out = [t for gets, sets in self.plan.stages for t, _ in gets + sets] + [t for t, _ in self.plan.record]
        out += self.implicit.transfers() if self.implicit is not None else []
        return out + (self.derivatives.transfers() if self.derivatives is not None else [])

    def fmu_time(self) -> float:
        return self.step_time + sum(t.elapsed for t in self.transfers())

    def fmu_times(self) -> dict[str, float]:
        """Wall time inside each FMU (doStep, get, set, derivatives)."""
        out = dict(self.step_times)
        for transfer in self.transfers():
            out[transfer.inst.name] = out.get(transfer.inst.name, 0.0) + transfer.elapsed
        return out

    def step(self, t: float, h: float) -> None:
        """Step every FMU from t to t + h (with implicit coupling: iterated, the values at t + h resolved)."""
        if self.implicit is not None:
            self.implicit.step(t, h)
            self._values_at = t + h
        else:
            self.step_some(t, h, self.do_step)
        self.n_steps += 1
        self.t = t + h

    def step_some(self, t: float, h: float, do_step: list) -> None:
        """fmi2DoStep from t over h of the FMUs `do_step` ([(instance, fmi2DoStep, component)])."""
        tic = time.perf_counter()
        times = self.step_times
        for inst, fn, comp in do_step:
            t_in = time.perf_counter()
            status = fn(comp, t, h, 1)
            times[inst.name] += time.perf_counter() - t_in
            if status > 1:
                self.step_time += time.perf_counter() - tic
                raise SimulationError(f"{inst.path.name}: component '{inst.name}' failed in fmi2DoStep "
                                      f"from t = {t:.9g} s (step {h:.3g} s, status {STATUS[status] if status < 6 else status})"
                                      f"{_last_message(inst)}")
        self.step_time += time.perf_counter() - tic

    def value_setter(self, component: str, names: list[str]) -> Callable[[list[float]], None]:
        """A function that sets the Real inputs `names` of `component` to given values."""
        transfer = _Transfer(self.instances[component], names, "Real", getter=False)

        def set_values(values: list[float]) -> None:
            for i, v in enumerate(values):
                transfer.values[i] = v
            try:
                transfer()
            except FMICallException as exc:
                self.failed(transfer, exc)
            except NonFiniteValue as exc:
                raise SimulationError(exc.message(self.t)) from None
        return set_values


def _initialize(scenario, instances, parameters, t0, t_stop, stepper: _Stepper, tolerance: float | None = None) -> None:
    """Set up, set the parameters, propagate the outputs in initialization mode. With a tolerance (an
    error-controlled run) the FMUs get INTERNAL_TOLERANCE times it in fmi2SetupExperiment, for their
    own integrators (FMI 2.0 suggests a slave with an error-controlled integrator use it)."""
    internal = None if tolerance is None else INTERNAL_TOLERANCE * tolerance
    for name, inst in instances.items():
        slave = inst.slave
        try:
            slave.setupExperiment(tolerance=internal, startTime=t0, stopTime=t_stop)
            for var, value in parameters[name]:
                setter = {"Real": slave.setReal, "Integer": slave.setInteger,
                          "Boolean": slave.setBoolean, "String": slave.setString}[var.type]
                setter([var.valueReference], [value.encode() if var.type == "String" else value])
            slave.enterInitializationMode()
        except FMICallException as exc:
            raise ScenarioError(f"{inst.path.name}: component '{name}' refused {exc.function} "
                                f"during initialization{_last_message(inst)}") from None
    try:
        stepper.resolve(with_derivatives=False)
    except SimulationError as exc:
        raise ScenarioError(f"initialization: {exc}") from None
    for name, inst in instances.items():
        try:
            inst.slave.exitInitializationMode()
        except FMICallException as exc:
            raise ScenarioError(f"{inst.path.name}: component '{name}' failed in {exc.function}"
                                f"{_last_message(inst)}") from None


def _run_fixed(stepper: _Stepper, result: Result, t0: float, t_stop: float, h: float, progress) -> None:
    n_steps = max(1, math.ceil((t_stop - t0) / h - 1e-9))
    every = max(1, n_steps // 200)
    try:
        for n in range(n_steps):
            t = t0 + n * h
            stepper.t = t
            stepper.resolve()
            result.append(t, stepper.row())
            t_next = t_stop if n == n_steps - 1 else t0 + (n + 1) * h
            stepper.step(t, t_next - t)
            if progress is not None and n % every == 0:
                progress((n + 1) / n_steps)
        stepper.t = t_stop
        stepper.resolve()
        result.append(t_stop, stepper.row())
    except SimulationError as exc:
        exc.result = result
        raise
    if progress is not None:
        progress(1.0)


def _degree(orders: dict[str, int], dynamic: set[str]) -> int:
    """The coupling order that sets the global error: the lowest polynomial degree on the inputs of
    FMUs that integrate them (stepcontrol.py), else on all inputs."""
    integrated = [k for name, k in orders.items() if name.partition(".")[0] in dynamic]
    return min(integrated or list(orders.values()) or [0])


def _check_state_support(instances: dict[str, Instance]) -> None:
    for inst in instances.values():
        if not inst.model_description.coSimulation.canGetAndSetFMUstate:
            raise ScenarioError(f"{inst.path.name}: error-controlled steps need canGetAndSetFMUstate")
