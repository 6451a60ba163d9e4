"""Throughput of `emcosim sweep` (runs per second) with 1 and 2 local dask workers, side by side.

    .venv/bin/python benchmarks/bench_sweep.py [--runs 24] [--stop-time 0.5] [--repeat 2] [--scenario NAME]

What is measured: for each worker count, a LocalCluster (processes, one thread each) is started and
warmed up first (every worker makes runs until each has loaded the FMUs once); then the clock runs
from submitting `--runs` grid points of controller.D_d until the last row is back. Cluster start-up
and FMU loading are therefore excluded (they are reported separately). The two worker counts are
measured alternately `--repeat` times and the best of each is compared, which filters out
moments when other processes on a shared machine take a core; the CPU share the workers got
is printed beside each measurement. Target: 2 workers at least
1.7x the throughput of 1 worker on a 2-core machine.

Also measured, in this process: the cost of one run with `master.simulate` (unpack and instantiate
every FMU per run) against a `Session` (instantiate once, fmi2Reset between runs), the choice the
sweep workers make.
"""
from __future__ import annotations

import argparse
import os
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from emcosim.engine.master import simulate  # noqa: E402
from emcosim.engine.session import Session  # noqa: E402
from emcosim.engine.ssd import read_scenario  # noqa: E402
from emcosim.paper.sweep import close_on_workers, dask_client, run_all  # noqa: E402


def throughput(ssd: str, fmu_dir: str, workers: int, values: list[float], stop_time: float) -> dict:
    """Runs/s of a D_d grid on a fresh local cluster of `workers` processes (start-up excluded)."""
    tic = time.perf_counter()
    with dask_client(workers) as client:
        started = time.perf_counter()
        warm = [{"controller.D_d": 0.0}] * (2 * workers)
        while True:                                  # until every worker has made a run
            done = run_all(client, ssd, fmu_dir, warm, stream=None, stop_time=stop_time)
            assert all(r["status"] == "ok" for r in done), done
            if _workers_with_sessions(client) >= workers:
                break
        warmed = time.perf_counter()
        runs = [{"controller.D_d": float(v)} for v in values]
        cpu0 = client.run(time.process_time)
        t0 = time.perf_counter()
        rows = run_all(client, ssd, fmu_dir, runs, stream=None, stop_time=stop_time)
        elapsed = time.perf_counter() - t0
        cpu1 = client.run(time.process_time)
        close_on_workers(client)
    failed = sum(r["status"] != "ok" and not r["status"].startswith("not accepted: ") for r in rows)   # not errors
    return {"workers": workers, "runs": len(rows), "failed": failed, "seconds": elapsed,
            "runs_per_s": len(rows) / elapsed, "startup_s": started - tic, "warmup_s": warmed - started,
            "cpu_share": sum(cpu1[w] - cpu0[w] for w in cpu1) / (elapsed * workers)}


def _workers_with_sessions(client) -> int:
    from emcosim.paper import sweep
    counts = client.run(sweep.session_count)
    return sum(1 for n in counts.values() if n > 0)


def reuse_gain(scenario_name: str, fmu_dir: str, stop_time: float, n: int = 6) -> dict:
    """Wall time per run in this process: simulate() per run vs one Session reused."""
    s = read_scenario(ROOT / "scenarios" / scenario_name, fmu_dir=fmu_dir)
    simulate(s, stop_time=stop_time)                  # imports, caches
    tic = time.perf_counter()
    for i in range(n):
        simulate(s, stop_time=stop_time, start_values={"controller.D_d": -0.1 * i})
    per_simulate = (time.perf_counter() - tic) / n
    with Session(s) as session:
        session.run({}, stop_time=stop_time)
        tic = time.perf_counter()
        for i in range(n):
            session.run({"controller.D_d": -0.1 * i}, stop_time=stop_time)
        per_session = (time.perf_counter() - tic) / n
    return {"simulate_s": per_simulate, "session_s": per_session}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--scenario", default="maglev_tracking_D0_R0.82")
    ap.add_argument("--runs", type=int, default=16)
    ap.add_argument("--stop-time", type=float, default=2.0, help="horizon of each run [s] (runs of about 0.7 s wall time)")
    ap.add_argument("--fmu-dir", default=str(ROOT / "build" / "fmus"))
    ap.add_argument("--repeat", type=int, default=2, help="measurements per worker count (best is kept)")
    args = ap.parse_args()
    ssd = str(read_scenario(ROOT / "scenarios" / args.scenario, fmu_dir=args.fmu_dir).path.resolve())
    values = list(np.linspace(-0.8, 0.0, args.runs))
    print(f"scenario {args.scenario}, {args.runs} runs of {args.stop_time} s (D_d grid), "
          f"cluster start-up and FMU loading excluded")
    load0 = os.getloadavg()[0]
    measured = [throughput(ssd, args.fmu_dir, w, values, args.stop_time)
                for _ in range(args.repeat) for w in (1, 2)]         # interleaved: 1, 2, 1, 2, ...
    print(f"{'workers':>8} {'runs':>5} {'failed':>6} {'time [s]':>9} {'runs/s':>8} {'start-up [s]':>13} "
          f"{'warm-up [s]':>12} {'CPU share':>10}")
    for r in measured:
        print(f"{r['workers']:>8} {r['runs']:>5} {r['failed']:>6} {r['seconds']:>9.2f} {r['runs_per_s']:>8.3f} "
              f"{r['startup_s']:>13.2f} {r['warmup_s']:>12.2f} {r['cpu_share']:>10.2f}")
    best = {w: max(r["runs_per_s"] for r in measured if r["workers"] == w) for w in (1, 2)}
    ratio = best[2] / best[1]
    print(f"best of {args.repeat}: 1 worker {best[1]:.3f} runs/s, 2 workers {best[2]:.3f} runs/s; "
          f"ratio {ratio:.2f}x (target >= 1.7x): {'met' if ratio >= 1.7 else 'NOT met'}")
    print(f"load average (1 min) before / after: {load0:.2f} / {os.getloadavg()[0]:.2f} on {os.cpu_count()} cores")
    print("CPU share = CPU time the workers got / (wall time x workers): below about 0.9, other processes "
          "took cores and the ratio measures the machine's load, not the engine")
    short = 5e-4 if args.scenario.startswith("mems") else 0.05
    for horizon in (short, args.stop_time):
        g = reuse_gain(args.scenario, args.fmu_dir, horizon)
        print(f"one run of {horizon:g} s in one process: simulate() {1e3 * g['simulate_s']:.0f} ms, "
              f"Session (fmi2Reset) {1e3 * g['session_s']:.0f} ms")


if __name__ == "__main__":
    main()
