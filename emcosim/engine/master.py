"""The co-simulation master: runs an SSP scenario of FMI 2.0 FMUs with fmpy.

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
the FMUs for the global error estimate). With interface_type "ModelExchange" there are no
communication steps: model_exchange.py integrates the FMUs' states as one ODE.

The modules it composes: options.py (the settings, checked once), binding.py (the scenario bound to its
FMUs), instances.py, plan.py and transfer.py (what moves at a communication point), stepper.py (the hot
loop), coupling.py, implicit.py and stepcontrol.py. The master knows nothing of the models: any FMI 2.0
co-simulation FMU and any SSP scenario runs.
"""
from __future__ import annotations

import math
import time
from typing import Callable, Sequence

from . import binding, coupling
from . import implicit as implicit_
from . import instances as instances_
from .doubling import StepDoubling
from .errors import ScenarioError, SimulationError
from .fmi import FMICallException
from .fmustate import States
from .instances import Instance, last_message
from .model_exchange import simulate_model_exchange
from .options import Experiment, RunOptions, experiment, options_of
from .outputs import ResultFile
from .plan import Plan, make_plan, n_slots
from .results import Result
from .ssd import Scenario
from .stepcontrol import StepControl, check_rollback
from .stepper import Stepper

INTERNAL_TOLERANCE = 0.01               # error-controlled runs: the FMUs' integrators get this times the tolerance


def simulate(scenario: Scenario, options: RunOptions | None = None,
             start_values: dict[str, str | float] | None = None, record: Sequence[str] | None = None,
             progress: Callable[[float], None] | None = None, timing: dict | None = None,
             sink: ResultFile | None = None, **settings) -> Result:
    """Run `scenario` once and return the recorded values at every communication point.

    options: the run's settings, one RunOptions (options.py; None: the scenario's choices); `settings` are
    shorthands for its fields (simulate(s, stop_time=1.0) is simulate(s, RunOptions(stop_time=1.0))), each
    described below.

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
    coupling: "implicit" iterates every communication step until the inputs of the FMUs with states
        agree with their sources at its end (implicit.py: stable on stiff loops at any step, third order;
        `result.implicit` gives the trial steps); it takes no coupling_order (it sets the inputs'
        polynomials itself). "explicit": the polynomials of the sources' derivatives at the start of each
        step. None (default): the scenario's choice (its emcosim:Coupling annotation), explicit if it makes
        none or if a coupling_order is given.
    interface_type: "CoSimulation" (default) or "ModelExchange": every FMU instantiated for Model Exchange
        and their states integrated as one ODE by scipy's `solver` (LSODA, BDF or Radau): one solve at the
        solver's relative tolerance `rtol` (default 1e-6), or, with a `tolerance`, the solves that keep that
        global error (model_exchange.py); the rows are at t0 + n step_size, or at every step of the solver
        with `solver_steps`. `result.model_exchange` reports the steps, right-hand sides and events.
    timing: if a dict is given, the master fills in the wall time of the run ('total', from
        initialization to the end), the part spent inside FMU calls ('fmu'), the number of
        communication steps ('steps') and FMUs ('fmus'), the time inside each FMU ('per_fmu',
        by component name), and 'overhead_per_fmu_step' =
        (total - fmu) / (steps * fmus): the master's own cost.
    sink: a `outputs.ResultFile`: every row is written to it as it is produced and the returned
        Result keeps only the last row in memory (without a sink, every row stays in memory).
    max_steps: refuse a run of more communication steps than this (a typing error such as a step
        of 1e-15 s would otherwise run for years); raise it to confirm a long run.
    Raises ScenarioError (an OptionError for a setting) for a scenario that cannot run, SimulationError
    (with `.result`, the values recorded so far) for an FMU that fails during the run (or a value that is
    not finite), `errors.Interrupted` when stopped by a signal (see `stopping`).
    """
    options = options_of(options, **settings)
    planned = experiment(scenario, options)                 # refuse a bad horizon before loading
    if options.model_exchange:
        return simulate_model_exchange(scenario, options, planned, start_values=start_values, record=record,
                                       progress=progress, timing=timing, sink=sink)
    with Simulation(scenario) as simulation:
        return simulation.run_experiment(options, planned, start_values=start_values, record=record,
                                         progress=progress, timing=timing, sink=sink)


class _Plans:
    """The plans of one copy of the FMUs (they hold its instances' C handles): the value plan per record,
    the derivative plan per set of orders."""

    def __init__(self) -> None:
        self.values: dict[tuple | None, Plan] = {}
        self.derivatives: dict[tuple, coupling.DerivativePlan] = {}

    def clear(self) -> None:
        self.values.clear()
        self.derivatives.clear()


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
        self._plans = _Plans()
        self._shadow_plans = _Plans()
        self._shadow: dict[str, Instance] | None = None     # the copy for error estimation (stepcontrol)
        self._shadow_own: list[str] = []                     # its own instances (the others are shared)
        self._shadow_used = False
        self.instances = binding.load(scenario)
        self._accepted = declared_orders(self.instances)     # input derivative orders declared or found accepted
        self.connections = binding.check_connections(scenario, self.instances)
        try:
            self._instantiate()
        except BaseException:
            self.close()
            raise

    # ---- the FMUs ---------------------------------------------------------------------------------
    def _instantiate(self) -> None:
        def instantiate_all() -> None:
            for inst in self.instances.values():
                instances_.instantiate(inst, self._workdirs)
        self._call(instantiate_all)
        self.instantiations += 1
        self._plans.clear()                   # plans hold the instances' C handles
        self._free_shadow()
        self.runs = 0

    def _reset(self) -> None:
        instances_.reset_all(self.instances, self._instantiate)

    def close(self) -> None:
        """Free the FMU instances and delete their unpacked files."""
        self._free_shadow()
        instances_.free_all(self.instances, self._workdirs)

    def __enter__(self) -> "Simulation":
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    # ---- runs -------------------------------------------------------------------------------------
    def run(self, options: RunOptions | None = None, start_values: dict[str, str | float] | None = None,
            record: Sequence[str] | None = None, progress: Callable[[float], None] | None = None,
            timing: dict | None = None, sink: ResultFile | None = None, **settings) -> Result:
        """Run the scenario once (Co-Simulation); the arguments and errors are those of `simulate`."""
        options = options_of(options, **settings)
        return self.run_experiment(options, experiment(self.scenario, options), start_values=start_values,
                                   record=record, progress=progress, timing=timing, sink=sink)

    def run_experiment(self, options: RunOptions, planned: Experiment,
                       start_values: dict[str, str | float] | None = None, record: Sequence[str] | None = None,
                       progress: Callable[[float], None] | None = None, timing: dict | None = None,
                       sink: ResultFile | None = None) -> Result:
        """Run the scenario once with checked `options` and their `planned` experiment (options.experiment)."""
        if options.model_exchange:
            raise ScenarioError("a Simulation runs its FMUs as Co-Simulation ones; simulate() runs Model Exchange")
        implicit = self._implicit_wanted(options)
        requested = 1 if implicit else options.coupling_order   # implicit: the sources' first derivatives
        parameters = binding.parameter_values(self.scenario, self.instances, start_values or {})
        tic = time.perf_counter()
        if options.tolerance is None:
            stepper, result, _ = self._start(record, parameters, planned, requested, implicit, None, sink)
            _run_fixed(stepper, result, planned, progress)
            mains, shadows = [stepper], list[Stepper]()
        else:
            mains, shadows, result = self._run_error_controlled(options, planned, record, parameters, requested,
                                                                implicit, progress, sink)
        if timing is not None:
            _fill_timing(timing, mains, shadows, time.perf_counter() - tic, len(self.instances))
        return result

    def _implicit_wanted(self, options: RunOptions) -> bool:
        if options.coupling is not None:
            return options.coupling == "implicit"
        return self.scenario.coupling == "implicit" and options.coupling_order is None

    def _start(self, record, parameters, planned: Experiment, requested: int | None, implicit: bool,
               tolerance: float | None, sink: ResultFile | None,
               rewind: bool = False) -> tuple[Stepper, Result, dict[str, int]]:
        """A fresh run of the main copy: reset, plan, initialize, settle the derivative orders (returned)."""
        if self.runs > 0:
            self._reset()
        self.runs += 1
        plan = self._plan(record, self.instances, self._plans)
        orders = coupling.connection_orders(self.instances, self.connections, plan.level, plan.depends,
                                            requested, self._accepted)
        if rewind and sink is not None:
            sink.rewind()                         # the second pass replaces the first's rows
        result = Result(plan.columns, sink=sink,
                        notes=binding.model_differences(self.scenario, self.instances, parameters))
        stepper = Stepper(self.scenario, self.instances, plan, [0.0] * n_slots(plan),
                          self._derivatives(plan, orders, self.instances, requested, implicit, self._plans))
        _initialize(self.scenario, self.instances, parameters, planned, stepper, tolerance)
        orders = self._settle_orders(stepper, plan, orders, requested, planned.start_time, implicit)
        if implicit:
            stepper.implicit = self._implicit(stepper, plan, halve=tolerance is None)
            result.implicit = stepper.implicit.statistics
        first_step = planned.step_size if tolerance is None else min(planned.step_size, planned.max_step)
        if stepper.derivatives is not None:
            stepper.derivatives.first_step = first_step       # coupling._Guard's first decision
        result.warnings += [f"{name}: {note}" for name, inst in self.instances.items() for note in inst.notes]
        result.warnings += [f"{name}: {' '.join(m.split())[len('[warning] '):]}"
                            for name, inst in self.instances.items() for m in inst.messages
                            if m.startswith("[warning]")]
        result.coupling_orders = dict(stepper.derivatives.orders) if stepper.derivatives is not None else dict(orders)
        return stepper, result, orders

    def _run_error_controlled(self, options: RunOptions, planned: Experiment, record, parameters,
                              requested: int | None, implicit: bool, progress,
                              sink) -> tuple[list[Stepper], list[Stepper], Result]:
        """One error-controlled run, and a second one at the level the first one's calibration gives when
        the first missed the aim (stepcontrol.py). Returns the main and the shadow steppers, and the result."""
        mains: list[Stepper] = []
        shadows: list[Stepper] = []
        level, first = None, None
        for attempt in range(2):
            stepper, result, orders = self._start(record, parameters, planned, requested, implicit, options.tolerance,
                                                  sink, rewind=attempt > 0)
            if attempt and implicit and mains[0].implicit is not None:   # a second run: count both
                stepper.implicit.statistics = mains[0].implicit.statistics
                result.implicit = stepper.implicit.statistics
            mains.append(stepper)
            _check_state_support(self.instances)
            if attempt == 0:
                check_rollback(stepper, planned.start_time, min(planned.step_size, planned.max_step))
            shadow = self._shadow_stepper(result.columns if record is None else record, orders,
                                          parameters, planned, requested, options.tolerance, implicit)
            shadows.append(shadow)
            if implicit:
                shadow.implicit = self._implicit(shadow, shadow.plan)
            if shadow.derivatives is not None:
                shadow.derivatives.first_step = 2 * min(planned.step_size, planned.max_step)
            shadow.mirror(stepper, set(self.instances) - set(self._shadow_own))
            degree = stepper.implicit.degree if implicit else _degree(result.coupling_orders, stepper.plan.dynamic)
            report = StepControl(stepper, shadow, result, planned.start_time, planned.stop_time, options.tolerance,
                                 planned.step_size, planned.max_step, degree, progress, level).run()
            if first is not None:                     # the second run: report both
                report.passes = 2
                report.accepted += first.accepted
                report.rejected += first.rejected
            result.step_control = report
            if report.next_level is None:
                break
            level, first = report.next_level, report
        return mains, shadows, result

    # ---- derivative orders and implicit coupling ------------------------------------------------------
    def _settle_orders(self, stepper: Stepper, plan: Plan, orders: dict[str, int], requested: int | None,
                       t0: float, implicit: bool = False) -> dict[str, int]:
        """FMI 2.0 declares canInterpolateInputs but not up to which derivative order: at the first
        communication point a target that refuses an order k > 1 of fmi2SetRealInputDerivatives
        (fmi2Error) is restored to its state before the call (fmi2SetFMUstate) and coupled at order
        k - 1 from then on (`result.coupling_orders` gives the orders used; the FMU's refusal is not
        kept among its messages). A target that declares the order it uses (vendor.py) gets no order
        above it from the start (`declared_orders`)."""
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
                    max(failure[0].orders) > 1 and failure[0].inst.model_description.coSimulation.canGetAndSetFMUstate
                if retry:
                    fmus.restore(states, t0)
            finally:
                fmus.free(states)
            if failure is None:
                break
            transfer, exc = failure
            if not retry:
                stepper.failed(transfer, exc)
            k = max(transfer.orders)
            self._accepted[transfer.inst.name] = k - 1
            messages = transfer.inst.messages
            while messages and not messages[-1].startswith("[ok]"):
                messages.pop()
            orders = coupling.connection_orders(self.instances, self.connections, plan.level, plan.depends,
                                                requested, self._accepted)
            stepper.derivatives = self._derivatives(plan, orders, self.instances, requested, implicit, self._plans)
            stepper.reset_counters()
        return orders

    def _implicit(self, stepper: Stepper, plan: Plan, halve: bool = False) -> implicit_.Implicit:
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

    # ---- plans --------------------------------------------------------------------------------------
    def _plan(self, record, instances: dict[str, Instance], plans: _Plans) -> Plan:
        key = None if record is None else tuple(record)
        if key not in plans.values:
            plans.values[key] = make_plan(self.scenario, instances, self.connections, record)
        return plans.values[key]

    def _derivatives(self, plan: Plan, orders: dict[str, int], instances: dict[str, Instance],
                     requested: int | None, implicit: bool, plans: _Plans) -> coupling.DerivativePlan | None:
        """The derivative transfers; implicit coupling reads the sources' derivatives only (no order
        added by extrapolation, no guard: implicit.py sets the inputs' polynomials itself)."""
        extra = {} if implicit else coupling.extrapolated_orders(instances, self.connections, orders, requested,
                                                                  self._accepted)
        if not any(orders.values()) and not extra:
            return None
        key = (tuple(sorted(orders.items())), tuple(sorted(extra.items())), implicit)
        if key not in plans.derivatives:
            read_only = {c.end for c in implicit_.implicit_inputs(instances, self.connections, plan.dynamic)} \
                if implicit else None
            plans.derivatives[key] = coupling.plan_derivatives(instances, self.connections, plan.level, orders, extra,
                                                               None if implicit else plan.slot, read_only)
        return plans.derivatives[key]

    # ---- the shadow copy of error-controlled runs -------------------------------------------------------
    def _shadow_stepper(self, record, orders, parameters, planned: Experiment, requested: int | None,
                        tolerance: float, implicit: bool = False) -> Stepper:
        """The shadow copy for error estimation (stepcontrol.py): a second instance of every FMU with
        connected inputs, sharing the sources (FMUs without connected inputs) with the main copy."""
        fed = {c.end_element for c in self.connections}
        if self._shadow is not None and self._shadow_used:
            try:
                for name in self._shadow_own:
                    self._shadow[name].fmu.reset()
                    self._shadow[name].messages.clear()
            except Exception:                 # noqa: BLE001 - any failure: a fresh shadow copy
                self._free_shadow()
        if self._shadow is None:
            fresh = {name: inst for name, inst in binding.load(self.scenario).items() if name in fed}

            def instantiate_all() -> None:
                for inst in fresh.values():
                    instances_.instantiate(inst, self._workdirs)
            self._shadow = {name: fresh.get(name, inst) for name, inst in self.instances.items()}
            self._shadow_own = list(fresh)
            self._call(instantiate_all)
        self._shadow_used = True
        shadow = self._shadow
        plan = self._plan(record, shadow, self._shadow_plans)
        own = self._shadow_own
        stepper = Stepper(self.scenario, shadow, plan, [0.0] * n_slots(plan),
                          self._derivatives(plan, orders, shadow, requested, implicit, self._shadow_plans), stepped=own)
        _initialize(self.scenario, {name: shadow[name] for name in own}, parameters, planned, stepper, tolerance)
        return stepper

    def _free_shadow(self) -> None:
        self._shadow_plans.clear()                           # plans over the shadow's instances
        for name in self._shadow_own:
            instances_.free(self._shadow[name])
        self._shadow, self._shadow_own, self._shadow_used = None, [], False


# ---- the parts of a run ---------------------------------------------------------------------------------
def declared_orders(instances: dict[str, Instance]) -> dict[str, int]:
    """Component -> the input derivative order it declares it uses (emcosim's vendor annotation, vendor.py:
    FMI 2.0 has no attribute for it), for the FMUs that declare one: no higher order is passed to them."""
    return {name: inst.input_order_used for name, inst in instances.items() if inst.input_order_used is not None}


def _initialize(scenario: Scenario, instances: dict[str, Instance], parameters, planned: Experiment,
                stepper: Stepper, tolerance: float | None = None) -> None:
    """Set up, set the parameters, propagate the outputs in initialization mode. With a tolerance (an
    error-controlled run) the FMUs get INTERNAL_TOLERANCE times it in fmi2SetupExperiment, for their
    own integrators (FMI 2.0 suggests a slave with an error-controlled integrator use it)."""
    internal = None if tolerance is None else INTERNAL_TOLERANCE * tolerance
    for name, inst in instances.items():
        fmu = inst.fmu
        try:
            fmu.setupExperiment(tolerance=internal, startTime=planned.start_time, stopTime=planned.stop_time)
            for var, value in parameters[name]:
                setter = {"Real": fmu.setReal, "Integer": fmu.setInteger,
                          "Boolean": fmu.setBoolean, "String": fmu.setString}[var.type]
                setter([var.valueReference], [value.encode() if var.type == "String" else value])
            fmu.enterInitializationMode()
        except FMICallException as exc:
            raise ScenarioError(f"{inst.path.name}: component '{name}' refused {exc.function} "
                                f"during initialization{last_message(inst)}") from None
    try:
        stepper.resolve(with_derivatives=False)
    except SimulationError as exc:
        raise ScenarioError(f"initialization: {exc}") from None
    for name, inst in instances.items():
        try:
            inst.fmu.exitInitializationMode()
        except FMICallException as exc:
            raise ScenarioError(f"{inst.path.name}: component '{name}' failed in {exc.function}"
                                f"{last_message(inst)}") from None


def _run_fixed(stepper: Stepper, result: Result, planned: Experiment, progress) -> None:
    """Steps of the fixed size h: t_n = t0 + n h (never accumulated), the last one ending at t_stop. A sample
    of the steps is doubled to estimate the run's coupling error (doubling.py): `result.coupling_error`."""
    t0, t_stop, h = planned.start_time, planned.stop_time, planned.step_size
    n_steps = max(1, math.ceil((t_stop - t0) / h - 1e-9))
    every = max(1, n_steps // 200)
    order = (stepper.implicit.degree if stepper.implicit is not None
             else _degree(result.coupling_orders, stepper.plan.dynamic)) + 1
    doubling = StepDoubling(stepper, result.columns, order, n_steps)
    result.coupling_error = doubling.report

    def t_at(m: int) -> float:
        return t_stop if m == n_steps else t0 + m * h
    try:
        for n in range(n_steps):
            t = t0 + n * h
            stepper.t = t
            stepper.resolve()
            row = stepper.row()
            result.append(t, row)
            doubling.observe(n, row)
            if doubling.closes(n):
                doubling.finish(n, t, t_at)
            if doubling.sampled(n):
                doubling.begin(n, t)
            t_next = t_at(n + 1)
            stepper.step(t, t_next - t)
            if progress is not None and n % every == 0:
                progress((n + 1) / n_steps)
        stepper.t = t_stop
        stepper.resolve()
        row = stepper.row()
        result.append(t_stop, row)
        doubling.observe(n_steps, row)
        if doubling.closes(n_steps):
            doubling.finish(n_steps, t_stop, t_at)
    except SimulationError as exc:
        exc.result = result
        raise
    finally:
        doubling.close()
    if progress is not None:
        progress(1.0)


def _fill_timing(timing: dict, mains: list[Stepper], shadows: list[Stepper], total: float, n_fmus: int) -> None:
    """The `timing` of `simulate`: the time inside the FMUs of both copies, the main copy's steps."""
    steppers = mains + shadows
    fmu = sum(s.fmu_time() for s in steppers)
    per_fmu: dict[str, float] = {}
    for s in steppers:
        for name, v in s.fmu_times().items():
            per_fmu[name] = per_fmu.get(name, 0.0) + v
    n_steps = sum(s.n_steps for s in mains)
    timing.update(total=total, fmu=fmu, steps=n_steps, fmus=n_fmus, per_fmu=per_fmu,
                  overhead_per_fmu_step=(total - fmu) / max(1, n_steps * n_fmus))


def _degree(orders: dict[str, int], dynamic: set[str]) -> int:
    """The coupling order that sets the global error: the lowest polynomial degree on the inputs of
    FMUs that integrate them (stepcontrol.py), else on all inputs."""
    integrated = [k for name, k in orders.items() if name.partition(".")[0] in dynamic]
    return min(integrated or list(orders.values()) or [0])


def _check_state_support(instances: dict[str, Instance]) -> None:
    for inst in instances.values():
        if not inst.model_description.coSimulation.canGetAndSetFMUstate:
            raise ScenarioError(f"{inst.path.name}: error-controlled steps need canGetAndSetFMUstate")
