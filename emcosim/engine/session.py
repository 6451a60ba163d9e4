"""A reusable co-simulation of one scenario for worker threads: `master.Simulation` (load the FMUs once,
run many times, fmi2Reset between runs) with the FMUs instantiated on the process's main thread.

`emcosim.engine.master.simulate` unpacks and instantiates every FMU for each run (about 20 ms per FMU on the
project's machine, so about 60 ms for a plant + controller + reference loop) and frees them at the
end. A parameter sweep runs the same scenario hundreds of times in the same worker process, so a
`Session` keeps the unpacked FMUs and their instances and, between runs, only calls fmi2Reset, which
returns every FMU to its freshly instantiated state (pythonfmu 0.7.0 re-creates the Python slave
object). Each run goes through the master's own initialization and stepping code, so a run in a
session gives the same numbers as `simulate` with the same settings; the sweep
tests check this bit for bit.
"""
from __future__ import annotations

import concurrent.futures
import threading
from typing import Callable, Sequence, TypeVar

from . import binding, master
from .options import RunOptions, options_of
from .results import Result
from .ssd import Scenario

T = TypeVar("T")


class Session:
    """One scenario's FMUs, instantiated once in this process (on its main thread) and reset between
    runs (a master.Simulation, or a model_exchange.ModelExchangeSimulation). Not thread-safe: use one session
    per thread (the sweep keeps one per worker thread)."""

    def __init__(self, scenario: Scenario, model_exchange: bool = False):
        from .model_exchange import ModelExchangeSimulation

        kind = ModelExchangeSimulation if model_exchange else master.Simulation
        self.simulation: master.Simulation | ModelExchangeSimulation = kind(scenario, call=on_main_thread)

    def run(self, start_values: dict[str, str | float] | None = None, options: RunOptions | None = None,
            record: Sequence[str] | None = None, **settings) -> Result:
        """Run the scenario once, like `master.simulate` with the same options (`settings`: shorthands for
        RunOptions' fields); raises the same ScenarioError / SimulationError. A session made with
        model_exchange=True runs its FMUs as Model Exchange."""
        return self.simulation.run(options_of(options, **settings), start_values=start_values, record=record)

    def close(self) -> None:
        self.simulation.close()

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
    instances = binding.load(scenario)
    binding.parameter_values(scenario, instances, start_values)


__all__ = ["Session", "check_start_values", "on_main_thread"]
