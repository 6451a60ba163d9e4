"""Cost of the integrity checks of issue 15, measured side by side in one run (interleaved repeats,
the median of each): the master's own overhead per FMU per communication step, and the wall time of
a run, for

  memory     rows kept in memory (the Python API's default), non-finite check on
  streamed   rows streamed to a CSV through outputs.ResultFile (what `emcosim run` does)
  unchecked  rows in memory, the non-finite check switched off (monkeypatched: the cost of the check)

on the toy loop of the tests (two trivial FMUs: the master's own cost dominates) and a paper scenario.

    python benchmarks/bench_integrity.py [--repeats 5] [--fmu-dir DIR]
"""
from __future__ import annotations

import argparse
import statistics
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from emcosim.engine import master  # noqa: E402
from emcosim.engine.outputs import ResultFile  # noqa: E402
from emcosim.engine.ssd import read_scenario  # noqa: E402
from emcosim.engine.transfer import Transfer  # noqa: E402
from tests.integrity_helpers import build_toys, toy_loop  # noqa: E402


def one(scenario, mode: str, folder: Path, stop_time: float | None) -> tuple[float, float]:
    timing: dict = {}
    original = Transfer.check_finite
    if mode == "unchecked":
        Transfer.check_finite = lambda self: None
    try:
        tic = time.perf_counter()
        if mode == "streamed":
            with ResultFile(folder / "r.csv") as sink:
                master.simulate(scenario, stop_time=stop_time, sink=sink, timing=timing)
        else:
            master.simulate(scenario, stop_time=stop_time, timing=timing)
        return time.perf_counter() - tic, timing["overhead_per_fmu_step"]
    finally:
        Transfer.check_finite = original


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--repeats", type=int, default=5)
    ap.add_argument("--fmu-dir", default=str(ROOT / "build" / "fmus"))
    args = ap.parse_args()
    with tempfile.TemporaryDirectory() as d:
        folder = Path(d)
        toys = build_toys(folder / "toys")
        cases = {"toy loop, 20000 steps": (read_scenario(toy_loop(folder / "loop", toys, stop_time=200.0)), None),
                 "maglev_tracking_D0_R2.82, 2 s": (read_scenario(ROOT / "scenarios" / "maglev_tracking_D0_R2.82",
                                                                 fmu_dir=args.fmu_dir), 2.0)}
        modes = ["memory", "streamed", "unchecked"]
        print(f"{'case':32} {'mode':10} {'wall [s]':>9} {'overhead [us/FMU/step]':>23} {'ratio to memory':>16}")
        for label, (scenario, stop) in cases.items():
            walls = {m: [] for m in modes}
            overheads = {m: [] for m in modes}
            for _ in range(args.repeats):
                for m in modes:
                    wall, overhead = one(scenario, m, folder, stop)
                    walls[m].append(wall)
                    overheads[m].append(overhead)
            base = statistics.median(walls["memory"])
            for m in modes:
                w = statistics.median(walls[m])
                print(f"{label:32} {m:10} {w:9.3f} {1e6 * statistics.median(overheads[m]):23.2f} {w / base:16.3f}")


if __name__ == "__main__":
    main()
