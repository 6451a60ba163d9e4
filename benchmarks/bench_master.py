"""Wall time of the co-simulation engines on the paper scenarios, as ratios to the monolithic
reference at matching accuracy, side by side in one run.

For each scenario (full horizon unless --horizon-scale < 1):
  truth       the monolithic closed loop at rtol 1e-10 (accuracy yardstick, not timed)
  master      our master at the scenario's default step: error, wall time, own overhead per FMU
              per communication step (wall time outside FMU calls / (steps * FMUs))
  adaptive    our master with error-controlled steps (step doubling with FMU-state rollback),
              if every FMU restores its state
  container   the exported container FMU under fmpy at the default step
  libcosim    OSP libcosim at the default step
  monolithic  components.monolithic at the loosest rtol (1e-3 ... 1e-10) whose error is at most
              the master's (floored at 1e-6): the baseline of every ratio
Errors are the normalised maximum position error of docs/scenarios.md (the adaptive run's at its own
communication points, with the truth interpolated there).

Targets: master overhead <= 10 us per FMU per step; master <= 3x the monolithic reference.

    python benchmarks/bench_master.py [--scenarios a,b] [--horizon-scale 0.1] [--fmu-dir DIR]
"""
from __future__ import annotations

import argparse
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from emcosim.paper import scenarios as paper_scenarios                                 # noqa: E402
from emcosim.engine.errors import ScenarioError                              # noqa: E402
from emcosim.engine.master import simulate                                   # noqa: E402
from emcosim.paper.reference_check import monolithic, monolithic_loop, position_error, position_scale, samples_for  # noqa: E402
from emcosim.engine.ssd import read_scenario                                 # noqa: E402

OVERHEAD_TARGET = 10e-6
RATIO_TARGET = 3.0
RTOLS = [1e-3, 1e-4, 1e-5, 1e-6, 1e-7, 1e-8, 1e-9, 1e-10]


def timed(fn):
    tic = time.perf_counter()
    out = fn()
    return out, time.perf_counter() - tic


def bench(name: str, fmu_dir: Path | None, scale: float, engines: set[str], tolerance: float) -> dict:
    s = read_scenario(ROOT / "scenarios" / name, fmu_dir=fmu_dir)
    h = s.step_size
    t_end = max(h, round(s.stop_time * scale / h) * h)
    n = samples_for(t_end, h, 2001)
    q_scale = position_scale(s)
    truth = monolithic(s, stop_time=t_end, n_samples=n)
    row = {"name": name, "h": h, "t_end": t_end}

    timing = {}
    r, row["t_master"] = timed(lambda: simulate(s, stop_time=t_end, record=["plant.q"], timing=timing))
    row["e_master"] = position_error(r.time, r["plant.q"], truth, q_scale)
    row["overhead"] = timing["overhead_per_fmu_step"]
    row["per_fmu"] = timing["per_fmu"]
    row["steps"] = timing["steps"]

    goal = max(row["e_master"], 1e-6)
    loop = monolithic_loop(s)
    from components.monolithic import simulate as mono
    for rtol in RTOLS:
        res, t_mono = timed(lambda: mono(loop.controller, loop.eta0, t_end, reference=loop.reference,
                                         n_samples=n, rtol=rtol, scale=truth.scale))
        if res.success and np.max(np.abs(res.q - truth.q)) / q_scale <= goal:
            row["t_mono"], row["rtol_mono"] = t_mono, rtol
            break
    else:
        row["t_mono"], row["rtol_mono"] = t_mono, rtol

    if "adaptive" in engines:
        try:
            r, row["t_adaptive"] = timed(lambda: simulate(s, stop_time=t_end, step_size=h * 64,
                                                          tolerance=tolerance, record=["plant.q"]))
            # at the adaptive run's own communication points, against the (dense) truth interpolated there:
            # interpolating the sparse adaptive grid instead would measure the grid, not the run
            row["e_adaptive"] = float(np.max(np.abs(r["plant.q"] - np.interp(r.time, truth.t, truth.q))) / q_scale)
            row["n_adaptive"] = len(r) - 1
        except ScenarioError as exc:
            row["adaptive_note"] = str(exc).split(":")[0]
    if "container" in engines:
        from fmpy import simulate_fmu
        from emcosim.engine.container import export_container
        with tempfile.TemporaryDirectory() as tmp:
            fmu = export_container(s, Path(tmp) / "loop.fmu")
            c, row["t_container"] = timed(lambda: simulate_fmu(str(fmu), stop_time=t_end, output_interval=h,
                                                               output=["plant.q"]))
        row["e_container"] = position_error(c["time"], c["plant.q"], truth, q_scale)
    if "libcosim" in engines:
        from emcosim.engine.libcosim import _simulate as libcosim_here     # in this process: the engine's time only
        lc, row["t_libcosim"] = timed(lambda: libcosim_here(s, t_end, None, None, ["plant.q"]))
        row["e_libcosim"] = position_error(lc.time, lc["plant.q"], truth, q_scale)
    return row


def verdict(row: dict) -> str:
    """What dominates the master's cost, when it misses a target."""
    notes = []
    ratio = row["t_master"] / row["t_mono"]
    if ratio > RATIO_TARGET:
        fmu = max(row["per_fmu"], key=row["per_fmu"].get)
        share = row["per_fmu"][fmu] / row["t_master"]
        per_step = row["per_fmu"][fmu] / row["steps"] * 1e6
        notes.append(f"misses {RATIO_TARGET:g}x: {fmu} takes {100 * share:.0f}% ({per_step:.0f} us/step over "
                     f"{row['steps']} fixed steps of {row['h']:g} s, sized for the fastest transient)")
    if row["overhead"] > OVERHEAD_TARGET:
        notes.append(f"overhead {row['overhead'] * 1e6:.1f} us > {OVERHEAD_TARGET * 1e6:g} us per FMU per step")
    return "; ".join(notes) or "meets targets"


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--scenarios", help="comma-separated names (default: all paper scenarios)")
    p.add_argument("--horizon-scale", type=float, default=1.0, help="fraction of each scenario's horizon")
    p.add_argument("--fmu-dir", type=Path, help="FMU folder (default: the scenarios' build/fmus)")
    p.add_argument("--engines", default="adaptive,container,libcosim", help="which engines besides the master")
    p.add_argument("--tolerance", type=float, default=1e-5, help="tolerance of the error-controlled master")
    args = p.parse_args(argv)
    names = args.scenarios.split(",") if args.scenarios else [c.name for c in paper_scenarios.cases()]
    engines = set(args.engines.split(",")) if args.engines else set()
    cols = ("scenario", "h [s]", "err master", "mono [s] (rtol)", "master x", "ovh us/FMU/step",
            "adaptive x (err)", "container x (err)", "libcosim x (err)")
    print(" | ".join(cols))
    print(" | ".join("---" for _ in cols))
    rows = []
    for name in names:
        row = bench(name, args.fmu_dir, args.horizon_scale, engines, args.tolerance)
        rows.append(row)
        m = row["t_mono"]

        def ratio(key, err):
            if f"t_{key}" not in row:
                return row.get(f"{key}_note", "n/a")
            return f"{row[f't_{key}'] / m:.2f} ({row[err]:.1e})"
        print(" | ".join([name, f"{row['h']:g}", f"{row['e_master']:.1e}", f"{m:.2f} ({row['rtol_mono']:g})",
                          f"{row['t_master'] / m:.2f}", f"{row['overhead'] * 1e6:.1f}",
                          ratio("adaptive", "e_adaptive"), ratio("container", "e_container"),
                          ratio("libcosim", "e_libcosim")]), flush=True)
    print()
    for row in rows:
        print(f"{row['name']}: {verdict(row)}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
