"""`emcosim reproduce [--out DIR]`: build the FMUs if needed, run every paper scenario through the
co-simulation master, and write the paper's figures, a metrics table and a claims report.

Physics-aware (uses components/ for the targets eta*(t) and the metrics); the runs themselves are
plain co-simulations of the FMUs.
"""
from __future__ import annotations

import json
import sys
import time
from pathlib import Path

import numpy as np

from . import report
from .certify import design_from_scenario
from .master import simulate
from .progress import ProgressBar
from .ssd import read_scenario

ROOT = Path(__file__).resolve().parents[1]
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


def run_paper_scenarios(names: dict[str, str] = PAPER_CASES, stop_time: float | None = None,
                        out=sys.stderr, fmu_dir: str | Path | None = None
                        ) -> tuple[dict[str, report.Run], dict[str, float]]:
    """Run each scenario (at its default step and horizon unless stop_time is given)."""
    runs, walls = {}, {}
    for i, (role, name) in enumerate(names.items(), 1):
        scenario = read_scenario(SCENARIOS / name, fmu_dir=fmu_dir)
        bar = ProgressBar(f"[{i}/{len(names)}] {name}", stream=out)
        tic = time.perf_counter()
        result = simulate(scenario, stop_time=stop_time, progress=bar)
        bar.close()
        walls[name] = time.perf_counter() - tic
        print(f"[{i}/{len(names)}] {name}: {len(result)} communication points in {walls[name]:.1f} s",
              file=out, flush=True)
        runs[role] = run_from_result(name, LABELS.get(role, name), scenario, result)
    return runs, walls


def ensure_fmus(out=sys.stderr) -> None:
    """Build the FMUs with the project's build.py when any FMU a paper scenario needs is missing."""
    needed = {Path(c.source) for name in PAPER_CASES.values() for c in read_scenario(SCENARIOS / name).components}
    if all(p.is_file() for p in needed):
        return
    import runpy
    print("building the FMUs (build.py) ...", file=out, flush=True)
    runpy.run_path(str(ROOT / "build.py"), run_name="__main__")


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


def reproduce(out_dir: str | Path = "results", stop_time: float | None = None, out=sys.stderr,
              fmu_dir: str | Path | None = None) -> dict:
    out_path = Path(out_dir)
    out_path.mkdir(parents=True, exist_ok=True)
    runs, walls = run_paper_scenarios(stop_time=stop_time, out=out, fmu_dir=fmu_dir)
    figures = write_figures(runs, out_path)
    notes = []
    for name in PAPER_CASES.values():
        notes += [n for n in read_scenario(SCENARIOS / name).notes if n not in notes and "Generated by" not in n]
    content = report.write_reports({r.name: r for r in runs.values()},
                                   {role: runs[role].name for role in runs}, out_path, notes)
    (out_path / "runs.json").write_text(json.dumps({"wall_time_s": walls}, indent=1))
    print(f"wrote {len(figures)} figure files, metrics.md/json, claims.md/json to {out_path}", file=out)
    return content
