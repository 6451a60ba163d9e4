"""Wall time of the co-simulation engines on the paper scenarios over their full horizons, as ratios to
a fair monolithic baseline at the same accuracy, side by side in one run.

For each scenario:
  truth       the monolithic closed loop at rtol 1e-9 (accuracy yardstick, not timed)
  fair        the baseline of every ratio: components.monolithic.record, which records only what a
              co-simulation run records (the plant's states and the controller's u at the fixed-step run's
              communication points, `grid`), with the fastest of scipy's LSODA, BDF and Radau (exact
              Jacobian), each at the loosest rtol (1e-3, 1e-4, ...) whose error is <= 1e-3
  old         components.monolithic.simulate (Radau) at its loosest rtol whose error is <= 1e-3, sampling
              2001 times with u and the target system eta* at every sample (the baseline of the tables
              before docs/scenarios.md, "Fair baseline"; its ratios are kept in a column to show what
              moved). Its share that is not
              integration: "post %", u and eta* at the 2001 samples timed alone, and "not solve %", one
              minus the time of the same Radau run without samples (the dense output at the 2001 samples
              as well), each timed in the same rounds
  fixed       our master at the scenario's default step and coupling (explicit: derivatives passed;
              implicit where the scenario says so, docs/scenarios.md)
  tolerance   our master with tolerance = 1e-3 (error-controlled steps, stepcontrol.py)
  ME          Model Exchange (emcosim.engine.model_exchange, the FMUs instantiated once, as for our master):
              "ME tol" with tolerance = 1e-3 (the engine's global-error control: 2-3 solves, LSODA), and
              "ME best", the same rule as the fair baseline: the fastest of LSODA, BDF and Radau, each at
              the loosest rtol whose error is <= 1e-3 (one solve; the search outside the timing); each with
              the pythonfmu FMUs (--fmu-dir) and, in the same rounds, with the native ones (--native-dir,
              default build/native from `build.py --native`; "native ME ..."). Timed without the engine's
              clocks; the breakdown comes from one more run of each with them (`timing`): its shares inside
              the FMUs' calls, in scipy and in the engine's Python, applied to the best time
  container   the exported container FMU under fmpy, and
  libcosim    OSP libcosim, both at their own first-order accuracy (they pass no derivatives: a zero-
              order hold, run at ZOH_STEP, the step of our master's zero-order hold that meets 1e-3)
"rec %": the fair baseline's share that is recording (the dense output and u at the grid), one minus the
time of the same run without samples, timed in the same rounds; "rows %" of the native ME best the same:
one minus the time of its run without the grid's rows (NO_ROWS), timed in the same rounds.
Errors: the normalised maximum position error of docs/scenarios.md at each run's communication points (the
fair baseline's: the fixed-step grid; the old baseline's: its 2001 samples). Diagnostics (errors, eta*) are
computed outside the timing.
Times of the monolithic solvers and of our master: the fastest of --repeat rounds (default 5; the noise of a
shared machine only adds time), each round running the old baseline, its post-processing, its bare
integration, the three fair candidates and their bare integrations, the fixed and the error-controlled run
one after the other, so that a slow spell falls on all of them; the container and libcosim columns: one run.
Our master's times are those of `Simulation.run` with the FMUs instantiated (as a session or sweep
does); `load` is the instantiation of the FMUs (main and shadow copy), paid once per process.
The breakdown gives, per communication step of the fixed-step run, the time inside each FMU and the
master's own time. "FMUs alone": the time spent inside the FMUs' calls (doStep, get, set, derivatives;
state saves not included) of the fixed and the error-controlled run, over the fair baseline's time: what the
run would cost with a master that took no time at all. Where it exceeds 2, no work on the master meets
the must at those steps: only fewer steps or cheaper FMU calls can. Co-simulation: must every ratio <= 2, goal
<= 1; Model Exchange: must <= 1, goal <= 0.5 (issue 23).

    python benchmarks/bench_master.py [--scenarios a,b] [--fmu-dir DIR] [--native-dir DIR] [--engines container,libcosim]
                                      [--repeat 5] [--clock wall|cpu]
    python benchmarks/bench_master.py --band [--scenarios a,b]    # error vs tolerance 1e-2 ... 1e-5
"""
from __future__ import annotations

import argparse
import contextlib
import gc
import math
import sys
import tempfile
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Callable

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from components import monolithic as mono  # noqa: E402
from emcosim.engine.master import Simulation  # noqa: E402
from emcosim.engine.model_exchange import ModelExchangeSimulation  # noqa: E402
from emcosim.engine.ssd import Scenario, read_scenario  # noqa: E402
from emcosim.paper import scenarios as paper_scenarios  # noqa: E402
from emcosim.paper.reference_check import Truth, monolithic_loop, truth  # noqa: E402

TARGET = 1e-3
RTOLS = [1e-3, 1e-4, 1e-5, 1e-6, 1e-7, 1e-8]
ME_RECORD = ["plant.q", "plant.p", "plant.x_e", "controller.u"]      # what the fair baseline records
SOLVERS = ("LSODA", "BDF", "Radau")           # the fair baseline's candidates (components.monolithic.METHODS)
OLD_SAMPLES = 2001                            # the old baseline's samples
BAND = (1e-2, 1e-3, 1e-4, 1e-5)
# zero-order hold steps that meet 1e-3 over the full horizon (our master, coupling order 0)
ZOH_STEP = {"mems_regulation_Dd0": 1e-5, "mems_regulation_Dd-1": 5e-7, "mems_regulation_prop1": 1e-6,
            "mems_tracking_Dd0": 1e-5, "mems_tracking_Dd-0.4": 1e-6, "maglev_tracking_D0_R0.82": 1.25e-4,
            "maglev_tracking_D0_R2.82": 5e-4, "maglev_tracking_D-1_R0.82": 5e-4, "maglev_tracking_D-1_R2.82": 5e-4,
            "maglev_regulation_prop2": 5e-4}


NATIVE = "native "    # the labels of the runs with the native FMUs (build.py --native)
NO_ROWS = " no rows"  # the label of a Model Exchange run without the grid's rows
CLOCK = time.perf_counter   # --clock wall; --clock cpu: time.process_time (this process's CPU time alone)
REPEAT = 5            # rounds (--repeat); each time the fastest of its rounds: the machine's noise is one-sided


def timed(fn):
    """(output, wall time) of one run of fn."""
    gc.collect()          # a full collection inside a run (~20 ms for the loaded FMUs) would be charged to it
    tic = CLOCK()
    out = fn()
    return out, CLOCK() - tic


@dataclass
class Candidate:
    """A monolithic solver at the loosest rtol of RTOLS whose error is <= TARGET (`meets`), else at the
    tightest; `run` repeats that run (the timed call), `solve` its integration alone (no samples)."""

    method: str
    rtol: float
    err: float
    nfev: int
    njev: int
    run: Callable[[], object]
    solve: Callable[[], object]

    @property
    def meets(self) -> bool:
        return self.err <= TARGET


def grid(s: Scenario) -> np.ndarray:
    """The communication points the fixed-step co-simulation records: t0 + k h, k = 0 ... N (the halved
    steps of an implicit run's transient record none)."""
    n = int(round((s.stop_time - s.start_time) / s.step_size))
    return np.linspace(s.start_time, s.stop_time, n + 1)


def fair_candidates(s: Scenario, ref: Truth, scale: np.ndarray) -> dict[str, Candidate]:
    """{solver: Candidate} of the fair baseline: `record` at the fixed-step grid, only eta and u."""
    loop, t_grid = monolithic_loop(s), grid(s)

    def run(method, rtol, times=t_grid):
        return lambda: mono.record(loop.controller, loop.eta0, times, reference=loop.reference, rtol=rtol,
                                   scale=scale, method=method)
    out = {}
    for method in SOLVERS:
        for rtol in RTOLS:
            rec = run(method, rtol)()
            err = ref.position_error(rec.t, rec.q) if rec.success else np.inf
            if err <= TARGET:
                break
        out[method] = Candidate(method, rtol, err, rec.nfev, rec.njev, run(method, rtol),
                                run(method, rtol, t_grid[[0, -1]]))
    return out


@dataclass
class Old:
    """The old baseline: components.monolithic.simulate (Radau) at the loosest rtol whose error is <= TARGET,
    with calls that run it (`run`), its integration alone without samples (`solve`) and its post-processing
    alone (`post`: u and eta* at the OLD_SAMPLES samples)."""

    rtol: float
    err: float
    run: Callable[[], object]
    solve: Callable[[], object]
    post: Callable[[], object]


def monolithic_run(s: Scenario, ref: Truth, scale: np.ndarray) -> Old:
    """The old baseline of scenario s (class Old), its rtol chosen against the truth `ref`."""
    loop = monolithic_loop(s)

    def run(rtol):
        return mono.simulate(loop.controller, loop.eta0, s.stop_time, reference=loop.reference,
                             n_samples=OLD_SAMPLES, rtol=rtol, scale=scale)
    for rtol in RTOLS:
        res = run(rtol)
        err = ref.position_error(res.t, res.q) if res.success else np.inf
        if err <= TARGET:
            break
    closed = mono.ClosedLoop(loop.controller, loop.reference)
    return Old(rtol, err, lambda: run(rtol),
               lambda: mono.record(loop.controller, loop.eta0, [s.start_time, s.stop_time], reference=loop.reference,
                                   rtol=rtol, scale=scale),
               lambda: (closed.controls(res.t, res.eta), closed.targets(res.t)))


# ---- Model Exchange ---------------------------------------------------------------------------------------
def model_exchange_runs(me: ModelExchangeSimulation, ref: Truth, prefix: str = "",
                        rows: bool = False) -> dict[str, Callable[..., object]]:
    """{label: a call}: "ME tol" (tolerance TARGET) and, for each solver, "ME <solver>" at the loosest rtol
    whose error is <= TARGET (found here, outside the timing; the solver left out if none meets it), each
    label after `prefix`. Each call returns the result; call(timing) fills the timing dict too (the engine's
    clocks on: the breakdown's run, not the timed one). They record what the fair baseline records (the
    plant's states and the controller's u) on the fixed-step run's grid. rows: each solver's run also
    without the grid (NO_ROWS: a row at the start and the stop time only), its cost of the rows the rest."""
    def run(**kwargs):
        def call(timing: dict | None = None):
            return me.run(record=ME_RECORD, timing=timing, **kwargs)
        return call
    runs = {f"{prefix}ME tol": run(tolerance=TARGET)}
    for solver in SOLVERS:
        for rtol in RTOLS:
            r = run(rtol=rtol, solver=solver)()
            if ref.position_error(r.time, r["plant.q"]) <= TARGET:
                runs[f"{prefix}ME {solver}"] = run(rtol=rtol, solver=solver)
                if rows:
                    horizon = me.scenario.stop_time - me.scenario.start_time
                    runs[f"{prefix}ME {solver}{NO_ROWS}"] = run(rtol=rtol, solver=solver, step_size=horizon)
                break
    return runs


def model_costs(s: Scenario) -> tuple[float, float]:
    """(plant, controller + reference) [s] of one evaluation of the models' own Python (components/, as the
    FMUs call it: the plant's scalar right-hand side, the controller's u and the reference's jet), measured
    here: what a right-hand side of the FMUs would cost with no FMI layer at all."""
    from components.plant_step import PlantStepper
    loop = monolithic_loop(s)
    model = PlantStepper(loop.controller.plant).model
    q, p, x = (float(v) for v in loop.eta0)
    n = 2000
    tic = time.perf_counter()
    for _ in range(n):
        model.f(q, p, x, 1.0)
    plant = (time.perf_counter() - tic) / n
    ctrl = loop.controller
    tic = time.perf_counter()
    for k in range(n):
        jet = loop.reference.values(1e-6 * k) if loop.reference is not None else None
        ctrl.u_scalar(q, p, x, jet) if ctrl.scalars is not None else ctrl.u(loop.eta0, None)
    return plant, (time.perf_counter() - tic) / n


def interleaved(runs: dict[str, Callable[[], object]], repeat: int) -> dict[str, tuple[object, float]]:
    """{name: (output of its fastest run, its wall time)}: `repeat` rounds, each running every entry once
    in turn, so that a slow spell of the shared machine (measured: the monolithic solver's time of one
    scenario at 0.08 s in one benchmark and 0.17 s in the next, best of three each) falls on all of them."""
    best = {name: (None, float("inf")) for name in runs}
    for _ in range(repeat):
        for name, fn in runs.items():
            out, seconds = timed(fn)
            if seconds < best[name][1]:
                best[name] = (out, seconds)
    return best


def bench(name: str, fmu_dir: Path | None, engines: set[str], repeat: int = REPEAT,
          native_dir: Path | None = None) -> dict:
    s = read_scenario(ROOT / "scenarios" / name, fmu_dir=fmu_dir)
    ref = truth(s, rtol=1e-9)
    row = {"name": name, "h": s.step_size, "coupling": s.coupling or "explicit"}
    scale = np.max(np.abs(_eta_samples(s)), axis=0)          # the state scales, outside the timing
    old = monolithic_run(s, ref, scale)
    row["rtol_old"], row["e_old"] = old.rtol, old.err
    row["candidates"] = fair_candidates(s, ref, scale)
    native = read_scenario(ROOT / "scenarios" / name, fmu_dir=native_dir) if native_dir is not None else None
    with contextlib.ExitStack() as stack:
        sim = stack.enter_context(Simulation(s))
        row["load"] = _load(sim, s)
        me = model_exchange_runs(stack.enter_context(ModelExchangeSimulation(s)), ref)
        if native is not None:
            me |= model_exchange_runs(stack.enter_context(ModelExchangeSimulation(native)), ref, NATIVE, rows=True)
        runs = {"old": old.run, "solve": old.solve, "post": old.post,
                **{m: c.run for m, c in row["candidates"].items()},
                **{f"{m} solve": c.solve for m, c in row["candidates"].items()},
                "fixed": _master(sim), "tol": _master(sim, tolerance=TARGET), **me}
        best = interleaved(runs, repeat)
        _fill_baselines(row, best)
        _fill_master(row, best, ref)
        _fill_model_exchange(row, best, ref, me, model_costs(s))
    _other_engines(row, s, ref, engines)
    return row


def _load(sim: Simulation, s: Scenario) -> float:
    """The instantiation of the FMUs (main and shadow copy): a short fixed and error-controlled run."""
    _, first = timed(lambda: sim.run(stop_time=s.start_time + s.step_size, record=["plant.q"]))
    _, second = timed(lambda: sim.run(stop_time=s.start_time + 4 * s.step_size, tolerance=TARGET, record=["plant.q"]))
    return first + second


def _master(sim: Simulation, tolerance: float | None = None) -> Callable[[], tuple[object, dict]]:
    def run():
        timing = {}
        return sim.run(tolerance=tolerance, record=["plant.q"], timing=timing), timing
    return run


def _fill_baselines(row: dict, best: dict) -> None:
    """The old baseline's time, its integration's and its post-processing's, every candidate's, and the fair
    baseline: the fastest candidate that meets TARGET (None if none does)."""
    row["t_old"], row["t_solve"], row["t_post"] = best["old"][1], best["solve"][1], best["post"][1]
    for method in row["candidates"]:
        row[f"t_{method}"], row[f"t_{method}_solve"] = best[method][1], best[f"{method} solve"][1]
    meeting = [c for c in row["candidates"].values() if c.meets]
    row["fair"] = min(meeting, key=lambda c: row[f"t_{c.method}"]) if meeting else None
    row["t_fair"] = row[f"t_{row['fair'].method}"] if meeting else np.nan


def _fill_master(row: dict, best: dict, ref: Truth) -> None:
    (r, timing), row["t_fixed"] = best["fixed"]
    row["e_fixed"] = ref.position_error(r.time, r["plant.q"])
    row["orders"] = sorted(set(r.coupling_orders.values()))
    row["implicit"] = getattr(r, "implicit", None)
    row["steps"] = timing["steps"]
    row["per_step"] = {k: v / timing["steps"] for k, v in timing["per_fmu"].items()}
    row["per_step"]["master"] = (timing["total"] - timing["fmu"]) / timing["steps"]
    row["fmu_fixed"] = timing["fmu"]
    estimate = r.coupling_error                   # the fixed run's own error estimate (engine/doubling.py)
    true = float(np.max(np.abs(r["plant.q"] - ref.q(r.time))))
    row["estimate"] = (estimate.seconds / timing["total"], estimate.absolute[estimate.columns.index("plant.q")] / true)
    (r, timing), row["t_tol"] = best["tol"]
    row["fmu_tol"] = timing["fmu"]
    row["e_tol"] = ref.position_error(r.time, r["plant.q"])
    row["tol_report"] = r.step_control


def _fill_model_exchange(row: dict, best: dict, ref: Truth, runs: dict[str, Callable[..., object]],
                         costs: tuple[float, float]) -> None:
    """row["me"]: label -> (time, error, result); row["me_best"][prefix]: the fastest solver's label, for
    the pythonfmu FMUs (prefix "") and the native ones (NATIVE); the breakdown of "ME tol" and the best of
    each, from one more run with the engine's clocks (`timing`, wall time): its shares inside the FMUs' calls
    (of it, for the pythonfmu FMUs: the models' own Python, `model_costs`), in scipy and in the engine's
    Python, applied to the best time. The clocks add about 0.3 us per FMU call to that run, charged to the
    engine's share and a little to the calls'."""
    row["me"], row["me_best"], row["me_breakdown"] = {}, {}, {}
    for label in runs:
        r, seconds = best[label]
        row["me"][label] = (seconds, ref.position_error(r.time, r["plant.q"]) if NO_ROWS not in label else 0.0, r)
    plant, others = costs
    for prefix in ("", NATIVE):
        solvers = [label for label in runs if label.startswith(f"{prefix}ME ") and label != f"{prefix}ME tol"
                   and NO_ROWS not in label]
        if solvers:
            row["me_best"][prefix] = min(solvers, key=lambda label: row["me"][label][0])
        for label in [f"{prefix}ME tol"] + ([row["me_best"][prefix]] if solvers else []):
            if label not in runs:
                continue
            seconds, _, r = row["me"][label]
            timing: dict = {}
            runs[label](timing)
            stats = r.model_exchange
            rows = len(r) * max(1, stats.solves)
            models = stats.rhs * (plant + others) + rows * others if not prefix else math.nan
            share = seconds / timing["total"]              # the timed run's shares, of the best time
            fmu, solver = share * timing["fmu"], share * timing["solver"]
            row["me_breakdown"][label] = {"fmu": fmu, "models": min(models, fmu), "engine": seconds - fmu - solver,
                                          "solver": solver, "total": seconds, "rhs": stats.rhs,
                                          "steps": stats.steps, "rows": rows, "jacobians": stats.jacobians,
                                          "summary": stats.summary()}


def _other_engines(row: dict, s: Scenario, ref: Truth, engines: set[str]) -> None:
    h0 = ZOH_STEP[s.name]
    if "container" in engines:
        from fmpy import simulate_fmu

        from emcosim.engine.container import export_container
        with tempfile.TemporaryDirectory() as tmp:
            fmu = export_container(s, Path(tmp) / "loop.fmu", step_size=h0)
            c, row["t_container"] = timed(lambda: simulate_fmu(str(fmu), stop_time=s.stop_time, output_interval=h0,
                                                               output=["plant.q"]))
        row["e_container"] = ref.position_error(c["time"], c["plant.q"])
    if "libcosim" in engines:
        from emcosim.engine.libcosim import _simulate as libcosim_here  # in this process: the engine's time only
        lc, row["t_libcosim"] = timed(lambda: libcosim_here(s, s.stop_time, h0, None, ["plant.q"]))
        row["e_libcosim"] = ref.position_error(lc.time, lc["plant.q"])


def _eta_samples(s):
    """States of a quick monolithic run: the scales components.monolithic otherwise finds in a first pass."""
    from emcosim.paper.reference_check import monolithic
    return monolithic(s, n_samples=201, rtol=1e-6).eta


def band(name: str, fmu_dir: Path | None) -> list[str]:
    s = read_scenario(ROOT / "scenarios" / name, fmu_dir=fmu_dir)
    ref = truth(s, rtol=1e-9)
    cells = []
    with Simulation(s) as sim:
        for tol in BAND:
            r, seconds = timed(lambda: sim.run(tolerance=tol, record=["plant.q"]))
            err, rep = ref.position_error(r.time, r["plant.q"]), r.step_control
            mark = "" if tol / 10 <= err <= 3 * tol else ("*" if err <= 3 * tol and rep.held >= 0.5 else " !")
            cells.append(f"{err:.1e} ({err / tol:.2f}{mark}) {rep.accepted} st {seconds:.1f} s")
    return cells


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--scenarios", help="comma-separated names (default: all paper scenarios)")
    p.add_argument("--fmu-dir", type=Path, help="FMU folder (default: the scenarios' build/fmus)")
    p.add_argument("--native-dir", type=Path, default=ROOT / "build" / "native",
                   help="the native FMUs' folder (build.py --native; default build/native): the native ME "
                        "columns; '' leaves them out")
    p.add_argument("--engines", default="container,libcosim", help="which engines besides our master")
    p.add_argument("--band", action="store_true", help="error of --tolerance 1e-2 ... 1e-5 instead of times")
    p.add_argument("--repeat", type=int, default=REPEAT,
                   help=f"rounds of the monolithic runs (old, its parts, the fair candidates), the fixed "
                        f"and the error-controlled run; each time the fastest of its rounds (default {REPEAT})")
    p.add_argument("--clock", choices=("wall", "cpu"), default="wall",
                   help="what the times are: wall time (default) or this process's CPU time, which other jobs on a "
                        "shared machine disturb far less (everything measured runs in this process, single-threaded)")
    args = p.parse_args(argv)
    global CLOCK
    CLOCK = time.process_time if args.clock == "cpu" else time.perf_counter
    names = args.scenarios.split(",") if args.scenarios else [c.name for c in paper_scenarios.cases()]
    if args.band:
        cols = ["scenario"] + [f"TOL {t:g}: err (err/TOL) steps time" for t in BAND]
        print(" | ".join(cols))
        print(" | ".join("---" for _ in cols))
        for name in names:
            print(" | ".join([name] + band(name, args.fmu_dir)), flush=True)
        print("\n(*: below TOL/10 with the steps held by the maximum step or the stability / estimate bound; "
              "!: outside [TOL/10, 3 TOL])")
        return 0
    engines = set(args.engines.split(",")) if args.engines else set()
    native_dir = args.native_dir if args.native_dir and str(args.native_dir) not in ("", ".") else None
    if native_dir is not None and not native_dir.is_dir():
        print(f"bench_master: no native FMUs in {native_dir} (build.py --native): the native ME columns are left out",
              file=sys.stderr)
        native_dir = None
    _header(COLUMNS)
    rows = []
    for name in names:
        rows.append(bench(name, args.fmu_dir, engines, max(1, args.repeat), native_dir))
        print(" | ".join(_cells(rows[-1])), flush=True)
    print()
    _header(ME_COLUMNS)
    for row in rows:
        print(" | ".join(_me_row(row)))
    print()
    _header(["scenario"] + [f"{m}: rtol, time [s], rhs/jac, err" for m in SOLVERS] + ["fair / old"])
    for row in rows:
        print(" | ".join([row["name"]] + [_candidate(row, m) for m in SOLVERS]
                         + [f"{row['t_fair'] / row['t_old']:.2f}"]))
    print()
    for row in rows:
        print(_verdict(row))
    return 0


COLUMNS = ("scenario", "fair [s] (solver rtol, rhs, err, rec %)", "old [s] (rtol, err, post %, not solve %)",
           "fixed h [s]", "fixed x (err)", "tol 1e-3 x (err, steps)", "old x fixed/tol", "FMUs alone x fixed/tol",
           "ME x (err): tol 1e-3; best", "native ME x (err): tol 1e-3; best", "load [s]", "container x (err)", "libcosim x (err)",
           "fixed: us per step plant/ctrl/ref/master", "fixed: estimate's cost %, estimate / true error of q")


def _header(cols) -> None:
    print(" | ".join(cols))
    print(" | ".join("---" for _ in cols))


def _cells(row: dict) -> list[str]:
    """One line of the main table: times as ratios to the fair baseline (old: to the old baseline)."""
    m, f = row["t_old"], row["fair"]

    def ratio(key):
        return f"{row[f't_{key}'] / row['t_fair']:.2f} ({row[f'e_{key}']:.1e})" if f"t_{key}" in row else "n/a"
    fair = (f"{row['t_fair']:.3f} ({f.method} {f.rtol:g}, {f.nfev}, {f.err:.1e}, "
            f"{100 * (1 - row[f't_{f.method}_solve'] / row['t_fair']):.0f} %)" if f is not None else "none meets 1e-3")
    ps = row["per_step"]
    breakdown = "/".join(f"{ps.get(k, 0.0) * 1e6:.0f}" for k in ("plant", "controller", "reference", "master"))
    h = f"{row['h']:g}" + (f" ({row['coupling']})" if row["coupling"] != "explicit" else "")
    me = [_me_cell(row, prefix) for prefix in ("", NATIVE)]
    return [row["name"], fair, f"{m:.3f} ({row['rtol_old']:g}, {row['e_old']:.1e}, {100 * row['t_post'] / m:.0f} %, "
            f"{100 * (1 - row['t_solve'] / m):.0f} %)",
            h, ratio("fixed"), f"{row['t_tol'] / row['t_fair']:.2f} ({row['e_tol']:.1e}, {row['tol_report'].accepted})",
            f"{row['t_fixed'] / m:.2f}/{row['t_tol'] / m:.2f}",
            f"{row['fmu_fixed'] / row['t_fair']:.2f}/{row['fmu_tol'] / row['t_fair']:.2f}", *me, f"{row['load']:.2f}",
            ratio("container"), ratio("libcosim"), breakdown,
            f"{100 * row['estimate'][0]:.1f} %, {row['estimate'][1]:.2g}"]


def _me_cell(row: dict, prefix: str) -> str:
    """"ME tol" and the best ME run of the FMUs of `prefix`, as ratios to the fair baseline (errors)."""
    shown = [f"{prefix}ME tol"] + ([row["me_best"][prefix]] if prefix in row["me_best"] else [])
    return "; ".join(f"{k[len(prefix) + 3:]} {row['me'][k][0] / row['t_fair']:.2f} ({row['me'][k][1]:.1e})"
                     for k in shown if k in row["me"]) or "n/a"


ME_COLUMNS = ("scenario", "fair [s]", "ME tol x (err) pythonfmu / native", "ME best x pythonfmu: solver rtol (err)",
              "ME best x native: solver rtol (err)", "native best: FMU calls / engine / solver x; rows %",
              "native best: steps, rhs, rows, Jacobians; us per evaluation")


def _me_row(row: dict) -> list[str]:
    """One line of the Model Exchange table: both kinds of FMUs side by side, the native best's breakdown
    and its evaluations (right-hand sides, rows, the indicators at each step's end, Jacobians)."""
    fair = row["t_fair"]

    def ratio(label: str) -> str:
        if label not in row["me"]:
            return "n/a"
        seconds, err, r = row["me"][label]
        return f"{seconds / fair:.2f} ({err:.1e})"

    def best(prefix: str) -> str:
        label = row["me_best"].get(prefix)
        return f"{label[len(prefix) + 3:]} {row['me'][label][2].model_exchange.rtol:g}: {ratio(label)}" if label else "n/a"
    cells = [row["name"], f"{fair:.3f}", f"{ratio('ME tol')} / {ratio(NATIVE + 'ME tol')}", best(""), best(NATIVE)]
    label = row["me_best"].get(NATIVE)
    if label is None:
        return cells + ["n/a", "n/a"]
    b = row["me_breakdown"][label]
    evaluations = b["rhs"] + b["rows"] + b["steps"] + b["jacobians"]
    bare = row["me"].get(label + NO_ROWS)
    rows = f"; {100 * (1 - bare[0] / b['total']):.0f} %" if bare else ""
    return cells + [f"{b['fmu'] / fair:.2f} / {b['engine'] / fair:.2f} / {b['solver'] / fair:.2f}{rows}",
                    f"{b['steps']}, {b['rhs']}, {b['rows']}, {b['jacobians']}; "
                    f"{1e6 * (b['fmu'] + b['engine']) / max(1, evaluations):.1f}"]


def _candidate(row: dict, method: str) -> str:
    c = row["candidates"][method]
    cell = f"{c.rtol:g}, {row[f't_{method}']:.3f}, {c.nfev}/{c.njev}, {c.err:.1e}"
    return cell if c.meets else f"{cell} (misses 1e-3)"


def _verdict(row: dict) -> str:
    """Goal / must of the fixed, error-controlled (and Model Exchange) runs against the fair baseline."""
    fair = row["t_fair"]
    worst = max([row["t_fixed"], row["t_tol"]]) / fair
    verdict = "meets the goal (<= 1)" if worst <= 1 else ("meets the must (<= 2)" if worst <= 2 else "MISSES 2x")
    me = _me_verdict(row)
    floors = {"fixed": row["fmu_fixed"] / fair, "tolerance": row["fmu_tol"] / fair}
    over = [f"{k} {v:.2f}x" for k, v in floors.items() if v > 2]
    if over:
        verdict += f" (the FMU calls alone cost {', '.join(over)}: no master meets the must at those steps)"
    coupling = (f"{row['coupling']} coupling ({row['implicit'].summary()})" if row["coupling"] == "implicit"
                else f"coupling order {row['orders']}")
    fair_name = f"{row['fair'].method} at rtol {row['fair'].rtol:g}" if row["fair"] is not None else "none meets 1e-3"
    return (f"{row['name']}: co-simulation {verdict} against the fair baseline ({fair_name}); "
            f"fixed {row['steps']} steps of {row['h']:g} s, {coupling}; tolerance: {row['tol_report'].summary()}\n"
            f"    {me}")


def _me_verdict(row: dict) -> str:
    """Model Exchange against the fair baseline: must <= 1, goal <= 0.5; the breakdown of each run."""
    fair = row["t_fair"]
    parts = []
    for label, b in row["me_breakdown"].items():
        ratio = b["total"] / fair
        verdict = "meets the goal (<= 0.5)" if ratio <= 0.5 else ("meets the must (<= 1)" if ratio <= 1 else "MISSES 1x")
        models = "" if math.isnan(b["models"]) else f" (the models' own Python about {b['models'] / fair:.2f}x of it)"
        parts.append(f"{label} {ratio:.2f}x, {verdict}: FMU calls {b['fmu'] / fair:.2f}x{models}, engine "
                     f"{b['engine'] / fair:.2f}x, solver "
                     f"{b['solver'] / fair:.2f}x; {b['rhs']} right-hand sides, {1e6 * b['total'] / max(1, b['rhs']):.0f} "
                     f"us per right-hand side in all [{b['summary']}]")
    return "Model Exchange: " + "; ".join(parts)


if __name__ == "__main__":
    sys.exit(main())
