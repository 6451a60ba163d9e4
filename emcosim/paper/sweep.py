"""`emcosim sweep`: run one scenario over a grid of parameter values (and random plant samples) on Dask, with the
paper's metrics. The Dask engine (cluster, TLS, streaming, sessions) is emcosim.sweeps, for any scenario; this
module gives it the reproduce report's metrics (`metrics_of`) and the CSV stream of the table (`RowStream`), and
re-exports its names for the command line.

A design study in control terms: pick the gains to compare (e.g. coupled damping `controller.D_d`
and electrical damping `controller.R_e_bar`), give each a range, and the sweep runs the closed loop
at every combination and tabulates the performance metrics of `emcosim reproduce` (time into the
2 % band, overshoot, oscillations, ISE, final error, peak input). Uncertain plant parameters can be
drawn at random (`--sample plant.m=LOW:HIGH --samples N`): every grid point is then run with the same
N plant draws, so designs are compared on the same plants.
"""
from __future__ import annotations

import csv
from dataclasses import asdict
from pathlib import Path

from .. import sweeps
from ..engine.options import RunOptions
from ..engine.ssd import Scenario, with_values
from ..sweeps import (  # noqa: F401 - the engine's names, as the command line and the tests import them
    IN_FLIGHT_PER_THREAD,
    MAX_RUNS,
    check_parameters,
    check_size,
    close_on_workers,
    close_sessions,
    dask_client,
    parse_grid,
    parse_sample,
    points,
    run_count,
    security,
    session_count,
)
from .sweep_output import columns, csv_cells


def metrics_of(scenario: Scenario, values: dict[str, float], result) -> dict[str, float]:
    """The reproduce report's metrics of one run's result (master Result, or the columns of a CSV
    wrapped the same way) for the scenario run with `values`."""
    from . import report
    from .reproduce import run_from_result

    run = run_from_result(scenario.name, scenario.name, with_values(scenario, values), result)
    metrics = asdict(report.run_metrics(run))
    for key in ("resolution", "unresolved"):      # the reproduce report's resolution check (issue 35): not a column
        metrics.pop(key)
    return metrics


def run_point(ssd: str, fmu_dir: str | None, values: dict[str, float], options: RunOptions | None = None,
              **settings) -> dict:
    """emcosim.sweeps.run_point with the paper's metrics."""
    return sweeps.run_point(ssd, fmu_dir, values, options, metrics_of, **settings)


def run_all(client, ssd: str, fmu_dir: str | None, runs: list[dict[str, float]], options: RunOptions | None = None,
            **settings) -> list[dict]:
    """emcosim.sweeps.run_all with the paper's metrics."""
    return sweeps.run_all(client, ssd, fmu_dir, runs, options, metrics=metrics_of, **settings)


def sweep(scenario: Scenario, grid: list[tuple[str, list[float]]], samples: list[tuple[str, float, float]] = (),
          n_samples: int = 0, seed: int = 0, options: RunOptions | None = None, **settings) -> tuple[list[dict], dict]:
    """emcosim.sweeps.sweep with the paper's metrics (the arguments are its)."""
    return sweeps.sweep(scenario, grid, samples, n_samples, seed, options, metrics=metrics_of, **settings)


class RowStream:
    """The finished runs of a sweep appended to a CSV as they arrive (in the order they finish, each
    with its run number; flushed after every row), so that an interrupted sweep keeps them. The
    complete sweep then writes the table in run order over it (sweep_output.write_table)."""

    def __init__(self, path: Path, names: list[str]):
        self.columns = columns([{n: 0.0 for n in names}])
        self.file = open(path, "w", newline="")
        self.writer = csv.writer(self.file)
        self.writer.writerow(self.columns)
        self.file.flush()
        self.rows = 0

    def __call__(self, i: int, row: dict) -> None:
        self.writer.writerow(csv_cells({"run": i, **row}, self.columns))
        self.file.flush()
        self.rows += 1

    def close(self) -> None:
        self.file.close()
