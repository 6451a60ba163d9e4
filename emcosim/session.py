"""A reusable co-simulation of one scenario: load the FMUs once, run many times (fmi2Reset between runs).

`emcosim.master.simulate` unpacks and instantiates every FMU for each run (about 20 ms per FMU on the
project's machine, so about 60 ms for a plant + controller + reference loop) and frees them at the
end. A parameter sweep runs the same scenario hundreds of times in the same worker process, so a
`Session` keeps the unpacked FMUs and their instances and, between runs, only calls fmi2Reset, which
returns every FMU to its freshly instantiated state (pythonfmu 0.7.0 re-creates the Python slave
object). Each run then goes through the master's own initialization and stepping code, so a run in a
session gives the same numbers as `simulate` (and `emcosim run`) with the same settings; the sweep
tests check this bit for bit.

The session uses the master's internal building blocks (`load`, `parameter_values`, `_instantiate`,
`_plan`, `_Stepper`, `_initialize`, `_run_fixed`). If a future master no longer offers them, the
session falls back to calling `simulate` for every run (correct, only slower): see `REUSE`.
"""
from __future__ import annotations

import concurrent.futures
import shutil
import threading
from typing import Callable, Sequence, TypeVar

from . import master
from .results import Result
from .ssd import Scenario

T = TypeVar("T")

_NEEDED = ("load", "check_connections", "parameter_values", "_instantiate", "_free", "_plan",
           "_n_slots", "_Stepper", "_initialize", "_run_fixed")
REUSE = all(hasattr(master, name) for name in _NEEDED)
"""True when instances can be reused; False means every run falls back to `master.simulate`."""


class Session:
    """One scenario's FMUs, instantiated once in this process and reset between runs.

    Not thread-safe: use one session per thread (the sweep keeps one per worker thread).
    """

    def __init__(self, scenario: Scenario):
        self.scenario = scenario
        self.runs = 0                         # runs made with these instances
        self.instantiations = 0               # how often the FMUs were instantiated (1 unless a reset failed)
        self._workdirs: list[str] = []
        self._plans: dict = {}
        self.instances = None
        if REUSE:
            self.instances = master.load(scenario)
            self.connections = master.check_connections(scenario, self.instances)
            self._instantiate()

    def _instantiate(self) -> None:
        def instantiate_all() -> None:
            for inst in self.instances.values():
                master._instantiate(inst, self._workdirs)
        on_main_thread(instantiate_all)
        self.instantiations += 1
        self._plans.clear()                   # plans hold the instances' C handles
        self.runs = 0

    def _reset(self) -> None:
        """fmi2Reset every FMU; if one refuses (e.g. after a fatal error), instantiate all again."""
        try:
            for inst in self.instances.values():
                inst.slave.reset()
                inst.messages.clear()
        except Exception:                     # noqa: BLE001 - any failure: start from scratch
            for inst in self.instances.values():
                master._free(inst)
                inst.messages.clear()
            self._instantiate()

    def run(self, start_values: dict[str, str | float] | None = None, stop_time: float | None = None,
            step_size: float | None = None, record: Sequence[str] | None = None) -> Result:
        """Run the scenario once (fixed communication step), like `master.simulate` with the same
        arguments; raises the same ScenarioError / SimulationError."""
        if not REUSE:
            return master.simulate(self.scenario, stop_time=stop_time, step_size=step_size,
                                   start_values=start_values, record=record)
        s = self.scenario
        t0 = s.start_time
        t_stop = s.stop_time if stop_time is None else stop_time
        h = s.step_size if step_size is None else step_size
        if t_stop is None or h is None or not (t_stop > t0) or not (h > 0):
            # let the master word the error exactly as `emcosim run` does
            return master.simulate(s, stop_time=stop_time, step_size=step_size, start_values=start_values,
                                   record=record)
        parameters = master.parameter_values(s, self.instances, start_values or {})
        if self.runs > 0:
            self._reset()
        self.runs += 1
        key = None if record is None else tuple(record)
        if key not in self._plans:
            self._plans[key] = master._plan(s, self.instances, self.connections, record)
        plan = self._plans[key]
        result = Result(plan.columns)
        slots = [0.0] * master._n_slots(plan)
        stepper = master._Stepper(s, self.instances, plan, slots)
        master._initialize(s, self.instances, parameters, t0, t_stop, stepper)
        master._run_fixed(stepper, result, t0, t_stop, h, None)
        return result

    def close(self) -> None:
        """Free the FMU instances and delete their unpacked files."""
        if self.instances:
            for inst in self.instances.values():
                master._free(inst)
        for d in self._workdirs:
            shutil.rmtree(d, ignore_errors=True)
        self._workdirs.clear()

    def __enter__(self) -> "Session":
        return self

    def __exit__(self, *exc) -> None:
        self.close()


def on_main_thread(fn: Callable[[], T]) -> T:
    """Call fn on the process's main thread when running in a dask worker thread (the worker's
    event loop runs on the main thread) and return its value; elsewhere just call it.

    Why: a pythonfmu 0.7.0 FMU instantiated in a thread other than the main one makes the process
    abort when it exits ('free(): corrupted unsorted chunks'), even after fmi2FreeInstance; stepping
    and resetting it from another thread afterwards is fine."""
    if threading.current_thread() is threading.main_thread():
        return fn()
    try:
        from distributed import get_worker
        worker = get_worker()
    except (ImportError, ValueError):
        return fn()
    done: concurrent.futures.Future = concurrent.futures.Future()

    def call() -> None:
        try:
            done.set_result(fn())
        except BaseException as exc:                  # noqa: BLE001 - handed to the waiting thread
            done.set_exception(exc)
    worker.loop.add_callback(call)
    return done.result()


def check_start_values(scenario: Scenario, start_values: dict[str, str | float]) -> None:
    """Raise the master's one-line ScenarioError if a start value names an unknown component or
    variable, a variable that cannot be set, or a value of the wrong type (nothing is run)."""
    if not hasattr(master, "parameter_values"):
        return
    instances = master.load(scenario)
    master.parameter_values(scenario, instances, start_values)


__all__ = ["Session", "REUSE", "check_start_values", "on_main_thread"]
