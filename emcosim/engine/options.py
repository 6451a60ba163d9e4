"""The settings of a run, checked in one place: `RunOptions` (what a caller asks for) and `experiment`
(the horizon and steps of one scenario with them). The Python API (`master.simulate`, `Simulation.run`),
the sweep and the command line's run, sweep and export all pass through here, so a setting is refused
the same way everywhere, before any FMU is loaded.
"""
from __future__ import annotations

import math
import numbers
from dataclasses import dataclass, replace

from .errors import LimitError, OptionError

MAX_STEPS = 10**8          # more communication steps must be confirmed (max_steps)
MAX_COUPLING_ORDER = 3     # the highest derivative order the master passes on a connection
COUPLINGS = ("explicit", "implicit")
INTERFACE_TYPES = ("CoSimulation", "ModelExchange")     # fmpy's spelling (fmpy simulate --interface-type)
SOLVERS = ("LSODA", "BDF", "Radau")                      # scipy's, for Model Exchange runs
# the smallest solver rtol of a Model Exchange run (its atol is rtol times each state's nominal): scipy's
# solvers raise an rtol below 100 eps (2.2e-14) to that but keep the atol, and at atol 1e-300 they never
# leave the start time (issue 31)
MIN_RTOL = 1e-13
ME_SOLVES = 100            # a Model Exchange run with a tolerance solves down to tolerance / ME_SOLVES
# the engine's resolution of time [s] at |t| <= 1 s (relative beyond): events are located to it and two events
# closer than it are one (model_exchange.py). A run spans at least this (`min_horizon`, issue 40): below it the
# solvers' step powers underflow (LSODA at a horizon of 1e-160 s steps with h = 0 for ever, implicit coupling
# divides by h * h = 0 at 1e-200 s)
TIME_RESOLUTION = 1e-12


@dataclass(frozen=True)
class RunOptions:
    """What a run is asked to do (None: the scenario's choice).

    stop_time, step_size     the horizon [s] and the communication step [s] (the first step with a tolerance)
    tolerance                relative error the recorded variables keep (error-controlled steps; Model
                             Exchange: the solver's rtol)
    max_step                 the largest step [s] a tolerance may choose
    coupling                 "explicit" or "implicit" (Co-Simulation)
    coupling_order           derivatives passed on the connections, 0..MAX_COUPLING_ORDER (explicit coupling)
    max_steps                refuse a run of more communication steps (a step of 1e-15 s would run for years);
                             a Model Exchange run: more rows on its grid, and more steps of any of its solves
    interface_type           "CoSimulation" (the master steps the FMUs) or "ModelExchange" (one ODE of all
                             the FMUs' states, integrated by scipy)
    rtol                     a Model Exchange run: one solve at the solver's relative tolerance rtol (default 1e-6,
                             at least MIN_RTOL;
                             with a tolerance instead, the solves keep that global error: model_exchange.py)
    solver                   the scipy solver of a Model Exchange run (default LSODA)
    solver_steps             a Model Exchange run records a row at every step its solver takes (default: on
                             the grid t0 + n step_size)
    """

    stop_time: float | None = None
    step_size: float | None = None
    tolerance: float | None = None
    max_step: float | None = None
    coupling: str | None = None
    coupling_order: int | None = None
    max_steps: float = MAX_STEPS
    interface_type: str = "CoSimulation"
    rtol: float | None = None
    solver: str | None = None
    solver_steps: bool = False

    def __post_init__(self) -> None:
        for name, kind in _NUMBERS.items():
            value = getattr(self, name)
            if _real(value) and (kind is float or isinstance(value, numbers.Integral)):
                object.__setattr__(self, name, kind(value))     # numpy's floats and ints as Python's (issue 40)
        check(self)

    @property
    def model_exchange(self) -> bool:
        return self.interface_type == "ModelExchange"


def options_of(options: RunOptions | None = None, **settings) -> RunOptions:
    """The one RunOptions of a run: `options` (default: the scenario's choices) with `settings` (keyword
    shorthands, the same names as RunOptions' fields) in place of its fields, checked again. A name that is no
    field is a TypeError.

    >>> options_of(RunOptions(stop_time=1.0), step_size=1e-3)
    RunOptions(stop_time=1.0, step_size=0.001, tolerance=None, max_step=None, coupling=None, coupling_order=None, \
max_steps=100000000, interface_type='CoSimulation', rtol=None, solver=None, solver_steps=False)
    """
    options = RunOptions() if options is None else options
    if not isinstance(options, RunOptions):
        raise TypeError(f"options must be a RunOptions, not {type(options).__name__}")
    return replace(options, **settings) if settings else options


# the numeric fields and the Python type each is kept as: any real number (numpy's included) but a bool (a
# True is no 1 s) is taken; max_steps stays an int when it is one
_NUMBERS = {"stop_time": float, "step_size": float, "tolerance": float, "max_step": float, "rtol": float,
            "coupling_order": int, "max_steps": int}


def _real(value) -> bool:
    """A real number that is no bool (Python's or numpy's: numbers.Real knows numpy's, and no numpy bool)."""
    return isinstance(value, numbers.Real) and not isinstance(value, bool)


def _shown(value) -> str:
    return f"{value:g}" if isinstance(value, (int, float)) and not isinstance(value, bool) else repr(value)


def _positive(value: float | None, option: str) -> None:
    if value is not None and not (_real(value) and math.isfinite(value) and value > 0):
        raise OptionError("{%s} {value}: must be a positive number" % option, option, value=_shown(value))


def check(options: RunOptions) -> None:
    """An OptionError for settings that cannot make a run, whatever the scenario."""
    if options.stop_time is not None and not (_real(options.stop_time) and math.isfinite(options.stop_time)):
        raise OptionError("{stop_time} {value}: must be a finite number (seconds)", "stop_time",
                          value=_shown(options.stop_time))
    _positive(options.step_size, "step_size")
    _positive(options.max_step, "max_step")
    if options.tolerance is not None and not (_real(options.tolerance)
                                              and math.isfinite(options.tolerance) and 0 < options.tolerance < 1):
        raise OptionError("{tolerance} {value}: must be a number between 0 and 1 (a relative error)", "tolerance",
                          value=_shown(options.tolerance))
    if options.max_step is not None and options.tolerance is None:
        raise OptionError("{max_step} bounds the steps that {tolerance} chooses; without {tolerance} the steps are "
                          "fixed: give {step_size}", "max_step", "tolerance", "step_size")
    if options.coupling is not None and options.coupling not in COUPLINGS:
        raise OptionError("{coupling} {value!r}: must be one of " + ", ".join(COUPLINGS), "coupling",
                          value=options.coupling)
    order = options.coupling_order
    if order is not None and not (isinstance(order, int) and not isinstance(order, bool)
                                  and 0 <= order <= MAX_COUPLING_ORDER):
        raise OptionError("{coupling_order} {value!r}: must be an integer from 0 to %d" % MAX_COUPLING_ORDER,
                          "coupling_order", value=order)
    if options.coupling == "implicit" and order is not None:
        raise OptionError("{coupling_order} {value} sets the derivatives of explicit coupling; {coupling} implicit "
                          "passes none (it sets its inputs' polynomials itself, from the end of each step)",
                          "coupling_order", "coupling", value=order)
    if not (_real(options.max_steps) and options.max_steps > 0):
        raise OptionError("{max_steps} {value}: must be a positive number", "max_steps", value=_shown(options.max_steps))
    if options.interface_type not in INTERFACE_TYPES:
        raise OptionError("{interface_type} {value!r}: must be one of " + ", ".join(INTERFACE_TYPES),
                          "interface_type", value=options.interface_type)
    if options.solver is not None and options.solver not in SOLVERS:
        raise OptionError("{solver} {value!r}: must be one of " + ", ".join(SOLVERS), "solver", value=options.solver)
    if options.solver is not None and not options.model_exchange:
        raise OptionError("{solver} chooses the integrator of a Model Exchange run; give {interface_type} "
                          "ModelExchange, or no solver", "solver", "interface_type")
    if options.rtol is not None:
        if not (_real(options.rtol) and math.isfinite(options.rtol) and 0 < options.rtol < 1):
            raise OptionError("{rtol} {value}: must be a number between 0 and 1", "rtol", value=_shown(options.rtol))
        if options.rtol < MIN_RTOL:
            raise OptionError("{rtol} {value}: below %g, the smallest relative tolerance the solvers resolve in "
                              "double precision (a smaller one never leaves the start time)" % MIN_RTOL, "rtol",
                              value=_shown(options.rtol))
        if not options.model_exchange:
            raise OptionError("{rtol} is the solver's tolerance of a Model Exchange run; give {interface_type} "
                              "ModelExchange (a Co-Simulation run takes {tolerance})", "rtol", "interface_type",
                              "tolerance")
        if options.tolerance is not None:
            raise OptionError("{rtol} (one solve at that solver tolerance) and {tolerance} (solves that keep that "
                              "global error) exclude each other", "rtol", "tolerance")
    if options.solver_steps and not options.model_exchange:
        raise OptionError("{solver_steps}: a Co-Simulation run records at its communication points; give "
                          "{interface_type} ModelExchange", "solver_steps", "interface_type")
    # (1 - 1e-9): 1e-11 itself passes, 100 * 1e-13 rounds to 1.0000000000000001e-11
    if options.model_exchange and options.tolerance is not None and options.tolerance < ME_SOLVES * MIN_RTOL * (1 - 1e-9):
        raise OptionError("{tolerance} {value}: a Model Exchange run cannot keep a global error below %g (its "
                          "solves run at {tolerance}/%d, and the solvers at a relative tolerance of %g or more); give "
                          "a larger {tolerance}" % (ME_SOLVES * MIN_RTOL, ME_SOLVES, MIN_RTOL), "tolerance",
                          value=_shown(options.tolerance))
    if options.model_exchange:
        for name in ("coupling", "coupling_order", "max_step"):
            if getattr(options, name) is not None:
                raise OptionError("{%s} is a setting of Co-Simulation runs; a Model Exchange run (one ODE, "
                                  "{interface_type} ModelExchange) takes {tolerance} and {solver}" % name,
                                  name, "interface_type", "tolerance", "solver")


def min_horizon(t0: float, t_stop: float) -> float:
    """The shortest horizon [s] of a run from t0 to about t_stop: TIME_RESOLUTION, relative to |t| beyond 1 s."""
    return TIME_RESOLUTION * max(1.0, abs(t0), abs(t_stop))


@dataclass(frozen=True)
class Experiment:
    """The horizon and steps of one run of one scenario: start and stop time [s], the communication
    step [s] (the first one with a tolerance), the largest step with a tolerance [s]."""

    start_time: float
    stop_time: float
    step_size: float
    max_step: float | None


def experiment(scenario, options: RunOptions) -> Experiment:
    """The scenario's horizon and steps overridden by `options`; a LimitError / OptionError if they do not
    make a run (or make more than max_steps communication steps)."""
    t0 = scenario.start_time
    t_stop = scenario.stop_time if options.stop_time is None else options.stop_time
    h = scenario.step_size if options.step_size is None else options.step_size
    where = str(scenario.path)
    if t_stop is None or h is None:
        raise OptionError("{where}: no stop time / step size in the scenario (give {stop_time} and {step_size})",
                          "stop_time", "step_size", where=where)
    if not (math.isfinite(t_stop) and t_stop > t0):
        raise OptionError("{where}: {stop_time} {t_stop} must be after the start time {t0}", "stop_time",
                          where=where, t_stop=t_stop, t0=t0)
    least = min_horizon(t0, t_stop)
    if t_stop - t0 < least:
        raise OptionError("{where}: {stop_time} {t_stop:g} s is {span:.3g} s after the start time {t0:g} s; a run "
                          "spans at least {least:.3g} s (the engine's resolution of time: %g s, relative to |t| "
                          "beyond 1 s)" % TIME_RESOLUTION, "stop_time", where=where, t_stop=t_stop, span=t_stop - t0,
                          t0=t0, least=least)
    if not (math.isfinite(h) and h > 0):
        raise OptionError("{where}: {step_size} {h} must be positive", "step_size", where=where, h=h)
    max_step = None
    if options.tolerance is not None and not options.model_exchange:
        max_step = (t_stop - t0) / 50 if options.max_step is None else options.max_step
    steps = (t_stop - t0) / h
    if not math.isfinite(steps):
        raise OptionError("{where}: stop time {t_stop:g} s with step size {h:g} s: too many communication steps to "
                          "count", "stop_time", where=where, t_stop=t_stop, h=h)
    edge = max(abs(t0), abs(t_stop))
    if h < 4 * math.ulp(edge):
        raise OptionError("{where}: step size {h:g} s is below the resolution of time near t = {edge:g} s (double "
                          "precision: {ulp:.3g} s)", "step_size", where=where, h=h, edge=edge, ulp=math.ulp(edge))
    # a Model Exchange run records a row at each grid point t0 + n h (with solver_steps: at each solver step,
    # counted as it runs: model_exchange.py)
    if steps > options.max_steps and not (options.model_exchange and options.solver_steps):
        raise LimitError("{where}: stop time {t_stop:g} s with step size {h:g} s makes {steps:.3g} {what}, more "
                         "than the limit of {limit:.3g}; give {max_steps} {needed} to run it anyway",
                         "max_steps", where=where, t_stop=t_stop, h=h, steps=steps, limit=options.max_steps,
                         needed=math.ceil(steps), what="recorded rows (communication points)" if options.model_exchange
                         else "communication steps")
    return Experiment(t0, t_stop, h, max_step)
