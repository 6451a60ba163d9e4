"""The results of `emcosim sweep`: a table (CSV, Markdown, JSON) and plots of each metric over the grid.

Table: one row per run, with the swept parameter values, the metrics of the reproduce report and
'status' ('ok' or the run's error). Plots (PNG): for a 1-D grid one figure with a panel per metric
over the swept parameter; for a 2-D grid one heatmap per metric. With random plant samples, a grid
point shows the mean over its samples (1-D: plus the min-max band). Failed runs are left out of the
plots (blank cells) and listed in the table.
"""
from __future__ import annotations

import csv
import json
import math
from pathlib import Path

import numpy as np

from .sweep import METRICS

METRIC_LABELS = {
    "settling_time_2pct": ("time into the 2 % band", "s"),
    "overshoot": ("overshoot (fraction of |e(0)|)", "1"),
    "oscillations": ("oscillations (sign changes of e)", "1"),
    "ise": ("ISE = integral of e^2", "m^2 s"),
    "final_error": ("final position error e(T)", "m"),
    "max_abs_u": ("peak input max |u|", "V"),
    "initial_error": ("initial position error e(0)", "m"),
}


def columns(rows: list[dict]) -> list[str]:
    """Column order: parameters (as in the runs), metrics, status."""
    params = [k for k in rows[0] if k not in METRIC_LABELS and k != "status"]
    return ["run", *params, *METRIC_LABELS, "status"]


def write_table(rows: list[dict], out: Path, info: dict) -> list[Path]:
    """sweep.csv, sweep.md and sweep.json (rows + info) into `out`."""
    out.mkdir(parents=True, exist_ok=True)
    cols = columns(rows)
    table = [{"run": i, **{c: r.get(c) for c in cols[1:]}} for i, r in enumerate(rows)]
    with open(out / "sweep.csv", "w", newline="") as f:      # exact numbers (repr); inf = never in the band
        w = csv.writer(f)
        w.writerow(cols)
        for r in table:
            w.writerow(["" if r[c] is None else (repr(r[c]) if isinstance(r[c], float) else r[c]) for c in cols])
    units = info.get("units", {})
    head = [f"{c} [{units[c]}]" if units.get(c) else
            (f"{c} [{METRIC_LABELS[c][1]}]" if c in METRIC_LABELS else c) for c in cols]
    lines = [f"# Sweep of {info.get('scenario', '')}", "",
             f"{info.get('runs')} runs, {info.get('failed')} failed, {info.get('workers')} worker(s), "
             f"{info.get('runs_per_s', float('nan')):.3g} runs/s.", "",
             "| " + " | ".join(head) + " |", "|" + "---|" * len(cols)]
    lines += ["| " + " | ".join(_cell(r[c]) for c in cols) + " |" for r in table]
    (out / "sweep.md").write_text("\n".join(lines) + "\n")
    clean = [{k: _finite_or_none(v) for k, v in r.items()} for r in table]     # strict JSON: no Infinity/NaN
    (out / "sweep.json").write_text(json.dumps({"info": info, "rows": clean}, indent=1, default=str))
    return [out / "sweep.csv", out / "sweep.md", out / "sweep.json"]


def read_table(path: Path) -> list[dict]:
    """The rows of a sweep.csv (numbers as floats, status as text)."""
    with open(path, newline="") as f:
        rows = list(csv.DictReader(f))
    return [{k: (v if k == "status" else (float(v) if v != "" else None)) for k, v in r.items()} for r in rows]


def _cell(v) -> str:
    if v is None:
        return ""
    if isinstance(v, float):
        return f"{v:.4g}"
    return str(v).replace("|", "/")


def _finite_or_none(v):
    """JSON value: non-finite numbers (a metric of a run that never enters the band) become null."""
    return None if isinstance(v, float) and not math.isfinite(v) else v


def replot(folder: Path, out: Path | None = None, prefix: str = "sweep", title: str = "") -> list[Path]:
    """Draw the plots again from a sweep's sweep.csv and sweep.json (e.g. with another title), into
    `out` (default: the same folder)."""
    folder = Path(folder)
    info = json.loads((folder / "sweep.json").read_text())["info"]
    return plot(read_table(folder / "sweep.csv"), info["grid"], info["units"], Path(out or folder), prefix, title)


# ---- plots ---------------------------------------------------------------------------------------

def plot(rows: list[dict], grid: dict[str, list[float]], units: dict[str, str], out: Path,
         prefix: str = "sweep", title: str = "") -> list[Path]:
    """PNG plots of each metric over the grid (see module docstring); returns the files written.
    No plots for a sweep without a grid or with more than two grid axes."""
    import matplotlib
    matplotlib.use("Agg")

    names = list(grid)
    if len(names) == 1:
        return [_lines(rows, names[0], grid[names[0]], units, out / f"{prefix}_metrics.png", title)]
    if len(names) == 2:
        return [_heatmap(rows, names, grid, units, m, out / f"{prefix}_{m}.png", title) for m in METRICS]
    return []


def _label(name: str, units: dict[str, str]) -> str:
    return f"{name} [{units[name]}]" if units.get(name) else name


def _metric_label(m: str) -> str:
    text, unit = METRIC_LABELS[m]
    return f"{text} [{unit}]"


def _values_at(rows: list[dict], point: dict[str, float], metric: str) -> np.ndarray:
    """The finite values of `metric` of the ok runs at this grid point (all its samples)."""
    vals = [r[metric] for r in rows if r["status"] == "ok" and all(r[k] == v for k, v in point.items())]
    vals = np.array(vals, dtype=float)
    return vals[np.isfinite(vals)]


def _lines(rows, name, values, units, path: Path, title: str) -> Path:
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(2, 3, figsize=(13, 6.5), sharex=True)
    x = np.array(values)
    any_failed = False
    for ax, m in zip(axes.ravel(), METRICS):
        stats = [_values_at(rows, {name: v}, m) for v in values]
        mean = np.array([s.mean() if s.size else np.nan for s in stats])
        ax.plot(x, mean, "o-", color="tab:blue", lw=1.3, ms=4)
        if any(s.size > 1 for s in stats):
            lo = np.array([s.min() if s.size else np.nan for s in stats])
            hi = np.array([s.max() if s.size else np.nan for s in stats])
            ax.fill_between(x, lo, hi, color="tab:blue", alpha=0.2, label="min-max over plant samples")
            ax.legend(fontsize=7)
        failed = [v for v, s in zip(values, stats) if s.size == 0]
        for v in failed:
            ax.axvline(v, color="tab:red", lw=0.8, ls=":")
        any_failed = any_failed or bool(failed)
        ax.set_ylabel(_metric_label(m), fontsize=9)
        ax.grid(alpha=0.3)
    for ax in axes[-1]:
        ax.set_xlabel(_label(name, units))
    fig.suptitle(title + ("   (dotted red: run failed or metric not finite)" if any_failed else ""), fontsize=10)
    fig.tight_layout()
    fig.savefig(path, dpi=100)
    plt.close(fig)
    return path


def _heatmap(rows, names, grid, units, metric: str, path: Path, title: str) -> Path:
    import matplotlib.pyplot as plt
    from matplotlib.colors import LogNorm

    xs, ys = grid[names[0]], grid[names[1]]
    z = np.full((len(ys), len(xs)), np.nan)
    for i, y in enumerate(ys):
        for j, x in enumerate(xs):
            s = _values_at(rows, {names[0]: x, names[1]: y}, metric)
            if s.size:
                z[i, j] = s.mean()
    fig, ax = plt.subplots(figsize=(6.4, 4.8))
    finite = z[np.isfinite(z)]
    norm = None
    if finite.size and finite.min() > 0 and finite.max() / finite.min() > 100:
        norm = LogNorm(finite.min(), finite.max())
    mesh = ax.pcolormesh(_edges(xs), _edges(ys), np.ma.masked_invalid(z), norm=norm, cmap="viridis",
                         shading="flat")
    fig.colorbar(mesh, ax=ax, label=_metric_label(metric))
    if len(xs) * len(ys) <= 100:
        for i, y in enumerate(ys):
            for j, x in enumerate(xs):
                ok = np.isfinite(z[i, j])
                bright = ok and mesh.norm(z[i, j]) > 0.6             # viridis is light at the top
                ax.text(x, y, f"{z[i, j]:.3g}" if ok else "n/a", ha="center", va="center", fontsize=7,
                        color="black" if bright else ("white" if ok else "tab:red"))
    ax.set_xlabel(_label(names[0], units))
    ax.set_ylabel(_label(names[1], units))
    sub = METRIC_LABELS[metric][0] + ("\n(n/a: run failed, or metric not finite, e.g. never in the band)" if not np.all(np.isfinite(z)) else "")
    ax.set_title(f"{title}\n{sub}" if title else sub, fontsize=10)
    fig.tight_layout()
    fig.savefig(path, dpi=100)
    plt.close(fig)
    return path


def _edges(values: list[float]) -> np.ndarray:
    """Cell edges around the grid values (midpoints; half a spacing beyond the ends)."""
    v = np.asarray(values, dtype=float)
    if v.size == 1:
        return np.array([v[0] - 0.5, v[0] + 0.5]) if v[0] == 0 else np.array([0.5 * v[0], 1.5 * v[0]])
    mid = 0.5 * (v[1:] + v[:-1])
    return np.concatenate([[v[0] - (mid[0] - v[0])], mid, [v[-1] + (v[-1] - mid[-1])]])
