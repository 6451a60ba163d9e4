"""Parameter sweeps of any SSP scenario on Dask: one scenario run over a grid of parameter values (and random
draws of uncertain ones), each run a row of numbers (`emcosim.sweep` from Python, `emcosim sweep` from the command
line). What the numbers are is the caller's: `metrics(scenario, values, result)`, by default the last value of
every recorded variable; the paper's layer passes its report's metrics (emcosim.paper.sweep).

Engine: Dask. By default a local cluster of worker processes on this machine (one per core, one
thread each: each process hosts one pythonfmu interpreter), reachable only by this process: it
listens on 127.0.0.1 with TLS and temporary credentials made for this sweep (dask's
`Security.temporary()`: a self-signed key and certificate that exist only in this process's memory
and its workers'; scheduler and workers require the client to present it), so another local user or
process can neither submit nor run code on it. With `--scheduler tls://HOST:PORT` the runs go to a
running `dask scheduler` and its workers instead, with the cluster's credentials given by
`--tls-ca-file`, `--tls-cert`, `--tls-key` (as for `dask scheduler`; without them, dask's own
configuration, `distributed.comm.tls`, applies). Each worker thread keeps the FMUs of
the scenario loaded and resets them between runs (`emcosim.engine.session`). Workers must see the same
paths as the machine that starts the sweep (scenario, FMUs) and have emcosim installed.

A run that fails (a gain the controller refuses, an FMU error) becomes a row with its error message;
the sweep goes on. Finished rows are appended to the output folder's sweep.csv as they arrive
(`RowStream`), so an interrupted sweep (Ctrl-C, SIGTERM) keeps them.

Bounds: a sweep of more than MAX_RUNS runs is refused before anything runs unless `max_runs` (the
command's --max-runs) allows it; the runs go to the cluster IN_FLIGHT_PER_THREAD per worker thread at
a time, the next one as each finishes (`run_all`), so the client and the scheduler hold a handful of
tasks whatever the grid, and an interruption cancels only those. The local cluster serves no HTTP
(dask starts a dashboard or, without one, its info, JSON and metrics pages on every scheduler and
worker, in plain HTTP to anyone on the machine): `dask_client` gives them no routes and closes their
sockets once the cluster is up.
"""
from __future__ import annotations

import atexit
import itertools
import math
import sys
import threading
import time
from contextlib import contextmanager
from pathlib import Path
from typing import Callable, Iterator, TextIO

import numpy as np

from .engine.doubling import THRESHOLD
from .engine.errors import LimitError, ScenarioError
from .engine.options import RunOptions, experiment, options_of
from .engine.ssd import Scenario, finite_number, read_scenario
from .engine.verdict import NOT_ACCEPTED, judge

Metrics = Callable[[Scenario, dict, object], dict]
"""metrics(scenario, values, result) -> the numbers of a run's row (a function importable on the workers)."""

# ---- the specification of a sweep ----------------------------------------------------------------

MAX_RUNS = 100_000
"""The most runs a sweep makes unless told otherwise (`max_runs`, --max-runs): a typing slip such as
1000 x 1000 is refused before anything runs. The table of a sweep is kept in memory (about 1.5 kB
per run: sweep.md, sweep.json and the plots are written from it), and 10^5 runs of 0.1 s are about
three hours on one core."""

IN_FLIGHT_PER_THREAD = 2
"""Runs submitted to the cluster per worker thread at a time (one running, one waiting): see run_all."""


def parse_grid(spec: str, max_runs: int = MAX_RUNS) -> tuple[str, list[float]]:
    """'component.parameter=START:STOP:N' (N equally spaced values, both ends included) or
    'component.parameter=V1,V2,...' -> (name, values). An N above `max_runs` is refused before the
    values are made."""
    name, values_text = _split(spec, "--grid", "START:STOP:N or V1,V2,...")
    if ":" in values_text:
        parts = values_text.split(":")
        if len(parts) != 3:
            raise ScenarioError(f"--grid {spec}: expected COMPONENT.PARAMETER=START:STOP:N")
        start, stop = (finite_number(p, f"--grid {spec}") for p in parts[:2])
        try:
            n = int(parts[2])
        except ValueError:
            raise ScenarioError(f"--grid {spec}: N = {parts[2]!r} is not a whole number") from None
        if n < 1 or (n == 1 and start != stop):
            raise ScenarioError(f"--grid {spec}: N must be >= 2 (or 1 with START = STOP)")
        check_size(n, f"--grid {spec}", max_runs)
        return name, [float(v) for v in np.linspace(start, stop, n)]
    values = [finite_number(v, f"--grid {spec}") for v in values_text.split(",")]
    return name, values


def parse_sample(spec: str) -> tuple[str, float, float]:
    """'component.parameter=LOW:HIGH' -> (name, low, high): a uniformly distributed parameter."""
    name, values_text = _split(spec, "--sample", "LOW:HIGH")
    parts = values_text.split(":")
    if len(parts) != 2:
        raise ScenarioError(f"--sample {spec}: expected COMPONENT.PARAMETER=LOW:HIGH")
    low, high = (finite_number(p, f"--sample {spec}") for p in parts)
    if not low <= high:
        raise ScenarioError(f"--sample {spec}: LOW must not exceed HIGH")
    return name, low, high


def _split(spec: str, option: str, form: str) -> tuple[str, str]:
    name, sep, values = spec.partition("=")
    name = name.strip()
    comp, dot, var = name.partition(".")
    if not sep or not dot or not comp or not var or not values.strip():
        raise ScenarioError(f"{option} {spec}: expected COMPONENT.PARAMETER={form}")
    return name, values.strip()


def run_count(grid: list[tuple[str, list[float]]], n_samples: int = 0) -> int:
    """How many runs the sweep makes: the product of the grid's axis lengths times the draws."""
    return math.prod(len(values) for _, values in grid) * max(n_samples, 1)


def check_size(runs: int, what: str, max_runs: int = MAX_RUNS) -> None:
    """A LimitError (option max_runs) if `what` makes more than max_runs runs."""
    if runs > max_runs:
        raise LimitError("{what} makes {runs} runs, more than the limit of {limit} runs of a sweep; give {max_runs} "
                         "{runs} to run them anyway", "max_runs", what=what, runs=runs, limit=max_runs)


def points(grid: list[tuple[str, list[float]]], samples: list[tuple[str, float, float]] = (),
           n_samples: int = 0, seed: int = 0, max_runs: int = MAX_RUNS) -> list[dict[str, float]]:
    """Parameter values of every run: the Cartesian product of the grid axes (first axis slowest),
    each combined with the same n_samples uniform random draws of the sampled parameters. More than
    max_runs runs are refused (check_size) before any is made."""
    if max_runs < 1:
        raise LimitError("{max_runs} {value}: must be >= 1", "max_runs", value=max_runs)
    shape = " x ".join([str(len(v)) for _, v in grid] + ([f"{n_samples} samples"] if n_samples else []))
    check_size(run_count(grid, n_samples), f"--grid/--sample ({shape})", max_runs)
    names = [n for n, _ in grid] + [n for n, _, _ in samples]
    if len(set(names)) != len(names):
        raise ScenarioError(f"a parameter appears twice in --grid/--sample: {', '.join(names)}")
    if samples and n_samples < 1:
        raise ScenarioError("--sample needs --samples N (N >= 1)")
    if n_samples and not samples:
        raise ScenarioError("--samples needs at least one --sample COMPONENT.PARAMETER=LOW:HIGH")
    if not grid and not samples:
        raise ScenarioError("nothing to sweep: give --grid and/or --sample")
    rng = np.random.default_rng(seed)
    draws = [{n: float(v) for n, v in zip([s[0] for s in samples], row)}
             for row in zip(*[rng.uniform(lo, hi, n_samples) for _, lo, hi in samples])] if samples else [{}]
    combos = itertools.product(*[values for _, values in grid])
    return [{**dict(zip([n for n, _ in grid], combo)), **draw} for combo in combos for draw in draws]


def check_parameters(scenario: Scenario, names: list[str], example: dict[str, float],
                     options: dict[str, str] | None = None) -> dict[str, str]:
    """Check every swept name with the master's own checks (component and variable exist, can be set,
    is Real) and return its unit from the FMU's modelDescription ('' if none). `options` names the
    command-line option of each name (--grid or --sample) for the error message."""
    from .engine import binding
    from .engine.session import check_start_values

    for name in names:
        option = (options or {}).get(name, "--grid/--sample")
        try:
            check_start_values(scenario, {name: example[name]})
        except ScenarioError as exc:                  # a start value to the engine; the user typed --grid/--sample
            raise ScenarioError(exc.describe({"start_values": option})) from None
    instances = binding.load(scenario)
    units = {}
    for name in names:
        comp, _, var_name = name.partition(".")
        var = instances[comp].variables[var_name]
        if var.type != "Real":
            raise ScenarioError(f"--grid/--sample {name}: only Real parameters can be swept "
                                f"({instances[comp].path.name} declares {var.type})")
        units[name] = var.unit or (var.declaredType.unit if var.declaredType is not None else None) or ""
    return units


# ---- one run (executed on a worker) --------------------------------------------------------------

_sessions: dict = {}            # (thread id, .ssd, fmu_dir) -> (scenario, Session), in this process
_lock = threading.Lock()


def _session(ssd: str, fmu_dir: str | None, model_exchange: bool = False):
    """This thread's (scenario, Session): the FMUs loaded once (for Co-Simulation, or Model Exchange), reused
    for every later run."""
    from .engine.session import Session

    key = (threading.get_ident(), ssd, fmu_dir, model_exchange)
    with _lock:
        found = _sessions.get(key)
    if found is None:
        scenario = read_scenario(ssd, fmu_dir=fmu_dir)
        found = (scenario, Session(scenario, model_exchange=model_exchange))
        with _lock:
            if not _sessions:
                atexit.register(close_sessions)
            _sessions[key] = found
    return found


def session_count() -> int:
    """The sessions this process keeps (one per worker thread and scenario)."""
    return len(_sessions)


def close_sessions() -> int:
    """Free every FMU instance this process holds and delete the unpacked FMUs; returns how many
    sessions were closed. The sweep calls it on every worker at the end (`client.run`, i.e. on the
    workers' main threads); it also runs at exit."""
    with _lock:
        sessions = [s for _, s in _sessions.values()]
        _sessions.clear()
    for session in sessions:
        session.close()
    return len(sessions)


def final_values(scenario: Scenario, values: dict[str, float], result) -> dict[str, float]:
    """The default metrics of a run: the last value of every recorded variable, by name."""
    last = result.last or []
    return {name: float(v) for name, v in zip(result.columns, last[1:])}


def run_point(ssd: str, fmu_dir: str | None, values: dict[str, float], options: RunOptions | None = None,
              metrics: Metrics | None = None, threshold: float = THRESHOLD, **settings) -> dict:
    """Run the scenario once with `values` and return its table row: the values, the metrics,
    'coupling_error' (a fixed-step co-simulation's estimated coupling error, the largest over the recorded
    variables relative to each one's range, engine/doubling.py; None where there is none) and 'status' ('ok',
    NOT_ACCEPTED and why where the result is not accepted: engine/verdict.py, the verdict of `emcosim run` and
    `emcosim.run`, e.g. that estimate above `threshold`; or the one-line error). Never raises for a
    failing run. `options` (RunOptions; `settings`:
    shorthands for its fields) as for `emcosim run`: e.g. a `tolerance` for error-controlled communication steps
    instead of the fixed step, which the scenario chose for its own gains and which other gains may not bear;
    `coupling`, `coupling_order`; interface_type "ModelExchange" runs the FMUs as one ODE. `metrics(scenario,
    values, result)` gives the row's numbers (default `final_values`; the paper's sweep: its report's metrics)."""
    row: dict = dict(values)
    try:
        options = options_of(options, **settings)
        scenario, session = _session(ssd, fmu_dir, options.model_exchange)
        result = session.run({k: float(v) for k, v in values.items()}, options)
        row.update((metrics or final_values)(scenario, values, result))
        estimate = getattr(result, "coupling_error", None)
        row["coupling_error"] = estimate.worst()[1] if estimate is not None and estimate.available else None
        verdict = judge(result, threshold, experiment(scenario, options).stop_time)
        row["status"] = "ok" if verdict.accepted else verdict.summary()
    except Exception as exc:                          # noqa: BLE001 - a failed run is a row, not a crash
        text = " ".join(str(exc).split())
        row["status"] = text if isinstance(exc, ScenarioError) else f"{type(exc).__name__}: {text}"
    return row


# ---- the engine ----------------------------------------------------------------------------------

def security(tls_ca_file: str | None = None, tls_cert: str | None = None, tls_key: str | None = None):
    """The dask Security to reach a running scheduler: TLS with these files (PEM), or None (dask's
    configuration) when none is given. A ScenarioError if only some are given or a file is missing."""
    given = {"--tls-ca-file": tls_ca_file, "--tls-cert": tls_cert, "--tls-key": tls_key}
    if not any(given.values()):
        return None
    missing = [k for k, v in given.items() if not v]
    if missing:
        raise ScenarioError(f"{', '.join(missing)}: needed with {', '.join(k for k, v in given.items() if v)}")
    for option, path in given.items():
        if not Path(path).is_file():
            raise ScenarioError(f"{option} {path}: file not found")
    from distributed.security import Security
    return Security(tls_ca_file=tls_ca_file, tls_client_cert=tls_cert, tls_client_key=tls_key,
                    require_encryption=True)


@contextmanager
def dask_client(workers: int | None = None, scheduler: str | None = None, security=None) -> Iterator[object]:
    """A dask.distributed Client: to the scheduler at `scheduler` (with `security`, see `security`),
    or to a new local cluster of `workers` processes (default: one per core), one thread each,
    reachable only with this process's temporary TLS credentials (see the module docstring)."""
    import logging
    import os

    try:
        from dask.distributed import Client, LocalCluster
        from distributed.security import Security
    except ImportError:
        raise ScenarioError("emcosim sweep needs Dask: pip install 'dask[distributed]'") from None

    if scheduler:
        try:
            client = Client(scheduler, timeout="20s", security=security)
        except (OSError, TimeoutError, TypeError, ValueError) as exc:     # TypeError: tls:// without credentials
            raise ScenarioError(f"--scheduler {scheduler}: cannot connect ({' '.join(str(exc).split())})") from None
        with client:
            yield client
        return
    n = workers or os.cpu_count() or 1
    if n < 1:
        raise ScenarioError(f"--workers {workers}: must be >= 1")
    try:
        local = Security.temporary()                  # needs the `cryptography` package
    except ImportError as exc:
        raise ScenarioError(f"emcosim sweep: {exc}") from None
    with _sigint_ignored(), _no_http_routes():       # the workers inherit both
        # silence_logs CRITICAL: every failure reaches the table as a row; what dask logs at ERROR is the
        # noise of a shutdown after Ctrl-C (a worker's heartbeat racing the scheduler's close)
        # the scheduler's HTTP socket (closed below) on a free port: not 8787, which may be another's
        cluster = LocalCluster(n_workers=n, threads_per_worker=1, processes=True, dashboard_address=None,
                               host="127.0.0.1", security=local, silence_logs=logging.CRITICAL,
                               scheduler_kwargs={"dashboard_address": "127.0.0.1:0"})
    with _quiet_logs(), cluster, Client(cluster, security=local) as client:
        close_http(client)
        yield client


HTTP_ROUTES = ("distributed.scheduler.http.routes", "distributed.worker.http.routes")


@contextmanager
def _no_http_routes() -> Iterator[None]:
    """Dask configured to serve nothing over HTTP while the local cluster starts (the worker processes
    take the configuration with them). Without a dashboard dask still listens for HTTP on every
    scheduler (port 8787 if free) and worker, without TLS, and serves its info pages (logs, worker
    addresses, call stacks of the workers' tasks), JSON and Prometheus metrics to any local user."""
    import dask

    with dask.config.set({key: [] for key in HTTP_ROUTES}):
        yield


def _stop_scheduler_http(dask_scheduler) -> None:
    dask_scheduler.http_server.stop()


def _stop_worker_http(dask_worker) -> None:
    dask_worker.http_server.stop()


def close_http(client) -> None:
    """Close the HTTP sockets of the scheduler and of every worker of `client`'s cluster (each in its
    own event loop): the local cluster talks TLS only."""
    client.run_on_scheduler(_stop_scheduler_http)
    client.run(_stop_worker_http)


@contextmanager
def _quiet_logs() -> Iterator[None]:
    """dask's log lines below CRITICAL silenced until the local cluster is closed: LocalCluster's own
    silence_logs ends before its scheduler has sent its last messages to a client closed by Ctrl-C
    (a CommClosedError traceback on stderr). Failures of runs reach the table as rows."""
    import logging

    logger = logging.getLogger("distributed")
    previous = logger.level
    logger.setLevel(logging.CRITICAL)
    try:
        yield
    finally:
        logger.setLevel(previous)


@contextmanager
def _sigint_ignored() -> Iterator[None]:
    """SIGINT ignored while the local cluster starts its worker processes, which inherit that: a
    Ctrl-C in the terminal (sent to every process of the group) then reaches only the client, which
    closes the cluster, instead of every worker printing a KeyboardInterrupt traceback."""
    import signal
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    previous = signal.signal(signal.SIGINT, signal.SIG_IGN)
    try:
        yield
    finally:
        signal.signal(signal.SIGINT, previous)


def run_all(client, ssd: str, fmu_dir: str | None, runs: list[dict[str, float]], options: RunOptions | None = None,
            stream: TextIO | None = sys.stderr, on_row=None, in_flight: int | None = None,
            metrics: Metrics | None = None, threshold: float = THRESHOLD, **settings) -> list[dict]:
    """Run every point on the cluster and return the rows in the order of `runs`. At most `in_flight`
    runs are submitted at a time (default IN_FLIGHT_PER_THREAD per worker thread, counted again every
    second so that workers joining a running cluster get work), the next ones as each finishes: the
    client and scheduler hold a few tasks whatever the grid. A progress bar of the runs
    done (emcosim.progress, on a terminal only) goes to `stream`; `on_row(i, row)` is called as each
    run finishes. An interruption (KeyboardInterrupt) cancels the runs in flight. `options`, `settings`: those
    of `run_point`, for every run."""
    from dask.distributed import as_completed

    from .progress import Counter

    options = options_of(options, **settings)
    window = _Window(client, in_flight)
    todo = iter(enumerate(runs))
    pending: dict = {}                                 # future key -> (run number, future)
    done = as_completed()

    def submit(count: int) -> None:
        for i, values in itertools.islice(todo, count):
            future = client.submit(run_point, ssd, fmu_dir, values, options, metrics, threshold, pure=False)
            pending[future.key] = (i, future)
            done.add(future)

    rows: list[dict | None] = [None] * len(runs)
    failed = rejected = 0
    bar = None if stream is None else Counter(len(runs), "sweep", "run", stream)
    try:
        submit(window.size())
        for future in done:
            i, _ = pending.pop(future.key)
            rows[i] = _row_of(future, runs[i])
            del future                                 # the scheduler forgets a result nobody holds
            submit(max(window.size() - len(pending), 0))
            if on_row is not None:
                on_row(i, rows[i])
            status = rows[i]["status"]
            failed += status != "ok" and not status.startswith(NOT_ACCEPTED)
            rejected += status.startswith(NOT_ACCEPTED)
            if bar is not None:
                bar.advance(", ".join([f"{failed} failed"] * bool(failed) + [f"{rejected} not accepted"] * bool(rejected)))
    except BaseException:
        _cancel(client, [f for _, f in pending.values()])
        raise
    finally:
        if bar is not None:
            bar.close()
    return rows


class _Window:
    """How many runs may be in flight: `fixed`, or IN_FLIGHT_PER_THREAD per worker thread of the cluster
    (asked again at most once a second)."""

    def __init__(self, client, fixed: int | None = None):
        self.client, self.fixed = client, fixed
        self.checked, self.value = -math.inf, 0

    def size(self) -> int:
        if self.fixed:
            return self.fixed
        if time.monotonic() - self.checked >= 1.0:
            self.value = IN_FLIGHT_PER_THREAD * max(1, sum(self.client.nthreads().values()))
            self.checked = time.monotonic()
        return self.value


def _row_of(future, values: dict[str, float]) -> dict:
    """The row a finished run returned, or a row with the error if its task failed (a worker died)."""
    try:
        return future.result()
    except Exception as exc:                          # noqa: BLE001 - e.g. a worker process died
        return {**values, "status": f"{type(exc).__name__}: {' '.join(str(exc).split())}"}


def _cancel(client, futures: list) -> None:
    """Cancel the runs in flight after an interruption (cleanup only: the cluster may be going away)."""
    try:
        client.cancel(futures, force=True)
    except Exception:                                 # noqa: BLE001
        pass


def sweep(scenario: Scenario, grid: list[tuple[str, list[float]]],
          samples: list[tuple[str, float, float]] = (), n_samples: int = 0, seed: int = 0,
          options: RunOptions | None = None, workers: int | None = None,
          scheduler: str | None = None, stream: TextIO | None = sys.stderr, security=None,
          on_row=None, max_runs: int = MAX_RUNS, metrics: Metrics | None = None,
          threshold: float = THRESHOLD, **settings) -> tuple[list[dict], dict]:
    """Run the whole sweep; returns (rows, info) where info holds the units of the parameters,
    the wall time and the throughput. `options` (RunOptions; `settings`: shorthands for its fields): the
    settings of every run, see `run_point` (Co-Simulation or Model Exchange); `on_row(i, row)`: see `run_all`;
    `max_runs`: see MAX_RUNS; `metrics`, `threshold`: see `run_point`. Progress lines go to `stream` while the cluster starts."""
    options = options_of(options, **settings)
    runs = points(grid, samples, n_samples, seed, max_runs)
    names = list(runs[0])
    flags = {**{n: "--grid" for n, _ in grid}, **{n: "--sample" for n, _, _ in samples}}
    units = check_parameters(scenario, names, runs[0], flags)
    fmu_dir = _common_fmu_dir(scenario)
    tic = time.perf_counter()
    if stream is not None:
        print(f"sweep: {len(runs)} runs; starting {scheduler or 'a local Dask cluster'} ...", file=stream, flush=True)
    with dask_client(workers, scheduler, security) as client:
        started = time.perf_counter()
        if stream is not None:
            print(f"sweep: {len(client.nthreads())} workers ready after {started - tic:.1f} s", file=stream, flush=True)
        # an interruption leaves the workers' FMUs alone: a cancelled run may still be stepping them (a local
        # cluster's workers end with it; a remote worker keeps its session for the next sweep, or frees it at exit)
        rows = run_all(client, str(scenario.path.resolve()), fmu_dir, runs, options, stream, on_row, metrics=metrics,
                       threshold=threshold)
        end = time.perf_counter()
        n_workers = len(client.nthreads())
        close_on_workers(client)
    closed = time.perf_counter()
    not_accepted = sum(r["status"].startswith(NOT_ACCEPTED) for r in rows)
    info = {"scenario": scenario.name, "runs": len(rows),
            "failed": sum(r["status"] != "ok" for r in rows) - not_accepted, "not_accepted": not_accepted,
            "error_threshold": threshold,
            "workers": n_workers, "engine": scheduler or "dask LocalCluster (processes)",
            "wall_time_s": closed - tic, "run_time_s": end - started,
            "runs_per_s": len(rows) / (end - started) if end > started else float("nan"),
            "stop_time": options.stop_time, "step_size": options.step_size, "tolerance": options.tolerance,
            "interface_type": options.interface_type,
            "coupling": None if options.model_exchange else options.coupling or scenario.coupling or "explicit",
            "coupling_order": options.coupling_order, "seed": seed,
            "grid": {n: v for n, v in grid}, "samples": {n: [lo, hi] for n, lo, hi in samples},
            "n_samples": n_samples, "units": units}
    return rows, info


def close_on_workers(client) -> None:
    """Free the FMU instances on every worker (a long-lived cluster should not keep them)."""
    try:
        client.run(close_sessions)
    except Exception:                                 # noqa: BLE001 - cleanup only; workers may be gone
        pass


def _common_fmu_dir(scenario: Scenario) -> str | None:
    """The folder every FMU of the scenario comes from, if they share one (passed to the workers as
    --fmu-dir so that they read the FMUs the client resolved); else None (the .ssd's paths)."""
    dirs = {str(Path(c.source).resolve().parent) for c in scenario.components}
    return dirs.pop() if len(dirs) == 1 else None
