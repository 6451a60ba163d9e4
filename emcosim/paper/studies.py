"""Design studies on the components' monolithic reference (physics-aware; the master stays generic).

coupled_damping_study: Section 6 of the paper as numbers: for each D_d, the certified contraction rate
(components.certificates, over a small box around the set-point) and the decay rate measured in a
simulation started inside that box. best_coupled_damping: the D_d that maximises the linearized decay
rate, found by a bounded scalar search.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy import optimize

from components import certificates, metrics
from components.maglev import Maglev
from components.mems import MEMS, R_e_bar_from_rbar_e
from components.monolithic import simulate
from components.references import Constant
from components.theorem2 import Theorem2
from components.theorem3 import Theorem3


@dataclass
class StudyPoint:
    D_d: float
    certified_rate: float | None     # 1/s, None where no certificate
    measured_rate: float             # 1/s
    nominal_rate: float              # -max Re eig of the closed-loop Jacobian at the set-point


def measured_decay_rate(t: np.ndarray, error: np.ndarray, scale: np.ndarray, n_windows: int = 12) -> float:
    """Asymptotic exponential decay rate of |error / scale|: least-squares slope of the log of its window
    peaks (an envelope, so oscillating errors count by amplitude) over the second half of the run, where
    the slowest mode dominates; windows below 1e-7 of the first peak (integration noise) are dropped."""
    norm = np.linalg.norm(error / scale, axis=1)
    peaks = metrics.window_peaks(norm, n_windows)
    k = len(norm) // n_windows
    centres = np.array([t[i * k: (i + 1) * k][np.argmax(norm[i * k: (i + 1) * k])] for i in range(n_windows)])
    keep = (np.arange(n_windows) >= n_windows // 2) & (peaks > 1e-7 * peaks[0])
    if np.count_nonzero(keep) < 2:
        keep = peaks > 1e-7 * peaks[0]
    slope = np.polyfit(centres[keep], np.log(peaks[keep]), 1)[0]
    return float(-slope)


def study_point(ctrl, ref: Constant, offset: np.ndarray, horizon: float, radius: float) -> StudyPoint:
    cert = certificates.certify(ctrl, ref, 0.0, radius=radius)
    eta_d = ctrl.target(ref.jet(0.0))
    r = simulate(ctrl, eta_d + offset, horizon, ref, rtol=1e-10)
    scale = certificates.state_scale(ctrl, r.eta_star)
    return StudyPoint(float(ctrl.D_d[0, 0]), cert.rate, measured_decay_rate(r.t, r.eta - r.eta_star, scale),
                      jacobian_rate(ctrl, ref))


def design(plant: str, D: float):
    """The study's loop for coupled damping D: MEMS: Theorem 2 at q_d = 3e-5 m, rbar_e = 100. Maglev:
    Theorem 3 at q_d = 2.5 mm, R_e_bar = 0.82, k_c = 20 (general D_d, erratum 1). Returns (controller, reference)."""
    if plant == "mems":
        return Theorem2(MEMS(), R_e_bar_from_rbar_e(100.0), D_d=D), Constant(q_d=3e-5)
    if plant == "maglev":
        return Theorem3(Maglev(), 0.82, k_c=20.0, D_d=D), Constant(q_d=0.0025)
    raise ValueError(f"plant = {plant!r}: expected 'mems' or 'maglev'")


def linearized_rate(plant: str, D: float) -> float:
    """The linearized decay rate (jacobian_rate) of the study's loop for coupled damping D [1/s]."""
    return jacobian_rate(*design(plant, D))


def jacobian_rate(ctrl, ref: Constant) -> float:
    """-max Re eig of the closed-loop Jacobian F_d hess H_d at the set-point [1/s]: the decay rate of the
    linearized loop, and the best rate any constant metric can certify near the set-point."""
    jet = ref.jet(0.0)
    J = ctrl.F_d() @ ctrl.hess_H_d(ctrl.target(jet), jet)
    return float(-np.max(np.linalg.eigvals(J).real))


SEARCH_INTERVALS = {"mems": (-5.0, 0.5), "maglev": (-20.0, 0.5)}


def best_coupled_damping(plant: str, interval: tuple[float, float] | None = None, n_scan: int = 45,
                         xatol: float = 1e-9) -> tuple[float, float]:
    """(D_d*, rate*): the coupled damping that maximises linearized_rate over `interval`. A scan of
    n_scan points brackets the best one between its neighbours; a bounded scalar search (Brent's
    method, scipy's minimize_scalar) then finds the maximum inside the bracket to xatol (relative)."""
    lo, hi = SEARCH_INTERVALS[plant] if interval is None else interval
    grid = np.linspace(lo, hi, n_scan)
    rates = [linearized_rate(plant, D) for D in grid]
    k = int(np.argmax(rates))
    a, b = grid[max(k - 1, 0)], grid[min(k + 1, n_scan - 1)]
    res = optimize.minimize_scalar(lambda D: -linearized_rate(plant, D), bounds=(a, b), method="bounded",
                                   options={"xatol": xatol * max(abs(a), abs(b))})
    best = max([(float(res.x), -float(res.fun)), (float(grid[k]), float(rates[k]))], key=lambda p: p[1])
    return best


def coupled_damping_study(plant: str, D_values) -> list[StudyPoint]:
    """Start 1 % (MEMS: 0.1 %) below the set-point; certificate over a 2 % (0.2 %) box (see `design`)."""
    points = []
    for D in D_values:
        ctrl, ref = design(plant, D)
        if plant == "mems":
            offset, radius, longest = np.array([-3e-8, 0, 0]), 0.002, 0.1
        else:
            offset, radius, longest = np.array([-2.5e-5, 0, 0]), 0.02, 200.0
        slow = jacobian_rate(ctrl, ref)
        if slow <= 0:                                   # locally unstable: no decay to measure
            points.append(StudyPoint(float(ctrl.D_d[0, 0]), None, float("nan"), float(slow)))
            continue
        points.append(study_point(ctrl, ref, offset, min(12.0 / slow, longest), radius))
    return points


def plot_coupled_damping(studies: dict[str, list[StudyPoint]], path: str,
                         best: dict[str, StudyPoint] | None = None) -> None:
    """Certified and measured rates versus D_d, one panel per plant (PNG or SVG by extension); `best`
    (the optimum of best_coupled_damping, per plant) is marked."""
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    units = {"mems": "C/m", "maglev": "Wb/m (general convention)"}
    fig, axes = plt.subplots(1, len(studies), figsize=(6 * len(studies), 4.2))
    for ax, (name, pts) in zip(np.atleast_1d(axes), studies.items()):
        D = [p.D_d for p in pts]
        ax.semilogy(D, [p.measured_rate for p in pts], "o-", label="decay rate measured in simulation")
        ax.semilogy(D, [p.nominal_rate for p in pts], ":", color="gray", label="-max Re eig J at the set-point")
        cert = [(p.D_d, p.certified_rate) for p in pts if p.certified_rate]
        if cert:
            ax.semilogy(*zip(*cert), "s--", label="certified contraction rate (Lemma 1)")
        if best and name in best:
            b = best[name]
            ax.axvline(b.D_d, color="crimson", lw=0.8, ls="--")
            ax.plot([b.D_d], [b.nominal_rate], "*", color="crimson", ms=12,
                    label=f"best D_d = {b.D_d:.6g}: linearized rate {b.nominal_rate:.5g} 1/s"
                          + (f", certified {b.certified_rate:.5g}" if b.certified_rate else ""))
        ax.set_xlabel(f"coupled damping D_d [{units.get(name, '')}]")
        ax.set_ylabel("rate [1/s]")
        ax.set_title({"mems": "MEMS switch, Theorem 2, q_d = 30 um", "maglev": "Maglev, Theorem 3, q_d = 2.5 mm"}.get(name, name))
        ax.grid(True, which="both", alpha=0.3)
        ax.legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)


MEMS_D_VALUES = [0.0, -0.05, -0.1, -0.2, -0.3, -0.4, -0.5, -0.6, -0.7, -1.0, -1.5, -2.0, -3.0]
MAGLEV_D_VALUES = [-16.0, -12.0, -10.0, -9.0, -8.0, -7.0, -5.0, -3.0, -2.0, -1.0, -0.5, 0.0, 0.25]


def main(out_dir: str = "docs/figures") -> None:
    """Write coupled_damping.png/.svg and coupled_damping.json (the numbers) into out_dir."""
    import json
    import os
    from dataclasses import asdict

    os.makedirs(out_dir, exist_ok=True)
    grids = {"mems": MEMS_D_VALUES, "maglev": MAGLEV_D_VALUES}
    studies, best = {}, {}
    for name, grid in grids.items():
        D_best, rate_best = best_coupled_damping(name)
        points = coupled_damping_study(name, sorted(set(grid) | {D_best}))
        studies[name] = points
        best[name] = next(p for p in points if p.D_d == D_best)
    for ext in ("png", "svg"):
        plot_coupled_damping(studies, os.path.join(out_dir, f"coupled_damping.{ext}"), best)
    with open(os.path.join(out_dir, "coupled_damping.json"), "w") as f:
        json.dump({"points": {k: [asdict(p) for p in v] for k, v in studies.items()},
                   "best": {k: asdict(p) | {"search interval": SEARCH_INTERVALS[k]} for k, p in best.items()}},
                  f, indent=1)
    for name, pts in studies.items():
        print(name)
        for p in pts:
            cert = "none" if p.certified_rate is None else f"{p.certified_rate:10.6g}"
            mark = "   <- best (bounded scalar search)" if p is best[name] else ""
            print(f"  D_d = {p.D_d:12.8g}   certified {cert:>10}   measured {p.measured_rate:10.6g}   "
                  f"linearized {p.nominal_rate:10.6g}  [1/s]{mark}")


if __name__ == "__main__":
    import sys
    main(*sys.argv[1:])
