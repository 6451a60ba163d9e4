"""The results of `emcosim sweep`: a table (CSV, Markdown, JSON) and plots of each metric over the grid.

Table: one row per run, with the swept parameter values, the metrics of the reproduce report and
'status' ('ok' or the run's error). Plots (PNG): for a 1-D grid one figure with a panel per metric
over the swept parameter; for a 2-D grid one heatmap per metric, on a log colour scale where the
values span more than a decade, with ticks at the grid values. With random plant samples, a grid
point shows the mean over its samples (1-D: plus the min-max band). A run whose error never stays in
the 2 % band within the horizon (settling time inf, or equal to the horizon) is marked "not reached"
(report.NOT_REACHED, the words of the reproduce report and of the table) rather than plotted as a
number; failed runs are left out of the plots and listed in the table.
Each PNG carries what it shows (grid, values, labels) as JSON in its 'Description' metadata.
"""
from __future__ import annotations

import csv
import json
import math
from pathlib import Path

import numpy as np

from ..engine.doubling import THRESHOLD
from .report import NOT_REACHED, finite_or_none, settling_text

METRICS = ["settling_time_2pct", "overshoot", "oscillations", "ise", "final_error", "max_abs_u"]
"""The metrics of report.run_metrics put in the table (initial_error is kept too, not plotted)."""

METRIC_LABELS = {
    "settling_time_2pct": ("time into the 2 % band", "s"),
    "overshoot": ("overshoot (% of |e(0)|)", "%"),
    "oscillations": ("oscillations (sign changes of e)", "1"),
    "ise": ("ISE = integral of e^2", "m^2 s"),
    "final_error": ("final position error e(T)", "m"),
    "max_abs_u": ("peak input max |u|", "V"),
    "initial_error": ("initial position error e(0)", "m"),
}


def columns(rows: list[dict]) -> list[str]:
    """Column order: parameters (as in the runs), metrics, the estimated coupling error, status."""
    params = [k for k in rows[0] if k not in METRIC_LABELS and k not in ("coupling_error", "status")]
    return ["run", *params, *METRIC_LABELS, "coupling_error", "status"]


def csv_cells(row: dict, cols: list[str]) -> list:
    """A table row as CSV cells: exact numbers (repr; inf = never settles in the band), "" for none."""
    return ["" if row.get(c) is None else (repr(row[c]) if isinstance(row[c], float) else row[c]) for c in cols]


def _settings(info: dict) -> str:
    """How every run of the sweep ran: its coupling, steps and horizon."""
    if info.get("interface_type") == "ModelExchange":
        parts = ["Model Exchange (the FMUs' states as one ODE)"]
    else:
        parts = [f"{info['coupling']} coupling" if info.get("coupling") else "the scenario's coupling"]
    if info.get("coupling_order") is not None:
        parts.append(f"coupling order {info['coupling_order']}")
    if info.get("tolerance") is not None:
        parts.append(f"error-controlled steps, tolerance {info['tolerance']:g}")
    else:
        parts.append(f"step {info['step_size']:g} s" if info.get("step_size") is not None else "the scenario's step")
    if info.get("stop_time") is not None:
        parts.append(f"stop time {info['stop_time']:g} s")
    return "Every run: " + ", ".join(parts) + "."


def write_table(rows: list[dict], out: Path, info: dict) -> list[Path]:
    """sweep.csv, sweep.md and sweep.json (rows + info) into `out`."""
    out.mkdir(parents=True, exist_ok=True)
    cols = columns(rows)
    table = [{"run": i, **{c: r.get(c) for c in cols[1:]}} for i, r in enumerate(rows)]
    with open(out / "sweep.csv", "w", newline="") as f:
        w = csv.writer(f)
        w.writerow(cols)
        for r in table:
            w.writerow(csv_cells(r, cols))
    units = info.get("units", {})
    head = [f"{c} [{units[c]}]" if units.get(c) else
            (f"{c} [{METRIC_LABELS[c][1]}]" if c in METRIC_LABELS else c) for c in cols]
    lines = [f"# Sweep of {info.get('scenario', '')}", "",
             f"{info.get('runs')} runs, {info.get('failed')} failed, {info.get('not_accepted', 0)} not accepted "
             f"(estimated coupling error above {info.get('error_threshold', THRESHOLD):g} of a variable's range), "
             f"{info.get('workers')} worker(s), "
             f"{info.get('runs_per_s', float('nan')):.3g} runs/s.", "", _settings(info), "",
             "| " + " | ".join(head) + " |", "|" + "---|" * len(cols)]
    lines += ["| " + " | ".join(_cell(r[c], c) for c in cols) + " |" for r in table]
    lines += ["", f"settling_time_2pct '{NOT_REACHED}': the error never stays in the 2 % band of |e(0)| within the "
                  "horizon (inf in sweep.csv, null in sweep.json)."]
    (out / "sweep.md").write_text("\n".join(lines) + "\n")
    clean = [finite_or_none(r) for r in table]                             # strict JSON: no Infinity/NaN
    (out / "sweep.json").write_text(json.dumps({"info": info, "rows": clean}, indent=1, default=str))
    return [out / "sweep.csv", out / "sweep.md", out / "sweep.json"]


def read_table(path: Path) -> list[dict]:
    """The rows of a sweep.csv (numbers as floats, status as text)."""
    with open(path, newline="") as f:
        rows = list(csv.DictReader(f))
    return [{k: (v if k == "status" else (float(v) if v != "" else None)) for k, v in r.items()} for r in rows]


def _cell(v, column: str = "") -> str:
    """A cell of the Markdown table (a time into the band as the reproduce report says it: settling_text)."""
    if v is None:
        return ""
    if isinstance(v, float) and column == "settling_time_2pct":
        return settling_text(v)
    if isinstance(v, float):
        return f"{v:.4g}"
    return str(v).replace("|", "/")


def replot(folder: Path, out: Path | None = None, prefix: str = "sweep", title: str = "") -> list[Path]:
    """Draw the plots again from a sweep's sweep.csv and sweep.json (e.g. with another title), into
    `out` (default: the same folder)."""
    folder = Path(folder)
    info = json.loads((folder / "sweep.json").read_text())["info"]
    return plot(read_table(folder / "sweep.csv"), info["grid"], info["units"], Path(out or folder), prefix, title,
                info.get("stop_time"))


# ---- plots ---------------------------------------------------------------------------------------

NOT_SETTLED = NOT_REACHED                 # a settling time inf or equal to the horizon, on a plot


def plot(rows: list[dict], grid: dict[str, list[float]], units: dict[str, str], out: Path,
         prefix: str = "sweep", title: str = "", horizon: float | None = None) -> list[Path]:
    """PNG plots of each metric over the grid (see module docstring); returns the files written.
    No plots for a sweep without a grid or with more than two grid axes. `horizon` [s]: a settling
    time equal to it counts as not settled."""
    import matplotlib
    matplotlib.use("Agg")

    names = list(grid)
    if len(names) == 1:
        return [_lines(rows, names[0], grid[names[0]], units, out / f"{prefix}_metrics.png", title, horizon)]
    if len(names) == 2:
        return [_heatmap(heatmap_data(rows, names, grid, units, m, horizon), out / f"{prefix}_{m}.png", title)
                for m in METRICS]
    return []


def _label(name: str, units: dict[str, str]) -> str:
    return f"{name} [{units[name]}]" if units.get(name) else name


def _metric_label(m: str) -> str:
    text, unit = METRIC_LABELS[m]
    return f"{text} [{unit}]"


def _not_settled(metric: str, value: float, horizon: float | None) -> bool:
    return metric == "settling_time_2pct" and (not math.isfinite(value) or
                                               (horizon is not None and value >= horizon * (1 - 1e-9)))


def _values_at(rows: list[dict], point: dict[str, float], metric: str, horizon: float | None = None
               ) -> tuple[np.ndarray, int]:
    """(finite values of `metric` of the ok runs at this grid point, how many of them did not settle)."""
    vals = [r[metric] for r in rows if r["status"] == "ok" and all(r[k] == v for k, v in point.items())]
    unsettled = sum(_not_settled(metric, v, horizon) for v in vals if v is not None)
    vals = np.array([v for v in vals if v is not None and not _not_settled(metric, v, horizon)], dtype=float)
    return vals[np.isfinite(vals)], unsettled


def _describe(data: dict) -> dict:
    """PNG metadata: the figure's data as JSON in 'Description' (strict JSON: null for n/a)."""
    return {"Description": json.dumps(finite_or_none(data), allow_nan=False)}


def _lines(rows, name, values, units, path: Path, title: str, horizon: float | None) -> Path:
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(2, 3, figsize=(13, 6.5), sharex=True)
    x = np.array(values)
    any_failed = False
    meta = {"x": {"name": name, "unit": units.get(name, ""), "values": list(values)}, "panels": {}}
    for ax, m in zip(axes.ravel(), METRICS):
        stats = [_values_at(rows, {name: v}, m, horizon) for v in values]
        mean = np.array([s.mean() if s.size else np.nan for s, _ in stats])
        ax.plot(x, mean, "o-", color="#0072B2", lw=1.3, ms=4)
        if any(s.size > 1 for s, _ in stats):
            lo = np.array([s.min() if s.size else np.nan for s, _ in stats])
            hi = np.array([s.max() if s.size else np.nan for s, _ in stats])
            ax.fill_between(x, lo, hi, color="#0072B2", alpha=0.2, label="min-max over plant samples")
            ax.legend(fontsize=7)
        unsettled = [v for v, (s, u) in zip(values, stats) if u and not s.size]
        for v in unsettled:
            ax.annotate(NOT_SETTLED, (v, 1.0), xycoords=("data", "axes fraction"), ha="center", va="top",
                        fontsize=7, color="#D55E00", rotation=90)
        failed = [v for v, (s, u) in zip(values, stats) if s.size == 0 and not u]
        for v in failed:
            ax.axvline(v, color="#D55E00", lw=0.8, ls=":")
        any_failed = any_failed or bool(failed)
        ax.set_ylabel(_metric_label(m), fontsize=9)
        ax.grid(alpha=0.3)
        if len(values) <= 12:
            ax.set_xticks(x, [f"{v:g}" for v in values])
        meta["panels"][m] = {"label": _metric_label(m), "mean": list(mean), "not_settled_at": unsettled,
                             "failed_at": failed}
    for ax in axes[-1]:
        ax.set_xlabel(_label(name, units))
    fig.suptitle(title + ("   (dotted: run failed or not accepted, or metric not finite)" if any_failed else ""), fontsize=10)
    fig.tight_layout()
    fig.savefig(path, dpi=100, metadata=_describe(meta))
    plt.close(fig)
    return path


def heatmap_data(rows: list[dict], names: list[str], grid: dict[str, list[float]], units: dict[str, str],
                 metric: str, horizon: float | None = None) -> dict:
    """What the heatmap of `metric` over a 2-D grid shows: the mean value per cell (None where there
    is none), the text of each cell (the value, 'not reached' or 'n/a'), whether the colour scale is
    logarithmic (the finite values span more than a decade), the axes with their ticks (the grid
    values) and labels."""
    xs, ys = list(grid[names[0]]), list(grid[names[1]])
    z = np.full((len(ys), len(xs)), np.nan)
    text = [["n/a"] * len(xs) for _ in ys]
    for i, y in enumerate(ys):
        for j, x in enumerate(xs):
            s, unsettled = _values_at(rows, {names[0]: x, names[1]: y}, metric, horizon)
            if s.size:
                z[i, j] = s.mean()
                text[i][j] = f"{z[i, j]:.3g}" + (f" ({unsettled} {NOT_SETTLED})" if unsettled else "")
            elif unsettled:
                text[i][j] = NOT_SETTLED
    finite = np.abs(z[np.isfinite(z)])
    nonzero = finite[finite > 0]
    spans = bool(nonzero.size and nonzero.max() / nonzero.min() > 10)
    scale = "linear"
    if spans:
        scale = "log" if np.all(z[np.isfinite(z)] > 0) else "symlog"
    return {"metric": metric, "label": _metric_label(metric), "title": METRIC_LABELS[metric][0],
            "x": {"name": names[0], "label": _label(names[0], units), "ticks": xs},
            "y": {"name": names[1], "label": _label(names[1], units), "ticks": ys},
            "values": z, "text": text, "scale": scale}


def _heatmap(data: dict, path: Path, title: str) -> Path:
    import matplotlib.pyplot as plt
    from matplotlib.colors import LogNorm, SymLogNorm

    xs, ys, z = data["x"]["ticks"], data["y"]["ticks"], data["values"]
    finite = z[np.isfinite(z)]
    norm = None
    if data["scale"] == "log":
        norm = LogNorm(finite.min(), finite.max())
    elif data["scale"] == "symlog":
        small = np.abs(finite[finite != 0]).min()
        norm = SymLogNorm(linthresh=small, vmin=finite.min(), vmax=finite.max())
    fig, ax = plt.subplots(figsize=(6.8, 5.0))
    mesh = ax.pcolormesh(_edges(xs), _edges(ys), np.ma.masked_invalid(z), norm=norm, cmap="viridis", shading="flat")
    fig.colorbar(mesh, ax=ax, label=data["label"] + (" (log scale)" if data["scale"] != "linear" else ""))
    ax.set_xticks(xs, [f"{v:g}" for v in xs])
    ax.set_yticks(ys, [f"{v:g}" for v in ys])
    if len(xs) * len(ys) <= 100:
        for i, y in enumerate(ys):
            for j, x in enumerate(xs):
                ok = np.isfinite(z[i, j])
                bright = ok and mesh.norm(z[i, j]) > 0.6             # viridis is light at the top
                ax.text(x, y, data["text"][i][j].replace(" (", "\n("), ha="center", va="center", fontsize=7,
                        color="black" if bright else ("white" if ok else "#D55E00"))
    ax.set_xlabel(data["x"]["label"])
    ax.set_ylabel(data["y"]["label"])
    missing = not np.all(np.isfinite(z))
    sub = data["title"] + (f"\n(blank: {NOT_SETTLED} within the horizon, or n/a: run failed)" if missing else "")
    ax.set_title(f"{title}\n{sub}" if title else sub, fontsize=10)
    fig.tight_layout()
    fig.savefig(path, dpi=100, metadata=_describe(data))
    plt.close(fig)
    return path


def _edges(values: list[float]) -> np.ndarray:
    """Cell edges around the grid values (midpoints; half a spacing beyond the ends)."""
    v = np.asarray(values, dtype=float)
    if v.size == 1:
        return np.array([v[0] - 0.5, v[0] + 0.5]) if v[0] == 0 else np.array([0.5 * v[0], 1.5 * v[0]])
    mid = 0.5 * (v[1:] + v[:-1])
    return np.concatenate([[v[0] - (mid[0] - v[0])], mid, [v[-1] + (v[-1] - mid[-1])]])
