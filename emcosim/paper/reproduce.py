"""`emcosim reproduce [--out DIR]`: build the FMUs if needed, run every paper scenario through the
co-simulation master, and write the paper's figures, a metrics table and a claims report.

Physics-aware (uses components/ for the targets eta*(t) and the metrics); the runs themselves are
plain co-simulations of the FMUs.
"""
from __future__ import annotations

import json
import multiprocessing
import os
import sys
import time
from concurrent.futures import FIRST_COMPLETED, ProcessPoolExecutor, wait
from pathlib import Path

import numpy as np

from . import report
from .certify import design_from_scenario
from ..engine.errors import ScenarioError, SimulationError
from ..engine.master import simulate
from ..progress import ProgressBar
from ..engine.results import Result
from ..engine.ssd import read_scenario

ROOT = Path(__file__).resolve().parents[2]
SCENARIOS = ROOT / "scenarios"

PAPER_CASES = {                       # role in the claims report -> scenario name
    "mems_reg_0": "mems_regulation_Dd0",
    "mems_reg_1": "mems_regulation_Dd-1",
    "mems_prop1": "mems_regulation_prop1",
    "mems_track_0": "mems_tracking_Dd0",
    "mems_track_1": "mems_tracking_Dd-0.4",
    "maglev_1": "maglev_tracking_D0_R0.82",
    "maglev_2": "maglev_tracking_D0_R2.82",
    "maglev_3": "maglev_tracking_D-1_R0.82",
    "maglev_4": "maglev_tracking_D-1_R2.82",
    "maglev_prop2": "maglev_regulation_prop2",
}
LABELS = {
    "mems_reg_0": "D_d = 0", "mems_reg_1": "D_d = -1", "mems_prop1": "Proposition 1, D_d = 0",
    "mems_track_0": "D_d = 0", "mems_track_1": "D_d = -0.4",
    "maglev_1": "case 1: D_d = 0, R_e_bar = 0.82", "maglev_2": "case 2: D_d = 0, R_e_bar = 2.82",
    "maglev_3": "case 3: D_d = -1, R_e_bar = 0.82", "maglev_4": "case 4: D_d = -1, R_e_bar = 2.82",
    "maglev_prop2": "Proposition 2, R_e_bar = 2.82",
}


def run_from_result(name: str, label: str, scenario, result) -> report.Run:
    """A report.Run from the master's recorded columns plus the design's target eta*(t)."""
    d = design_from_scenario(scenario)
    t = result.time
    jets = [None if d.reference is None else d.reference.jet(tt) for tt in t]
    eta_star = np.array([d.controller.target(j) for j in jets])
    plant = "MEMS" if d.controller_name.startswith("MEMS") else "Maglev"
    return report.Run(name, plant, label, t, result["plant.q"], result["plant.p"], result["plant.x_e"],
                      result["controller.u"], eta_star)


def _simulate_case(name: str, stop_time: float | None, fmu_dir: str | Path | None,
                   progress=None) -> tuple[list[str], list[list[float]], float]:
    """Run one paper scenario through the master: (columns, rows, wall time [s])."""
    scenario = read_scenario(SCENARIOS / name, fmu_dir=fmu_dir)
    tic = time.perf_counter()
    result = simulate(scenario, stop_time=stop_time, progress=progress)
    return result.columns, result.rows, time.perf_counter() - tic


def _worker(name: str, stop_time, fmu_dir, queue) -> tuple[list[str], list[list[float]], float]:
    """A worker process's task: the run, reporting its progress (name, fraction) to `queue`."""
    last = [-1.0]

    def progress(fraction: float) -> None:
        if fraction - last[0] >= 0.02 or fraction >= 1.0:
            last[0] = fraction
            queue.put((name, fraction))
    return _simulate_case(name, stop_time, fmu_dir, progress)


def run_paper_scenarios(names: dict[str, str] = PAPER_CASES, stop_time: float | None = None,
                        out=None, fmu_dir: str | Path | None = None, jobs: int | None = None,
                        failed: dict[str, SimulationError | ScenarioError] | None = None,
                        ) -> tuple[dict[str, report.Run], dict[str, float]]:
    """Run each scenario (at its default step and horizon unless stop_time is given), `jobs` at a
    time in worker processes (default: one per core; 1 runs them here, one after the other).
    Progress goes to `out`: which scenarios run and how far each is. A scenario that fails does not
    stop the others: its error goes into `failed` (by name) when a dict is given, else it is raised
    after the other runs."""
    out = sys.stderr if out is None else out
    jobs = max(1, min(len(names), jobs or os.cpu_count() or 1))
    errors: dict = {} if failed is None else failed
    results = _run_parallel(names, stop_time, fmu_dir, jobs, out, errors) if jobs > 1 else \
        _run_serial(names, stop_time, fmu_dir, out, errors)
    if failed is None and errors:
        raise next(iter(errors.values()))
    runs, walls = {}, {}
    for role, name in names.items():
        if name not in results:
            continue
        columns, rows, walls[name] = results[name]
        result = Result(columns)
        result.rows = rows
        runs[role] = run_from_result(name, LABELS.get(role, name), read_scenario(SCENARIOS / name), result)
    return runs, walls


def _done(i: int, n: int, name: str, outcome) -> str:
    """The line that reports a finished scenario: its size and time, or why it failed."""
    if isinstance(outcome, Exception):
        return f"[{i}/{n}] {name}: failed: {' '.join(str(outcome).split())}"
    return f"[{i}/{n}] {name}: {len(outcome[1])} communication points in {outcome[2]:.1f} s"


def _run_serial(names, stop_time, fmu_dir, out, errors) -> dict:
    results = {}
    for i, name in enumerate(names.values(), 1):
        bar = ProgressBar(f"[{i}/{len(names)}] {name}", stream=out)
        try:
            outcome = results[name] = _simulate_case(name, stop_time, fmu_dir, bar)
        except ScenarioError as exc:
            outcome = errors[name] = exc
        finally:
            bar.close()
        print(_done(i, len(names), name, outcome), file=out, flush=True)
    return results


def _run_parallel(names, stop_time, fmu_dir, jobs, out, errors) -> dict:
    """Longest runs first (by communication steps), in `jobs` worker processes; one bar (tqdm, on a
    terminal only) of the communication steps done over all scenarios, and a line per finished one."""
    steps = {n: _n_steps(n, stop_time) for n in names.values()}
    order = sorted(names.values(), key=lambda n: -steps[n])
    context = multiprocessing.get_context("spawn")              # a fresh interpreter per worker (pythonfmu)
    results, fraction = {}, {}
    finished = 0
    print(f"running {len(names)} scenarios in {jobs} worker processes", file=out, flush=True)
    bar = ProgressBar("reproduce", stream=out)
    try:
        with context.Manager() as manager, ProcessPoolExecutor(jobs, mp_context=context) as pool:
            queue = manager.Queue()
            futures = {pool.submit(_worker, n, stop_time, fmu_dir, queue): n for n in order}
            pending = set(futures)
            while pending:
                done, pending = wait(pending, timeout=0.2, return_when=FIRST_COMPLETED)
                while not queue.empty():
                    name, f = queue.get()
                    fraction[name] = f
                for future in done:
                    name = futures[future]
                    try:
                        outcome = results[name] = future.result()
                    except ScenarioError as exc:
                        outcome = errors[name] = exc
                    except Exception as exc:                       # a worker died (e.g. the host crashed)
                        outcome = errors[name] = ScenarioError(f"{name}: worker process failed: {exc!r}")
                    fraction[name] = 1.0
                    finished += 1
                    bar.write(_done(finished, len(names), name, outcome))
                bar(sum(steps[n] * f for n, f in fraction.items()) / sum(steps.values()))
    finally:
        bar.close()
    return results


def _n_steps(name: str, stop_time: float | None) -> float:
    s = read_scenario(SCENARIOS / name)
    return ((stop_time or s.stop_time) - s.start_time) / s.step_size


def ensure_fmus(out=sys.stderr) -> None:
    """Build the FMUs with the project's build.py into build/fmus unless they are up to date with
    the sources (build.py compares a fingerprint of every input: cheap when nothing changed)."""
    import runpy
    build = runpy.run_path(str(ROOT / "build.py"))
    if not build["up_to_date"]():
        print("building the FMUs (build.py) ...", file=out, flush=True)
        build["build"](verbose=True)


def write_figures(runs: dict[str, report.Run], out: Path) -> list[Path]:
    files = []
    if {"mems_reg_0", "mems_reg_1"} <= runs.keys():
        files += report.figure_states([runs["mems_reg_0"], runs["mems_reg_1"]],
                                      "MEMS regulation to q_d = 30 um without and with coupled damping (Theorem 2, Fig. 1)",
                                      out / "fig1_mems_regulation", "q_d (eta_d)")
    if {"mems_track_0", "mems_track_1"} <= runs.keys():
        files += report.figure_states([runs["mems_track_0"], runs["mems_track_1"]],
                                      "MEMS tracking of q* = 0.05 + 0.05 sin 30t without and with coupled damping (Fig. 2)",
                                      out / "fig2_mems_tracking", "q* (eta*)")
    maglev = [runs[f"maglev_{i}"] for i in range(1, 5) if f"maglev_{i}" in runs]
    if len(maglev) == 4:
        files += report.figure_states(maglev, "Maglev tracking, four cases (Theorem 3, paper's D_d convention, Fig. 3)",
                                      out / "fig3_maglev_tracking", "q* (eta*)")
        files += report.figure_error_norms(maglev, runs["maglev_3"], out / "fig4_maglev_error_norms")
    return files


def reproduce(out_dir: str | Path = "results", stop_time: float | None = None, out=None,
              fmu_dir: str | Path | None = None, jobs: int | None = None) -> dict:
    """Run every paper scenario and write figures, metrics and claims into out_dir. A failed
    scenario leaves out what needs it (its rows up to the failure go to NAME.partial.csv) and ends
    in a ScenarioError naming it, after everything else is written."""
    out = sys.stderr if out is None else out
    out_path = Path(out_dir)
    out_path.mkdir(parents=True, exist_ok=True)
    failed: dict[str, ScenarioError] = {}
    runs, walls = run_paper_scenarios(stop_time=stop_time, out=out, fmu_dir=fmu_dir, jobs=jobs, failed=failed)
    figures = write_figures(runs, out_path)
    notes = []
    for name in PAPER_CASES.values():
        notes += [n for n in read_scenario(SCENARIOS / name).notes if n not in notes and "Generated by" not in n]
    content = report.write_reports({r.name: r for r in runs.values()},
                                   {role: runs[role].name for role in runs}, out_path, notes)
    (out_path / "runs.json").write_text(json.dumps({"wall_time_s": walls,
                                                    "failed": {n: str(e) for n, e in failed.items()}}, indent=1))
    print(f"wrote {len(figures)} figure files, metrics.md/json, claims.md/json to {out_path}", file=out)
    if failed:
        for name, exc in failed.items():
            partial = getattr(exc, "result", None)
            if partial is not None and len(partial):
                partial.write_csv(out_path / f"{name}.partial.csv")
        raise ScenarioError(f"{len(failed)} of {len(PAPER_CASES)} scenarios failed: "
                            + "; ".join(f"{n}: {' '.join(str(e).split())}" for n, e in failed.items()))
    return content
