"""The paper's Section 7 as figures, a metrics table and a claims report, computed from time series.

Physics-aware (uses components/ for eta*(t) and the metrics); fed by the co-simulation master's
results in `emcosim reproduce`, and by the monolithic reference in the tests that check it.
"""
from __future__ import annotations

import json
from dataclasses import asdict, dataclass, field
from pathlib import Path

import numpy as np

from components import metrics


@dataclass
class Run:
    """One paper case: time series of the plant state, the input and the reference (SI units)."""

    name: str
    plant: str                     # "MEMS" or "Maglev"
    label: str                     # legend text, e.g. "D_d = 0"
    t: np.ndarray
    q: np.ndarray
    p: np.ndarray
    x_e: np.ndarray
    u: np.ndarray
    eta_star: np.ndarray           # (N, 3): target eta*(t) (or eta_d)

    @property
    def e(self) -> np.ndarray:
        """Position error q - q*."""
        return self.q - self.eta_star[:, 0]

    @property
    def error_norm(self) -> np.ndarray:
        """|eta(t) - eta*(t)|_2 in SI units: the 'L2-norm of the error' of the paper's Fig. 4."""
        return np.linalg.norm(np.column_stack([self.q, self.p, self.x_e]) - self.eta_star, axis=1)


@dataclass
class Metrics:
    settling_time_2pct: float      # s; first time after which |e| stays within 2 % of |e(0)|
    overshoot: float               # relative to |e(0)|
    oscillations: int              # sign changes of e outside the 2 % band
    ise: float                     # m^2 s, integral of e^2
    final_error: float             # m, e at the last sample
    max_abs_u: float               # V
    initial_error: float           # m


def run_metrics(run: Run) -> Metrics:
    e = run.e
    band = 0.02 * abs(e[0]) if e[0] != 0 else 0.02 * np.max(np.abs(e))
    return Metrics(metrics.settling_time(run.t, e, band), metrics.overshoot(e), metrics.oscillations(e, band),
                   metrics.ise(run.t, e), float(e[-1]), float(np.max(np.abs(run.u))), float(e[0]))


def metrics_table(runs: dict[str, Run]) -> tuple[str, dict]:
    """(Markdown table, JSON-able dict) of the metrics of every run."""
    data = {name: asdict(run_metrics(r)) for name, r in runs.items()}
    head = ("| case | time into 2 % band [s] | overshoot [%] | oscillations | ISE [m^2 s] | final error [m] "
            "| max abs u [V] |\n|---|---|---|---|---|---|---|")
    rows = [f"| {n} | {m['settling_time_2pct']:.4g} | {100 * m['overshoot']:.3g} | {m['oscillations']} | "
            f"{m['ise']:.3g} | {m['final_error']:.3g} | {m['max_abs_u']:.4g} |" for n, m in data.items()]
    return "\n".join([head, *rows]), data


@dataclass
class Claim:
    text: str                      # what Section 7 says
    holds: bool
    numbers: dict = field(default_factory=dict)
    where: str = ""                # where the paper says it


def _peak_ratio(run: Run, n: int = 8) -> float:
    """Error envelope at the end relative to the start (max |e| over the last and first of n windows)."""
    p = metrics.window_peaks(run.e, n)
    return float(p[-1] / p[0])


def _converges(run: Run) -> tuple[bool, dict]:
    r = _peak_ratio(run)
    return r < 0.6, {"final/initial error envelope": r}


def claims(runs: dict[str, Run], cases: dict[str, str]) -> list[Claim]:
    """Evaluate the Section 7 claims. `cases` maps roles to run names:
    mems_reg_0, mems_reg_1 (D_d = 0, -1), mems_track_0, mems_track_1 (D_d = 0, -0.4),
    maglev_1 .. maglev_4 (the paper's cases 1-4)."""
    out: list[Claim] = []
    M = {role: run_metrics(runs[name]) for role, name in cases.items() if name in runs}

    if {"mems_reg_0", "mems_reg_1"} <= M.keys():
        a, b = M["mems_reg_0"], M["mems_reg_1"]
        ok, nums = _converges(runs[cases["mems_reg_0"]])
        out.append(Claim("MEMS regulation, D_d = 0: the states converge to eta_d", ok, nums, "Sec. 7.1, Fig. 1"))
        out.append(Claim("MEMS regulation, D_d = 0: the transient oscillates before reaching eta_d",
                         a.oscillations >= 3, {"oscillations": a.oscillations, "overshoot": a.overshoot}, "Sec. 7.1"))
        out.append(Claim("MEMS regulation, D_d = -1: converges to eta_d with no oscillations (no overshoot)",
                         b.oscillations == 0 and b.overshoot < 0.02 and abs(b.final_error) < 0.02 * abs(b.initial_error),
                         {"oscillations": b.oscillations, "overshoot": b.overshoot,
                          "time into 2 % band [s]": b.settling_time_2pct}, "Sec. 7.1"))
    if {"mems_track_0", "mems_track_1"} <= M.keys():
        a, b = M["mems_track_0"], M["mems_track_1"]
        ok, nums = _converges(runs[cases["mems_track_0"]])
        out.append(Claim("MEMS tracking, D_d = 0: converges to the reference with oscillating responses",
                         ok and a.oscillations >= 3, {**nums, "oscillations": a.oscillations}, "Sec. 7.1, Fig. 2"))
        ok, nums = _converges(runs[cases["mems_track_1"]])
        out.append(Claim("MEMS tracking, D_d = -0.4: tracks q* without oscillations", ok and b.oscillations == 0,
                         {**nums, "oscillations": b.oscillations, "time into 2 % band [s]": b.settling_time_2pct},
                         "Sec. 7.1, Fig. 2"))
    roles = [f"maglev_{i}" for i in range(1, 5)]
    if set(roles) <= M.keys():
        R = {r: runs[cases[r]] for r in roles}
        conv = {r: _converges(R[r]) for r in roles}
        out.append(Claim("Maglev: all four cases converge to the desired trajectory",
                         all(c[0] for c in conv.values()),
                         {f"case {i + 1} final/initial envelope": conv[r][1]["final/initial error envelope"]
                          for i, r in enumerate(roles)}, "Sec. 7.2, Fig. 3"))
        osc = {r: M[r].oscillations for r in roles}
        out.append(Claim("Maglev: q oscillates less with coupled damping (case 3 < case 1, case 4 < case 2)",
                         osc["maglev_3"] < osc["maglev_1"] and osc["maglev_4"] < osc["maglev_2"],
                         {f"case {i + 1} oscillations": osc[r] for i, r in enumerate(roles)}, "Sec. 7.2"))
        ise = {r: M[r].ise for r in roles}
        out.append(Claim("Maglev: larger electrical damping (cases 2, 4) converges more slowly than cases 1, 3",
                         ise["maglev_2"] > ise["maglev_1"] and ise["maglev_4"] > ise["maglev_3"],
                         {f"case {i + 1} ISE [m^2 s]": ise[r] for i, r in enumerate(roles)}, "Sec. 7.2, Fig. 4"))
        early = {r: float(np.trapezoid(R[r].error_norm[R[r].t <= 0.25 * R[r].t[-1]],
                                       R[r].t[R[r].t <= 0.25 * R[r].t[-1]])) for r in roles}
        out.append(Claim("Maglev: coupled damping (cases 3, 4) reduces the error norm in the initial interval",
                         early["maglev_3"] < early["maglev_1"] and early["maglev_4"] < early["maglev_2"],
                         {f"case {i + 1} integral of |eta - eta*| over the first quarter": early[r]
                          for i, r in enumerate(roles)}, "Sec. 7.2, Fig. 4"))
        best = min(roles, key=lambda r: ise[r])
        out.append(Claim("Maglev: case 3 (coupled damping, R_e_bar = 0.82) has the smallest error",
                         best == "maglev_3", {"case with the smallest ISE": roles.index(best) + 1}, "Sec. 7.2"))
        out.append(Claim("Maglev: coupled damping helps more than larger electrical damping (case 3 better than case 2)",
                         ise["maglev_3"] < ise["maglev_2"], {"case 3 ISE": ise["maglev_3"], "case 2 ISE": ise["maglev_2"]},
                         "Sec. 7.2"))
    return out


def claims_markdown(cl: list[Claim]) -> str:
    lines = ["| claim (paper) | verdict | numbers |", "|---|---|---|"]
    for c in cl:
        nums = "; ".join(f"{k} = {v:.4g}" if isinstance(v, float) else f"{k} = {v}" for k, v in c.numbers.items())
        lines.append(f"| {c.text} ({c.where}) | {'holds' if c.holds else '**does not hold**'} | {nums} |")
    return "\n".join(lines)


# ---- figures -----------------------------------------------------------------------------------

UNITS = {"MEMS": {"q": "m", "p": "kg m/s", "x_e": "C", "u": "V"},
         "Maglev": {"q": "m", "p": "kg m/s", "x_e": "Wb", "u": "V"}}
NAMES = {"q": "position q", "p": "momentum p", "x_e": "electrical state x_e", "u": "input u"}
COLORS = ["tab:orange", "tab:red", "tab:blue", "tab:green"]


def figure_states(runs: list[Run], title: str, path_stem: Path, star_label: str) -> list[Path]:
    """Four panels (q, p, x_e, u) with every run overlaid and the target dashed."""
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(2, 2, figsize=(11, 7), sharex=True)
    units = UNITS[runs[0].plant]
    for k, (ax, var) in enumerate(zip(axes.ravel(), ["q", "p", "x_e", "u"])):
        for i, r in enumerate(runs):
            ax.plot(r.t, getattr(r, var), color=COLORS[i % 4], lw=1.2, label=r.label)
        if var != "u":
            ax.plot(runs[0].t, runs[0].eta_star[:, ["q", "p", "x_e"].index(var)], "k--", lw=0.9, label=star_label)
        ax.set_ylabel(f"{NAMES[var]} [{units[var]}]")
        ax.grid(alpha=0.3)
        if k >= 2:
            ax.set_xlabel("time t [s]")
    axes[0, 0].legend(fontsize=8)
    fig.suptitle(title)
    fig.tight_layout()
    return _save(fig, path_stem)


def figure_error_norms(runs: list[Run], control_run: Run, path_stem: Path) -> list[Path]:
    """Paper's Fig. 4: error norms of the four maglev cases (top), u of case 3 (bottom left),
    position errors (bottom right)."""
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig = plt.figure(figsize=(11, 7))
    top = fig.add_subplot(2, 1, 1)
    for i, r in enumerate(runs):
        top.semilogy(r.t, r.error_norm, color=COLORS[i % 4], lw=1.2, label=r.label)
    top.set_ylabel("|eta - eta*|_2 (SI)")
    top.set_xlabel("time t [s]")
    top.set_title("Error norms, maglev tracking")
    top.grid(alpha=0.3, which="both")
    top.legend(fontsize=8)
    bl = fig.add_subplot(2, 2, 3)
    bl.plot(control_run.t, control_run.u, color=COLORS[2], lw=1.0)
    bl.set_title(f"Control signal, {control_run.label}")
    bl.set_xlabel("time t [s]")
    bl.set_ylabel("input u [V]")
    bl.grid(alpha=0.3)
    br = fig.add_subplot(2, 2, 4)
    for i, r in enumerate(runs):
        br.plot(r.t, r.e, color=COLORS[i % 4], lw=1.0, label=r.label)
    br.set_title("Position errors q - q*")
    br.set_xlabel("time t [s]")
    br.set_ylabel("q - q* [m]")
    br.grid(alpha=0.3)
    fig.tight_layout()
    return _save(fig, path_stem)


def _save(fig, stem: Path) -> list[Path]:
    import matplotlib.pyplot as plt
    paths = []
    for ext in ("png", "svg"):
        p = stem.with_suffix(f".{ext}")
        fig.savefig(p, dpi=110)
        paths.append(p)
    plt.close(fig)
    return paths


def write_reports(runs: dict[str, Run], cases: dict[str, str], out: Path, notes: list[str]) -> dict:
    """metrics.md/json and claims.md/json into `out`; returns the JSON-able content."""
    table_md, table = metrics_table(runs)
    cl = claims(runs, cases)
    (out / "metrics.md").write_text("# Metrics per case\n\nPosition error e = q - q*; band = 2 % of |e(0)|.\n\n"
                                    + table_md + "\n")
    (out / "metrics.json").write_text(json.dumps(table, indent=1))
    body = ["# Claims of Section 7, checked\n", "Each claim the paper makes about these runs, with the verdict the "
            "numbers give (our runs; where they disagree with the paper, we say so).\n", claims_markdown(cl), "",
            "## Choices the paper does not make\n", *[f"- {n}" for n in notes], ""]
    (out / "claims.md").write_text("\n".join(body))
    (out / "claims.json").write_text(json.dumps([asdict(c) for c in cl], indent=1, default=float))
    return {"metrics": table, "claims": [asdict(c) for c in cl]}
