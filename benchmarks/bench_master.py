"""Wall time of the co-simulation engines on the paper scenarios over their full horizons, as ratios to
the monolithic reference at the same accuracy, side by side in one run.

For each scenario:
  truth       the monolithic closed loop at rtol 1e-9 (accuracy yardstick, not timed)
  monolithic  components.monolithic at the loosest rtol (1e-3, 1e-4, ...) whose error is <= 1e-3:
              the baseline of every ratio
  fixed       our master at the scenario's default step and coupling (explicit: derivatives passed;
              implicit where the scenario says so, docs/scenarios.md)
  tolerance   our master with tolerance = 1e-3 (error-controlled steps, stepcontrol.py)
  container   the exported container FMU under fmpy, and
  libcosim    OSP libcosim, both at their own first-order accuracy (they pass no derivatives: a zero-
              order hold, run at ZOH_STEP, the step of our master's zero-order hold that meets 1e-3)
Errors: the normalised maximum position error of docs/scenarios.md at each run's communication points.
Times of the monolithic solver and of our master: the fastest of --repeat rounds (default 5; the noise of a
shared machine only adds time), each round running the monolithic solver, the fixed and the error-controlled
run one after the other, so that a slow spell falls on all three; the container and libcosim columns: one run.
Our master's times are those of `Simulation.run` with the FMUs instantiated (as a session or sweep
does); `load` is the instantiation of the FMUs (main and shadow copy), paid once per process.
The breakdown gives, per communication step of the fixed-step run, the time inside each FMU and the
master's own time. "FMUs alone": the time spent inside the FMUs' calls (doStep, get, set, derivatives;
state saves not included) of the fixed and the error-controlled run, over the monolithic time: what the
run would cost with a master that took no time at all. Where it exceeds 2, no work on the master meets
the must at those steps: only fewer steps or cheaper FMU calls can. Must: every ratio <= 2; goal: <= 1.

    python benchmarks/bench_master.py [--scenarios a,b] [--fmu-dir DIR] [--engines container,libcosim] [--repeat 5]
    python benchmarks/bench_master.py --band [--scenarios a,b]    # error vs tolerance 1e-2 ... 1e-5
"""
from __future__ import annotations

import argparse
import gc
import sys
import tempfile
import time
from pathlib import Path
from typing import Callable

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from emcosim.engine.master import Simulation                                  # noqa: E402
from emcosim.engine.ssd import read_scenario                                   # noqa: E402
from emcosim.paper import scenarios as paper_scenarios                         # noqa: E402
from emcosim.paper.reference_check import monolithic_loop, truth               # noqa: E402

TARGET = 1e-3
RTOLS = [1e-3, 1e-4, 1e-5, 1e-6, 1e-7, 1e-8]
BAND = (1e-2, 1e-3, 1e-4, 1e-5)
# zero-order hold steps that meet 1e-3 over the full horizon (our master, coupling order 0)
ZOH_STEP = {"mems_regulation_Dd0": 1e-5, "mems_regulation_Dd-1": 5e-7, "mems_regulation_prop1": 1e-6,
            "mems_tracking_Dd0": 1e-5, "mems_tracking_Dd-0.4": 1e-6, "maglev_tracking_D0_R0.82": 1.25e-4,
            "maglev_tracking_D0_R2.82": 5e-4, "maglev_tracking_D-1_R0.82": 5e-4, "maglev_tracking_D-1_R2.82": 5e-4,
            "maglev_regulation_prop2": 5e-4}


REPEAT = 5            # rounds (--repeat); each time the fastest of its rounds: the machine's noise is one-sided


def timed(fn):
    """(output, wall time) of one run of fn."""
    gc.collect()          # a full collection inside a run (~20 ms for the loaded FMUs) would be charged to it
    tic = time.perf_counter()
    out = fn()
    return out, time.perf_counter() - tic


def monolithic_run(s, ref) -> tuple[Callable[[], object], float, float]:
    """(a call that runs it, rtol, error) of the monolithic solver at the loosest rtol whose error is <= TARGET."""
    from components.monolithic import simulate as mono
    loop = monolithic_loop(s)
    scale = np.max(np.abs(_eta_samples(s)), axis=0)          # the state scales, outside the timing

    def run(rtol):
        return mono(loop.controller, loop.eta0, s.stop_time, reference=loop.reference, n_samples=2001, rtol=rtol,
                    scale=scale)
    for rtol in RTOLS:
        res = run(rtol)
        err = ref.position_error(res.t, res.q) if res.success else np.inf
        if err <= TARGET:
            break
    return (lambda: run(rtol)), rtol, err


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


def bench(name: str, fmu_dir: Path | None, engines: set[str], repeat: int = REPEAT) -> dict:
    s = read_scenario(ROOT / "scenarios" / name, fmu_dir=fmu_dir)
    ref = truth(s, rtol=1e-9)
    row = {"name": name, "h": s.step_size, "coupling": s.coupling or "explicit"}
    mono, row["rtol_mono"], row["e_mono"] = monolithic_run(s, ref)
    with Simulation(s) as sim:
        _, row["load"] = timed(lambda: sim.run(stop_time=s.start_time + s.step_size, record=["plant.q"]))
        _, load2 = timed(lambda: sim.run(stop_time=s.start_time + 4 * s.step_size, tolerance=TARGET, record=["plant.q"]))
        row["load"] += load2

        def fixed():
            timing = {}
            return sim.run(record=["plant.q"], timing=timing), timing

        def tol():
            timing = {}
            return sim.run(tolerance=TARGET, record=["plant.q"], timing=timing), timing
        best = interleaved({"mono": mono, "fixed": fixed, "tol": tol}, repeat)
        row["t_mono"] = best["mono"][1]
        (r, timing), row["t_fixed"] = best["fixed"]
        row["e_fixed"] = ref.position_error(r.time, r["plant.q"])
        row["orders"] = sorted(set(r.coupling_orders.values()))
        row["implicit"] = getattr(r, "implicit", None)
        row["steps"] = timing["steps"]
        row["per_step"] = {k: v / timing["steps"] for k, v in timing["per_fmu"].items()}
        row["per_step"]["master"] = (timing["total"] - timing["fmu"]) / timing["steps"]
        row["fmu_fixed"] = timing["fmu"]
        (r, timing), row["t_tol"] = best["tol"]
        row["fmu_tol"] = timing["fmu"]
        row["e_tol"] = ref.position_error(r.time, r["plant.q"])
        row["tol_report"] = r.step_control
    h0 = ZOH_STEP[name]
    if "container" in engines:
        from fmpy import simulate_fmu
        from emcosim.engine.container import export_container
        with tempfile.TemporaryDirectory() as tmp:
            fmu = export_container(s, Path(tmp) / "loop.fmu", step_size=h0)
            c, row["t_container"] = timed(lambda: simulate_fmu(str(fmu), stop_time=s.stop_time, output_interval=h0,
                                                               output=["plant.q"]))
        row["e_container"] = ref.position_error(c["time"], c["plant.q"])
    if "libcosim" in engines:
        from emcosim.engine.libcosim import _simulate as libcosim_here     # in this process: the engine's time only
        lc, row["t_libcosim"] = timed(lambda: libcosim_here(s, s.stop_time, h0, None, ["plant.q"]))
        row["e_libcosim"] = ref.position_error(lc.time, lc["plant.q"])
    return row


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
    p.add_argument("--engines", default="container,libcosim", help="which engines besides our master")
    p.add_argument("--band", action="store_true", help="error of --tolerance 1e-2 ... 1e-5 instead of times")
    p.add_argument("--repeat", type=int, default=REPEAT,
                   help=f"rounds of the monolithic solver, the fixed and the error-controlled run; each time the "
                        f"fastest of its rounds (default {REPEAT})")
    args = p.parse_args(argv)
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
    cols = ("scenario", "mono [s] (rtol, err)", "fixed h [s]", "fixed x (err)", "tol 1e-3 x (err, steps)",
            "FMUs alone x fixed/tol", "load [s]", "container x (err)", "libcosim x (err)",
            "fixed: us per step plant/ctrl/ref/master")
    print(" | ".join(cols))
    print(" | ".join("---" for _ in cols))
    rows = []
    for name in names:
        row = bench(name, args.fmu_dir, engines, max(1, args.repeat))
        rows.append(row)
        m = row["t_mono"]

        def ratio(key):
            return f"{row[f't_{key}'] / m:.2f} ({row[f'e_{key}']:.1e})" if f"t_{key}" in row else "n/a"
        ps = row["per_step"]
        breakdown = "/".join(f"{ps.get(k, 0.0) * 1e6:.0f}" for k in ("plant", "controller", "reference", "master"))
        h = f"{row['h']:g}" + (f" ({row['coupling']})" if row["coupling"] != "explicit" else "")
        print(" | ".join([name, f"{m:.2f} ({row['rtol_mono']:g}, {row['e_mono']:.1e})", h,
                          ratio("fixed"), f"{row['t_tol'] / m:.2f} ({row['e_tol']:.1e}, {row['tol_report'].accepted})",
                          f"{row['fmu_fixed'] / m:.2f}/{row['fmu_tol'] / m:.2f}", f"{row['load']:.2f}", ratio("container"), ratio("libcosim"), breakdown]), flush=True)
    print()
    for row in rows:
        worst = max(row["t_fixed"], row["t_tol"]) / row["t_mono"]
        verdict = "meets the goal (<= 1)" if worst <= 1 else ("meets the must (<= 2)" if worst <= 2 else "MISSES 2x")
        floors = {"fixed": row["fmu_fixed"] / row["t_mono"], "tolerance": row["fmu_tol"] / row["t_mono"]}
        over = [f"{k} {v:.2f}x" for k, v in floors.items() if v > 2]
        if over:
            verdict += f" (the FMU calls alone cost {', '.join(over)}: no master meets the must at those steps)"
        coupling = (f"{row['coupling']} coupling ({row['implicit'].summary()})" if row["coupling"] == "implicit"
                    else f"coupling order {row['orders']}")
        print(f"{row['name']}: {verdict}; fixed {row['steps']} steps of {row['h']:g} s, {coupling}; "
              f"tolerance: {row['tol_report'].summary()}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
