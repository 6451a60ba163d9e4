"""Model Exchange: every FMU of a scenario instantiated for Model Exchange, and their continuous states
integrated as one ODE (ode.System) by scipy (`simulate(..., interface_type="ModelExchange")`).

After each solver step the rows on the recording grid t0 + n h are taken from the solver's dense output
(the FMUs a row needs set to the interpolated state, an output that is a state read from it; a grid
point at an event's time gets the values after the event, as a Co-Simulation step to that time would), or,
with `solver_steps`, one row at every step (at an event, the values before it). Events: the FMUs' event
indicators are compared between steps; a change of domain
(z > 0 or z <= 0, FMI 2.0 section 3.1) is located on the dense output (brentq, then the first time found in
the new domain, so that the FMU sees its event's condition) and every FMU enters event mode there; an FMU
that refuses (fmi2Error: e.g. a state on the boundary of its model's domain) or asks to terminate ends the
run with a SimulationError (the rows so far are kept); changed states restart the solver. Time events
(nextEventTime, from the initial event on) bound the solver's steps, up to and including the stop time.
The engine knows no model: any FMI 2.0 Model Exchange FMUs wired by an SSP scenario run this way.

Bounded, stoppable runs (issue 31), as the Co-Simulation ones: the rows are recorded as they come (to the
run's sink: a results file written row by row) and the grid is computed point by point, never held; the
grid's rows (`options.experiment`) and each solve's steps are limited by max_steps; the solver's rtol is at
least options.MIN_RTOL. A Ctrl-C or SIGTERM stops the run at the FMUs' next evaluation (ode.py), within a
solver step, keeping the rows so far; an FMU call that fails once a stop was asked for (a second signal
raised inside it) ends the run as stopped, not as the FMU's failure. A run with a tolerance that the
solvers cannot keep ends with `RunLimit` (the rows of its last solve kept, as a partial file from the
command line), as a Co-Simulation run ends with stepcontrol.StepBelowResolution.
"""
from __future__ import annotations

import contextlib
import math
import tempfile
import time
from typing import Any, Callable, Mapping, Sequence

import numpy as np
from scipy.integrate import BDF, LSODA, Radau
from scipy.integrate._ivp.lsoda import LsodaDenseOutput
from scipy.optimize import brentq

from . import binding, stopping
from . import instances as instances_
from . import options as options_
from .errors import Interrupted, ScenarioError, SimulationError
from .fmi import FMICallException
from .instances import last_message
from .ode import Statistics, System, transfers
from .options import MAX_STEPS, ME_SOLVES, MIN_RTOL, Experiment, RunOptions, experiment, options_of
from .outputs import ResultFile
from .plan import Plan, make_plan
from .results import Result
from .ssd import Scenario


class _LSODA(LSODA):
    """scipy's LSODA with a cheaper dense output. Works around: scipy's LSODA.dense_output builds a
    DenseOutput object each step (an np.arange of the orders among it) and checks its argument at every call,
    about 2.5 us of the 10 us a step's rows pay for the dense output (0.5 ms of maglev_regulation_prop2's
    8.6, native FMUs). `_dense_output_impl` (the hook scipy's OdeSolver leaves to its methods) gives the
    interpolation of scipy's LsodaDenseOutput: the Nordsieck history read as scipy's LSODA._dense_output_impl
    reads it, evaluated at an array of times by the same numpy operations (the same doubles), scalars by
    scipy's own object. The first dense output of each solve is compared with scipy's, and a difference (a
    scipy whose internals moved) turns this off for the solve."""

    _powers: dict[int, np.ndarray] = {}        # order -> the exponents 0..order as a column

    def __init__(self, *args, **kwargs):
        super().__init__(*args, **kwargs)
        self._trusted: bool | None = None

    def _dense_output_impl(self):
        if self._trusted is False:
            return super()._dense_output_impl()
        try:
            dense = self._nordsieck()
        except (AttributeError, IndexError, TypeError, ValueError):
            self._trusted = False
            return super()._dense_output_impl()
        if self._trusted is None:
            reference = super()._dense_output_impl()
            probe = np.array([self.t_old + 0.3 * (self.t - self.t_old), self.t])
            self._trusted = bool(np.array_equal(dense(probe), reference(probe)))
            if not self._trusted:
                return reference
        return dense

    def _nordsieck(self) -> "_NordsieckDense":
        integrator = self._lsoda_solver._integrator
        iwork, rwork = integrator.iwork, integrator.rwork
        order, h = int(iwork[13]), rwork[11]
        yh = np.reshape(rwork[20:20 + (order + 1) * self.n], (self.n, order + 1), order="F").copy()
        if iwork[14] < order:
            yh[:, -1] *= (h / rwork[10]) ** order
        powers = self._powers.get(order)
        if powers is None:
            powers = self._powers[order] = np.arange(order + 1)[:, None]
        return _NordsieckDense(self.t_old, self.t, h, order, yh, powers)


class _NordsieckDense:
    """LSODA's interpolant on [t_old, t] (_LSODA): at an array of times the Nordsieck sum of scipy's
    LsodaDenseOutput._call_impl; anything else through scipy's object."""

    __slots__ = ("t_old", "t", "h", "order", "yh", "powers")

    def __init__(self, t_old: float, t: float, h: float, order: int, yh: np.ndarray, powers: np.ndarray):
        self.t_old, self.t, self.h, self.order, self.yh, self.powers = t_old, t, h, order, yh, powers

    def __call__(self, t):
        if isinstance(t, np.ndarray) and t.ndim == 1:
            return np.dot(self.yh, ((t - self.t) / self.h) ** self.powers)
        return LsodaDenseOutput(self.t_old, self.t, self.h, self.order, self.yh)(t)


SOLVERS = {"LSODA": _LSODA, "BDF": BDF, "Radau": Radau}
DEFAULT_SOLVER = "LSODA"
DEFAULT_TOLERANCE = 1e-6          # the solver's rtol when the run asks for neither rtol nor a tolerance
MAX_EVENT_ITERATIONS = 100        # fmi2NewDiscreteStates rounds of one event
CHUNK = 256                       # grid points taken from the dense output at once (memory stays bounded)
# solver steps in a row that do not move time on before a run ends as stuck (issue 40: LSODA's step underflowed
# to h = 0 at a horizon of 1e-160 s and it stepped on the spot up to max_steps, for hours). With the horizon at
# least options.min_horizon no solve was seen to need one; the bound holds whatever a solver does
MAX_STALLED_STEPS = 100


class RunLimit(SimulationError):
    """A run ended by one of its settings: a tolerance the solvers cannot keep, a solve of more steps than
    max_steps. The message names the settings as `describe(names)` spells them (the command line:
    --tolerance, --max-steps), as errors.OptionError does; `result` holds the rows so far."""

    def __init__(self, template: str, *options: str, result: Result | None = None, **fields: Any):
        self.template, self.options, self.fields = template, options, fields
        super().__init__(self.describe(), result)

    def describe(self, names: Mapping[str, str] | None = None) -> str:
        return self.template.format(**{o: (names or {}).get(o, o) for o in self.options}, **self.fields)


# ---- runs ---------------------------------------------------------------------------------------------
def simulate_model_exchange(scenario: Scenario, options: RunOptions, planned: Experiment,
                            start_values: dict[str, str | float] | None = None, record: Sequence[str] | None = None,
                            progress: Callable[[float], None] | None = None, timing: dict | None = None,
                            sink: ResultFile | None = None) -> Result:
    """One Model Exchange run of `scenario` (master.simulate's arguments; module docstring)."""
    with ModelExchangeSimulation(scenario) as simulation:
        return simulation.run_experiment(options, planned, start_values=start_values, record=record,
                                         progress=progress, timing=timing, sink=sink)


class ModelExchangeSimulation:
    """One scenario's FMUs, unpacked and instantiated once for Model Exchange; `run` as often as needed
    (fmi2Reset between runs, as master.Simulation does for Co-Simulation).

    A run at `rtol` is one solve at the solver's relative tolerance rtol (absolute: rtol times each state's
    nominal). A run with a `tolerance` keeps the recorded variables' global error within it (each variable's
    largest error over its largest magnitude in the run): it solves at rtol_A = FIRST tolerance (FIRST =
    10 / ME_SOLVES) and rtol_B = rtol_A / 10, takes |y_A - y_B| as the error of A and, with tolerance
    proportionality (the global error falls by at least RATIO per decade of rtol), d / (RATIO - 1) as the
    error of B; B is the result if that is within AIM tolerance, else a third solve at the rtol that
    proportionality gives for AIM tolerance (at most rtol_A). Each solve streams its rows to the sink (the
    next one replaces them); A's rows wait on a tape (a temporary file) for B's to be compared with them one
    by one. A third solve that would need an rtol below MIN_RTOL is not made: the run ends with `RunLimit`
    (B's rows kept). `result.model_exchange` reports the solves and the estimate."""

    FIRST, RATIO, AIM = 10 / ME_SOLVES, 5.0, 0.5

    def __init__(self, scenario: Scenario, call: Callable[[Callable[[], None]], None] | None = None):
        self.scenario = scenario
        self.runs = 0
        self._call = call or (lambda fn: fn())
        self._workdirs: list[str] = []
        self._plans: dict[tuple | None, Plan] = {}
        self._timed = False
        self.instances = binding.load(scenario, model_exchange=True)
        self.connections = binding.check_connections(scenario, self.instances)
        try:
            self._instantiate()
        except BaseException:
            self.close()
            raise

    def _instantiate(self) -> None:
        def instantiate_all() -> None:
            for inst in self.instances.values():
                instances_.instantiate(inst, self._workdirs, model_exchange=True)
        self._call(instantiate_all)
        self._plans.clear()
        self.runs = 0

    def _reset(self) -> None:
        instances_.reset_all(self.instances, self._instantiate)

    def close(self) -> None:
        instances_.free_all(self.instances, self._workdirs)

    def __enter__(self) -> "ModelExchangeSimulation":
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    def run(self, options: RunOptions | None = None, start_values: dict[str, str | float] | None = None,
            record: Sequence[str] | None = None, progress: Callable[[float], None] | None = None,
            timing: dict | None = None, sink: ResultFile | None = None, **settings) -> Result:
        """Run the scenario once as Model Exchange; the arguments and errors are those of master.simulate."""
        options = options_of(options, **{"interface_type": "ModelExchange", **settings})
        return self.run_experiment(options, experiment(self.scenario, options), start_values=start_values,
                                   record=record, progress=progress, timing=timing, sink=sink)

    def run_experiment(self, options: RunOptions, planned: Experiment,
                       start_values: dict[str, str | float] | None = None, record: Sequence[str] | None = None,
                       progress: Callable[[float], None] | None = None, timing: dict | None = None,
                       sink: ResultFile | None = None) -> Result:
        parameters = binding.parameter_values(self.scenario, self.instances, start_values or {})
        name = options.solver or DEFAULT_SOLVER
        self._timed = timing is not None                 # the clocks of the breakdown (ode.System's timed)
        tic = time.perf_counter()
        limit = options.max_steps
        if options.tolerance is None:
            rtol = DEFAULT_TOLERANCE if options.rtol is None else options.rtol
            result, system = self._solve(parameters, planned, record, name, rtol, progress, options.solver_steps, sink,
                                         limit)
            systems = [system]
        else:
            result, systems = self._controlled(parameters, planned, record, name, options.tolerance, progress,
                                               options.solver_steps, sink, limit)
        if timing is not None:
            statistics = result.model_exchange
            total = time.perf_counter() - tic
            fmu = sum(s.fmu_time + sum(t.elapsed for t in transfers(s.plan)) for s in systems)
            engine = sum(s.engine_time for s in systems)
            # fmu: inside the FMUs' calls; engine: this engine's Python around them (right-hand sides,
            # Jacobians, indicators, rows); solver: the rest (scipy's integrator, initialization, resets)
            timing.update(total=total, fmu=fmu, engine=engine - fmu, solver=total - engine, steps=statistics.steps,
                          fmus=len(self.instances), rhs=statistics.rhs, jacobians=statistics.jacobians)
        return result

    def _controlled(self, parameters, planned: Experiment, record, name: str, tolerance: float, progress,
                    solver_steps: bool, sink: ResultFile | None, limit: float) -> tuple[Result, list[System]]:
        """The solves of a run with a tolerance (class docstring)."""
        rtol_a = self.FIRST * tolerance
        rtol_b = rtol_a / 10
        with _Tape() as tape:
            _, system_a = self._solve(parameters, planned, record, name, rtol_a, None, False, sink, limit, tape.write)
            difference = _Difference(tape)
            b, system_b = self._solve(parameters, planned, record, name, rtol_b, progress, False, sink, limit,
                                      difference.add)
            estimate = difference.value() / (self.RATIO - 1)
        systems = [system_a, system_b]
        result = b
        if estimate > self.AIM * tolerance or solver_steps:
            rtol_c = min(rtol_b * self.AIM * tolerance / max(estimate, 1e-300), rtol_a)
            if rtol_c < MIN_RTOL:
                self._account(b, systems, tolerance, estimate)
                raise RunLimit("Model Exchange: {tolerance} {tolerance_:g} cannot be kept: the solves at rtol "
                               "{rtol_a:g} and {rtol_b:g} estimate the second's error at {estimate:.2g}, and keeping "
                               "{tolerance} would take rtol {rtol_c:.2g}, below the solvers' smallest ({floor:g}); "
                               "give a larger {tolerance}", "tolerance", tolerance_=tolerance, rtol_a=rtol_a,
                               rtol_b=rtol_b, estimate=estimate, rtol_c=rtol_c, floor=MIN_RTOL, result=b)
            result, system_c = self._solve(parameters, planned, record, name, rtol_c, progress, solver_steps, sink,
                                           limit)
            systems.append(system_c)
            estimate *= rtol_c / rtol_b
        self._account(result, systems, tolerance, estimate)
        if estimate > tolerance:                                 # (proportionality makes it AIM tolerance)
            raise RunLimit("Model Exchange: {tolerance} {tolerance_:g} was not kept: estimated error {estimate:.2g}; "
                           "give a larger {tolerance}", "tolerance", tolerance_=tolerance, estimate=estimate,
                           result=result)
        return result, systems

    @staticmethod
    def _account(result: Result, systems: list[System], tolerance: float, estimate: float) -> None:
        """The result's statistics: the tolerance, the estimate, and the cost of every solve."""
        statistics = result.model_exchange
        statistics.tolerance, statistics.estimated_error = tolerance, estimate
        statistics.solves = len(systems)
        for s in systems:
            if s.statistics is not statistics:
                for field_ in ("steps", "rhs", "jacobians", "events"):
                    setattr(statistics, field_, getattr(statistics, field_) + getattr(s.statistics, field_))

    def _solve(self, parameters, planned: Experiment, record, name: str, rtol: float, progress,
               solver_steps: bool, sink: ResultFile | None, limit: float,
               tap: Callable[[list[float]], None] | None = None) -> tuple[Result, System]:
        """One solve at rtol from a freshly reset set of FMUs, its rows to the sink (replacing any there) and
        each to `tap`; a solve of more than `limit` steps ends with RunLimit."""
        if self.runs > 0:
            self._reset()
        self.runs += 1
        key = None if record is None else tuple(record)
        if key not in self._plans:
            self._plans[key] = make_plan(self.scenario, self.instances, self.connections, record)
        plan = self._plans[key]
        for transfer in transfers(plan):
            transfer.elapsed = 0.0
        system = System(self.scenario, self.instances, self.connections, plan, timed=self._timed)
        if sink is not None:
            sink.rewind()
        notes = binding.model_differences(self.scenario, self.instances, parameters)
        result = Result(plan.columns, sink=sink, notes=notes) if tap is None else _Tapped(plan.columns, sink, tap, notes)
        system.statistics = Statistics(name, rtol, exact_jacobian=system.jacobian_plan is not None)
        result.model_exchange = system.statistics
        try:
            next_event = initialize(system, parameters, planned, rtol)
            result.warnings += [f"{n}: {' '.join(m.split())[len('[warning] '):]}" for n, inst in self.instances.items()
                                for m in inst.messages if m.startswith("[warning]")]
            with _event_reason(system):
                _integrate(system, result, planned, SOLVERS[name], rtol, progress, solver_steps, next_event, limit)
        except ScenarioError as exc:
            signum = stopping.requested()
            if signum is not None and not isinstance(exc, Interrupted):
                # a stop was asked for, and an FMU call failed before the next check: a second signal raised
                # inside the FMU (a Python FMU turns it into its own error); the run was stopped, not failed
                raise Interrupted(signum, result) from exc
            if isinstance(exc, SimulationError):
                exc.result = result
            raise
        return result, system


class _Tapped(Result):
    """A Result that also hands each row (time first) to `tap`."""

    def __init__(self, columns: list[str], sink: ResultFile | None, tap: Callable[[list[float]], None],
                 notes: list[str] | None = None):
        super().__init__(columns, sink=sink, notes=notes)
        self.tap = tap

    def append(self, t: float, values: list) -> None:
        super().append(t, values)
        self.tap([t, *values])


class _Tape:
    """The rows of one solve as doubles in an anonymous temporary file (gone with the process, even after
    kill -9), read back in order: a run with a tolerance holds no solve's rows in memory (8 bytes per value
    on the disk of $TMPDIR instead). A file that cannot be written (a full disk) ends the run with a
    SimulationError saying so."""

    def __init__(self) -> None:
        self.rows, self.width = 0, 0
        try:
            self.file = tempfile.TemporaryFile()
        except OSError as exc:
            raise self._failure(exc) from None

    @staticmethod
    def _failure(exc: OSError) -> SimulationError:
        return SimulationError(f"Model Exchange: cannot keep the first solve's rows for the error estimate in a "
                               f"temporary file in {tempfile.gettempdir()}: {exc.strerror or exc}")

    def write(self, row: list[float]) -> None:
        self.width = len(row)
        try:
            self.file.write(np.asarray(row, dtype=float).tobytes())
        except OSError as exc:
            raise self._failure(exc) from None
        self.rows += 1

    def rewind(self) -> None:
        try:
            self.file.seek(0)                      # flushes the buffered rows
        except OSError as exc:
            raise self._failure(exc) from None

    def read(self) -> np.ndarray | None:
        """The next row, or None after the last."""
        data = self.file.read(8 * self.width)
        return np.frombuffer(data, dtype=float) if self.width and len(data) == 8 * self.width else None

    def __enter__(self) -> "_Tape":
        return self

    def __exit__(self, *exc) -> None:
        self.file.close()


class _Difference:
    """max over the recorded variables of max_t |a - b| / max_t |b|, for two solves on one grid: a's rows
    from its tape, b's as its solve records them (`add`)."""

    def __init__(self, tape: _Tape):
        self.tape = tape
        tape.rewind()
        self.rows = 0
        self.largest: np.ndarray | None = None        # max_t |a - b| of each variable
        self.scale: np.ndarray | None = None          # max_t |b|

    def add(self, row: list[float]) -> None:
        a, b = self.tape.read(), np.asarray(row, dtype=float)
        if a is None or a.shape != b.shape or a[0] != b[0]:
            raise SimulationError(f"Model Exchange: two solves recorded different grids (at t = {b[0]:.9g} s)")
        if self.largest is None or self.scale is None:
            self.largest, self.scale = np.zeros(b.size - 1), np.zeros(b.size - 1)
        np.maximum(self.largest, np.abs(a[1:] - b[1:]), out=self.largest)
        np.maximum(self.scale, np.abs(b[1:]), out=self.scale)
        self.rows += 1

    def value(self) -> float:
        if self.rows != self.tape.rows:
            raise SimulationError("Model Exchange: two solves recorded different grids")
        if self.largest is None or self.scale is None:
            return 0.0
        with np.errstate(invalid="ignore", divide="ignore"):
            rel = np.where(self.scale > 0, self.largest / self.scale, 0.0)
        return float(np.max(rel, initial=0.0))


def initialize(system: System, parameters, planned: Experiment, rtol: float) -> float | None:
    """Set up, set the parameters, propagate the outputs in initialization mode, leave it, settle the
    initial event, enter continuous-time mode (FMI 2.0, section 3.2.3). Returns the first time event (the
    initial event's nextEventTime) or None."""
    for unit in system.units:
        inst = unit.inst
        fmu = inst.fmu
        try:
            fmu.setupExperiment(tolerance=rtol, startTime=planned.start_time, stopTime=planned.stop_time)
            for var, value in parameters[inst.name]:
                setter = {"Real": fmu.setReal, "Integer": fmu.setInteger,
                          "Boolean": fmu.setBoolean, "String": fmu.setString}[var.type]
                setter([var.valueReference], [value.encode() if var.type == "String" else value])
            fmu.enterInitializationMode()
        except FMICallException as exc:
            raise ScenarioError(f"{inst.path.name}: component '{inst.name}' refused {exc.function} "
                                f"during initialization{last_message(inst)}") from None
    system.time = planned.start_time
    try:
        system.resolve(planned.start_time)
        for unit in system.units:
            try:
                unit.inst.fmu.exitInitializationMode()
            except FMICallException as exc:
                raise ScenarioError(f"{unit.inst.path.name}: component '{unit.inst.name}' failed in {exc.function}"
                                    f"{last_message(unit.inst)}") from None
        _, next_event = system.discrete_states(planned.start_time)
        for unit in system.units:
            system.call(unit, "fmi2EnterContinuousTimeMode")
    except SimulationError as exc:
        raise ScenarioError(f"initialization: {exc}") from None
    system.scale = system.nominals()
    return next_event


class _Grid:
    """The recording grid t0 + k h (k < n), then t_stop (k = n): computed point by point, never held."""

    def __init__(self, t0: float, t_stop: float, h: float):
        self.t0, self.t_stop, self.h = t0, t_stop, h
        self.n = max(1, math.ceil((t_stop - t0) / h - 1e-9))
        self.size = self.n + 1

    def __getitem__(self, k: int) -> float:
        return self.t0 + k * self.h if k < self.n else self.t_stop

    def before(self, k: int, t_end: float, most: int) -> list[float]:
        """The grid points from the k-th on that lie before t_end, at most `most` of them (__getitem__'s
        doubles; a step holds a few: Python's floats cost less than numpy's arrays here)."""
        times: list[float] = []
        end = min(self.size, k + most)
        while k < end:
            t = self.t0 + k * self.h if k < self.n else self.t_stop
            if not t < t_end:
                break
            times.append(t)
            k += 1
        return times


def _integrate(system: System, result: Result, planned: Experiment, solver_class, rtol: float,
               progress, solver_steps: bool, next_event: float | None = None, limit: float = MAX_STEPS) -> None:
    t0, t_stop, h = planned.start_time, planned.stop_time, planned.step_size
    grid = _Grid(t0, t_stop, h)
    n_rows = grid.n
    t = t0
    xi = system.states() / system.scale
    system.set_point(t, xi, record=True)
    result.append(t, system.row())
    k = 1                                                       # the next grid point to record
    stalled = 0                                                 # state events in a row at one time
    jac = system.jacobian if system.jacobian_plan is not None else None
    z = system.indicators(t, xi) if system.with_indicators else None
    above = None if z is None else (z > 0).tolist()
    every = max(1, n_rows // 200)
    still = 0                                                   # solver steps in a row that left time where it was
    while t < t_stop:
        bound = t_stop if next_event is None else min(t_stop, next_event)
        solver = solver_class(system.rhs, t, xi, bound, rtol=rtol, atol=rtol, jac=jac)
        restart = False
        while solver.status == "running" and not restart:
            message = solver.step()
            if solver.status == "failed":
                raise SimulationError(f"Model Exchange: {system.statistics.solver} failed at t = {solver.t:.9g} s: "
                                      f"{message}{system.discarded}")
            system.statistics.steps += 1
            if system.statistics.steps > limit:
                raise RunLimit("Model Exchange: {solver} at rtol {rtol:g} took more than {limit:.3g} steps and reached "
                               "t = {t:.9g} s of {t_stop:g} s; give a larger {max_steps} to let it go on", "max_steps",
                               solver=system.statistics.solver, rtol=rtol, limit=limit, t=solver.t, t_stop=t_stop)
            stopping.check()                                    # besides every evaluation (ode.System.set_point)
            t_new, x_new = solver.t, solver.y
            still = still + 1 if not t_new > t else 0
            if still > MAX_STALLED_STEPS:
                raise SimulationError(f"Model Exchange: {system.statistics.solver} is stuck at t = {t:.9g} s: "
                                      f"{still} steps in a row did not move time on (the last of "
                                      f"{float(solver.step_size or 0.0):.3g} s)")
            event_at = None
            if z is not None:
                z_new = system.indicators(t_new, x_new)
                # a change of domain, z > 0 or z <= 0 (FMI 2.0 section 3.1); an indicator at exactly 0 where
                # the step starts (an FMU resets a state to its boundary at an event: a ball at h = 0) takes
                # its domain from where it goes, so leaving 0 is no event. (The domains compared as lists
                # first: numpy's operations on a few indicators cost more than the rest of the step's check.)
                above_new = [v > 0 for v in z_new.tolist()]
                if above_new != above:
                    crossed = np.flatnonzero(((z_new > 0) != (z > 0)) & (z != 0))
                    if crossed.size:
                        dense = solver.dense_output()
                        event_at = min(_locate(system, dense, solver.t_old, t_new, int(i)) for i in crossed)
                z, above = z_new, above_new
            if event_at is None and system.completed_step(t_new, x_new):
                event_at = t_new
            if event_at is not None:
                stalled = stalled + 1 if event_at <= t + options_.TIME_RESOLUTION * max(1.0, abs(t)) else 0
                if stalled > MAX_EVENT_ITERATIONS:
                    raise SimulationError(f"Model Exchange: the events at t = {t:.9g} s do not end: {stalled} events "
                                          "in a row without the time moving on (an event indicator that its FMU's "
                                          "event does not move out of its domain)")
                dense = solver.dense_output()
                x_event = dense(event_at) if event_at < t_new else x_new
                k = _record(system, result, lambda: dense, grid, k, event_at, solver_steps, x_event, before_event=True)
                system.set_point(event_at, x_event)
                system.statistics.events += 1
                changed, next_event = system.event(event_at)
                t = event_at
                xi = system.states() / system.scale if changed else x_event
                z = system.indicators(t, xi) if system.with_indicators else None
                above = None if z is None else (z > 0).tolist()
                restart = True
                continue
            time_event = next_event is not None and t_new >= next_event
            k = _record(system, result, solver.dense_output, grid, k, t_new, solver_steps, x_new, time_event)
            t, xi = t_new, x_new
            if progress is not None and system.statistics.steps % every == 0:
                progress((t - t0) / (t_stop - t0))
        if not restart and next_event is not None and t >= next_event:
            system.set_point(t, xi)
            system.statistics.events += 1
            changed, next_event = system.event(t)
            if changed:
                xi = system.states() / system.scale
    if not solver_steps and k < grid.size:                      # the stop time's row, after an event there
        system.set_point(t, xi, record=True)
        result.append(t, system.row())
    if progress is not None:
        progress(1.0)


@contextlib.contextmanager
def _event_reason(system: System):
    """An FMU without event indicators failing at a point where one with indicators has its event (a
    controller evaluated on the plant's domain boundary, where its law is not defined: Radau's stages land
    there before the step's indicators are compared) ends the run with that FMU's reason, if it gives one."""
    try:
        yield
    except SimulationError as exc:
        if type(exc) is not SimulationError:                   # Ctrl-C, SIGTERM: not the FMUs' doing
            raise
        reason = system.event_reason()
        if reason is None:
            raise
        raise SimulationError(f"{reason} (before it: {exc})") from None


def _locate(system: System, dense, t_a: float, t_b: float, i: int) -> float:
    """The time of indicator i's change of domain (z > 0 or z <= 0) in (t_a, t_b] on the dense output: a
    time at which the indicator is in its new domain, within xtol of the zero, so that the FMUs see the
    event's condition there (a ball at h = +1e-14 has not reached the floor, and would not bounce)."""
    def g(tt):
        return system.indicators(tt, dense(tt))[i]
    old = g(t_a) > 0
    if (g(t_b) > 0) == old:
        return t_b
    xtol = options_.TIME_RESOLUTION * max(1.0, abs(t_b))
    t = brentq(g, t_a, t_b, xtol=xtol, rtol=4 * np.finfo(float).eps)
    step = xtol
    while t < t_b and (g(t) > 0) == old:                 # brentq's zero may lie on the old side
        t, step = min(t_b, t + step), 2 * step
    return t


def _record(system: System, result: Result, dense_output: Callable[[], Any], grid: _Grid, k: int, t_end: float,
            solver_steps: bool, x_end: np.ndarray, before_event: bool = False) -> int:
    """The rows up to t_end: the grid points (from the dense output, `dense_output()`, made only where a
    grid point falls inside the step), or the step's end (solver_steps). before_event: an event follows at
    t_end, so a grid point at t_end waits for the values after it (as a Co-Simulation step to t_end gives
    them, and fmpy records them)."""
    if not system.timed:
        return _rows(system, result, dense_output, grid, k, t_end, solver_steps, x_end, before_event)
    tic = time.perf_counter()
    try:
        return _rows(system, result, dense_output, grid, k, t_end, solver_steps, x_end, before_event)
    finally:
        system.engine_time += time.perf_counter() - tic


def _rows(system: System, result: Result, dense_output: Callable[[], Any], grid: _Grid, k: int, t_end: float,
          solver_steps: bool, x_end: np.ndarray, before_event: bool) -> int:
    if solver_steps:
        system.set_point(t_end, x_end, record=True)
        result.append(t_end, system.row())
        return k
    dense = None
    while k < grid.size and grid[k] < t_end:
        # the grid points inside the step, up to CHUNK of them interpolated in one call of the dense output
        # (scipy's cost is per call: 3-7 us, as much as the FMUs' calls of a row)
        times = grid.before(k, t_end, CHUNK)
        dense = dense_output() if dense is None else dense
        system.rows(times, dense(np.array(times)), result.append)
        k += len(times)
    if k < grid.size and grid[k] == t_end and not before_event:
        system.set_point(t_end, x_end, record=True)
        result.append(t_end, system.row())
        k += 1
    return k
