"""Run a scenario in an independent engine: the Open Simulation Platform's libcosim (libcosimpy).

libcosim reads the same .ssd/.ssv files itself (its own SSP parser), instantiates the FMUs with
FMI Library and steps them with its fixed-step algorithm. That algorithm is Jacobi-style: all
FMUs step from t_n with the inputs transferred at t_n, and outputs are transferred only after the
step. A direct-feedthrough controller's output at t_n therefore reaches the plant one step late
(the plant integrates [t_n, t_n+1] with u(t_{n-1})), where our master resolves it at t_n.
The libcosim trajectory then differs from ours by O(h), which the cross-check test bounds.

libcosim calls the FMUs from its own worker threads. That does not harm this suite's FMUs: libcosim
run in this process (`_simulate`, maglev_tracking_D-1_R0.82 over 0.5 s) exited cleanly in 10 of 10
processes, and so did 10 of 10 processes that ran that loop through the master in a thread other
than the main one (2026-12-01; tests/test_libcosim_in_process.py repeats the first). An earlier note
here said such threads corrupt the heap so that glibc aborts the process at exit: that was pythonfmu
0.7.0 freeing its interpreter state at exit (docs/reliability.md, finding 1), which this suite's FMU
loader no longer does. `simulate_libcosim` still runs libcosim in a child process (a fresh
interpreter) and returns its results, for the FMUs that are not ours: one built with stock
pythonfmu still aborts its host at exit now and then (emcosim.cli.entry gives the measurement), and a
crash in libcosim's or an FMU's native code then ends the child, not the caller.
"""
from __future__ import annotations

import math
import tempfile
from pathlib import Path

from .errors import ScenarioError
from .results import Result
from .ssd import Scenario
from .ssp import pack_ssp

NS_PER_S = 1_000_000_000


def simulate_libcosim(scenario: Scenario, stop_time: float | None = None, step_size: float | None = None,
                      start_values: dict[str, float] | None = None, record: list[str] | None = None) -> Result:
    """Run `scenario` with a fixed step in libcosim, which reads the .ssd/.ssv files itself (packed
    into a temporary .ssp with the FMUs the scenario resolved); record `record` (default: every
    output connector) at every communication point. libcosim runs in a child process (see the module
    docstring for why)."""
    import multiprocessing
    from concurrent.futures import ProcessPoolExecutor
    from concurrent.futures.process import BrokenProcessPool

    step_size = scenario.hold_step(step_size, "libcosim")
    context = multiprocessing.get_context("spawn")
    try:
        with ProcessPoolExecutor(1, mp_context=context) as pool:
            columns, rows = pool.submit(_simulate_here, scenario, stop_time, step_size, start_values, record).result()
    except BrokenProcessPool as exc:
        raise ScenarioError(f"libcosim: the process running {scenario.name} died ({exc})") from None
    result = Result(columns)
    result.rows = rows
    return result


def _simulate_here(scenario, stop_time, step_size, start_values, record) -> tuple[list[str], list[list[float]]]:
    """simulate_libcosim in this process: (columns, rows)."""
    result = _simulate(scenario, stop_time, step_size, start_values, record)
    return result.columns, result.rows


def _simulate(scenario: Scenario, stop_time, step_size, start_values, record) -> Result:
    try:
        from libcosimpy.CosimExecution import CosimExecution
        from libcosimpy.CosimLogging import CosimLogLevel, log_output_level
    except ImportError:
        raise ScenarioError("libcosim is not installed (pip install libcosimpy)") from None
    log_output_level(CosimLogLevel.ERROR)
    t_stop = scenario.stop_time if stop_time is None else stop_time
    h = scenario.hold_step(step_size, "libcosim")
    h_ns = int(round(h * NS_PER_S))
    if abs(h_ns - h * NS_PER_S) > 1e-6 * h * NS_PER_S:
        raise ScenarioError(f"step {h} s is not a whole number of nanoseconds (libcosim's time unit)")
    n_steps = math.ceil((t_stop - scenario.start_time) / h - 1e-9)
    with tempfile.TemporaryDirectory(prefix="emcosim-libcosim-") as tmp:
        archive = pack_ssp(scenario, Path(tmp) / f"{scenario.name}.ssp")    # the FMUs the scenario resolved
        try:
            ex = CosimExecution.from_ssp_file(str(archive), step_size=h_ns)
        except AssertionError:
            raise ScenarioError(f"libcosim could not load {scenario.path}: {_last_error()}") from None
        return _run(ex, scenario, t_stop, n_steps, start_values, record)


def _last_error() -> str:
    try:
        from libcosimpy._internal import get_last_error_message
        return " ".join(str(get_last_error_message()).split())
    except Exception:
        return "no message"


def _run(ex, scenario, t_stop, n_steps, start_values, record) -> Result:
    from libcosimpy.CosimEnums import CosimVariableType
    from libcosimpy.CosimObserver import CosimObserver

    index = {info.name.decode(): info.index for info in ex.slave_infos()}
    refs = {name: {v.name.decode(): v.reference for v in ex.slave_variables(i)} for name, i in index.items()}
    for full, value in (start_values or {}).items():
        comp, _, var = full.partition(".")
        if comp not in refs or var not in refs[comp]:
            raise ScenarioError(f"libcosim: unknown variable '{full}'")
        ex.real_initial_value(index[comp], refs[comp][var], float(value))
    if record is None:
        record = [f"{c.name}.{k.name}" for c in scenario.components for k in c.connectors if k.kind == "output"]
    series = CosimObserver.create_time_series(buffer_size=n_steps + 2)
    ex.add_observer(series)
    for full in record:
        comp, _, var = full.partition(".")
        if comp not in refs or var not in refs[comp]:
            raise ScenarioError(f"libcosim: cannot record unknown variable '{full}'")
        series.start_time_series(index[comp], refs[comp][var], CosimVariableType.REAL)
    if not ex.simulate_until(int(round(t_stop * NS_PER_S))):
        raise ScenarioError(f"libcosim: the simulation of {scenario.name} failed: {_last_error()}")
    result = Result(record)
    columns = [_samples(series, index[c], refs[c][v]) for c, _, v in (f.partition(".") for f in record)]
    n = min(len(col) for col in columns)
    for i in range(n):
        result.append(columns[0][i][0], [col[i][1] for col in columns])
    return result


def _samples(series, slave: int, ref: int) -> list[tuple[float, float]]:
    """(time, value) of every step. libcosimpy trims its sample arrays by counting step numbers
    equal to 0, which also drops a valid sample when step 0 is included; so step 0 is read alone
    (as the first of two) and steps 1.. separately."""
    first = series.time_series_real_samples(slave, ref, 0, 2)
    out = [(t / NS_PER_S, v) for t, v in zip(first[0][:1], first[2][:1])]
    count = 1 << 20
    step = 1
    while True:
        times, steps, values = series.time_series_real_samples(slave, ref, step, count)
        out += [(t / NS_PER_S, v) for t, v in zip(times, values)]
        if len(times) < count:
            return out
        step += count
