"""Figures and numbers of docs/reliability.md.

Runs the 1000-lifecycle loop of every FMU (tests/reliability/fmu_worker.py, one process per FMU), plots
the resident memory against the iteration to docs/figures/reliability_rss.png, and prints the growth
per FMU and the case counts of the last reliability test session (build/reliability/counts.json,
written by `pytest -m reliability`).

    .venv/bin/python benchmarks/reliability_report.py [--fmu-dir build/fmus] [-n 1000]
"""
from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from tests.reliability.harness import ALL, RESULTS_JSON, run_worker_once  # noqa: E402


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--fmu-dir", default=str(ROOT / "build" / "fmus"))
    ap.add_argument("-n", type=int, default=1000)
    ap.add_argument("--figure", default=str(ROOT / "docs" / "figures" / "reliability_rss.png"))
    args = ap.parse_args()
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(7, 4))
    print(f"{'FMU':<22}{'RSS before':>12}{'after':>10}{'growth':>12}{'per lifecycle':>15}{'time':>8}")
    for identifier in ALL:
        r = run_worker_once("lifecycle", {"fmu": str(Path(args.fmu_dir) / f"{identifier}.fmu"), "n": args.n,
                                          "h": {"MEMS": 1e-6, "Maglev": 1e-3, "Reference": 1e-3}.get(identifier, 1e-6),
                                          "every": 10, "warmup": 20,
                                          "inputs": {"u": 25.0} if identifier == "MEMS"
                                          else {"u": 0.02} if identifier == "Maglev" else {}})
        assert r["ok"], r
        it = [s[0] for s in r["samples"]]
        rss = [(s[1] - r["rss_before"]) / 2**20 for s in r["samples"]]
        ax.plot(it, rss, label=identifier)
        print(f"{identifier:<22}{r['rss_before'] / 2**20:>10.1f}Mi{r['rss_after'] / 2**20:>8.1f}Mi"
              f"{r['growth'] / 2**20:>10.2f}Mi{r['growth'] / 1024 / args.n:>12.2f}KiB{r['seconds']:>7.1f}s")
    ax.axhline(16, color="k", ls="--", lw=0.8, label="test bound (16 MiB / 1000)")
    ax.set_xlabel("lifecycle (instantiate, initialize, 3 steps, free)")
    ax.set_ylabel("RSS growth [MiB]")
    ax.set_title("Resident memory over FMU lifecycles in one process (pythonfmu 0.7.0)")
    ax.legend(fontsize=7, ncol=2)
    fig.tight_layout()
    fig.savefig(args.figure, dpi=110)
    print(f"figure: {args.figure}")
    if RESULTS_JSON.is_file():
        d = json.loads(RESULTS_JSON.read_text())
        print(f"last reliability session ({RESULTS_JSON}): {json.dumps(d['totals'])}, {d['seconds']} s")
        for group, subjects in d["counts"].items():
            for subject, outcomes in subjects.items():
                print(f"  {group:<20}{subject:<40}{json.dumps(outcomes)}")
    else:
        print("no case counts yet: run `pytest -m reliability`")


if __name__ == "__main__":
    main()
