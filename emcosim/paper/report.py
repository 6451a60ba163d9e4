"""The paper's Section 7 as figures, a metrics table and a claims report, computed from time series.

Physics-aware (uses components/ for units and the metrics); fed by the co-simulation master's
results in `emcosim reproduce`, and by the monolithic reference in the tests that check it. Every
claim states its test (quantity, threshold, horizon), the numbers and a verdict: 'holds', 'does not
hold' or 'not decided' (the horizon, a shortened run or the data cannot decide); docs/claims.md
explains the tests. Figures are built as data (emcosim.engine.plotting.FigureSpec) in physical units.
"""
from __future__ import annotations

import json
import math
from dataclasses import asdict, dataclass, field
from pathlib import Path

import numpy as np

from components import maglev, mems, metrics

from ..engine.plotting import OKABE_ITO, FigureSpec, Panel, Series, draw, label, save, scale_unit

HOLDS, FAILS, UNDECIDED = "holds", "does not hold", "not decided"
BAND = 0.02                      # the 2 % band: |e| <= 2 % of |e(0)|
MIN_R2 = 0.9                     # fit quality an exponential decay rate needs to count
N_WINDOWS = 16                   # envelope windows over the horizon for the decay fit
FLOOR = 1e-3                     # envelope windows below FLOOR x the first are left out of the fit
OSCILLATING = 2                  # sign changes of e outside the band that make an oscillation
DECISION = "_decision"           # role + DECISION: a longer run of the role's scenario that decides its convergence
RESOLVED = 0.05                  # a metric that changes by more than this (relative) at half the recording resolution
                                 # is not resolved by the run's samples (a count: by more than 1 as well)

PLANTS = {"MEMS": mems, "Maglev": maglev}
NAMES = {"q": "position q", "p": "momentum p", "x_e": "electrical state x_e", "u": "input u", "H": "stored energy H"}


def units(plant: str) -> dict[str, str]:
    """Units of q, p, x_e (components' STATES), u (INPUT) and H of a plant; a described device's (its first
    position, electrical state and input: components.catalog.DEVICES) for any other."""
    module = PLANTS.get(plant)
    if module is None:
        from components import catalog

        d = catalog.DEVICES[plant]
        return {"q": d.q[0].unit, "p": d.p[0].unit, "x_e": d.x_e[0].unit, "u": d.u[0].unit, "H": "J"}
    return {**{k: v[0] for k, v in module.STATES.items()}, "u": module.INPUT[1], "H": "J"}


@dataclass
class Run:
    """One paper case: time series of the plant state, the input and the target (SI units)."""

    name: str
    plant: str                     # "MEMS" or "Maglev"
    label: str                     # legend text, e.g. "D_d = 0"
    t: np.ndarray
    q: np.ndarray
    p: np.ndarray
    x_e: np.ndarray
    u: np.ndarray
    eta_star: np.ndarray           # (N, 3): target eta*(t) (or eta_d)
    horizon: float = float("nan")  # the scenario's own horizon [s]; a run that ends before it is shortened
    H: np.ndarray | None = None    # stored energy [J], when recorded
    notes: list[str] = field(default_factory=list)   # conditions of its theorem the design violates

    @property
    def e(self) -> np.ndarray:
        """Position error q - q*."""
        return self.q - self.eta_star[:, 0]

    @property
    def shortened(self) -> bool:
        return bool(np.isfinite(self.horizon) and self.t[-1] < self.horizon * (1 - 1e-9))

    @property
    def state_scales(self) -> np.ndarray:
        """Per state, the largest magnitude of its target over the run (of the state itself where
        the target is zero throughout): the scales of the error norm."""
        eta = np.column_stack([self.q, self.p, self.x_e])
        s = np.max(np.abs(self.eta_star), axis=0)
        s = np.where(s > 0, s, np.max(np.abs(eta), axis=0))
        return np.where(s > 0, s, 1.0)

    @property
    def error_norm(self) -> np.ndarray:
        """|(eta - eta*) / s|_2, each state divided by its scale s (state_scales): dimensionless,
        each state counted by its relative error (the 'L2-norm of the error' of the paper's Fig. 4)."""
        eta = np.column_stack([self.q, self.p, self.x_e])
        return np.linalg.norm((eta - self.eta_star) / self.state_scales, axis=1)


# ---- metrics -------------------------------------------------------------------------------------

@dataclass
class Metrics:
    settling_time_2pct: float      # s; first time after which |e| stays within 2 % of |e(0)|; inf: not within the horizon
    overshoot: float               # % of |e(0)|: largest excursion past the target, opposite to e(0)
    oscillations: int              # sign changes of e outside the 2 % band
    ise: float                     # m^2 s, integral of e^2
    final_error: float             # m, e at the last sample
    max_abs_u: float               # V
    initial_error: float           # m
    resolution: float = math.nan   # s: the recording step the metrics are computed from (the largest spacing)
    unresolved: dict = field(default_factory=dict)   # metric -> why its value is not resolved (see `resolution_check`)


def band_of(e: np.ndarray) -> float:
    return BAND * abs(e[0]) if e[0] != 0 else BAND * float(np.max(np.abs(e)))


def run_metrics(run: Run) -> Metrics:
    e = run.e
    band = band_of(e)
    m = Metrics(metrics.settling_time(run.t, e, band), 100.0 * metrics.overshoot(e), metrics.oscillations(e, band),
                metrics.ise(run.t, e), float(e[-1]), float(np.max(np.abs(run.u))), float(e[0]))
    m.resolution = float(np.max(np.diff(run.t))) if len(run.t) > 1 else math.nan
    m.unresolved = resolution_check(run.t, e, band)
    return m


def resolution_check(t: np.ndarray, e: np.ndarray, band: float) -> dict[str, str]:
    """The overshoot and the oscillation count computed again from every other sample (half the recording
    resolution, the same band): where one changes by more than RESOLVED (a count: and by more than 1), the
    samples do not resolve what it measures (e.g. a 2.2 kHz oscillation recorded every 1 ms): metric -> why."""
    out = {}
    h = float(np.max(np.diff(t))) if len(t) > 1 else math.nan
    half = e[::2]
    over, over_half = 100.0 * metrics.overshoot(e), 100.0 * metrics.overshoot(half)
    if abs(over - over_half) > RESOLVED * max(over, over_half, 100 * BAND):
        out["overshoot"] = (f"overshoot {over:.3g} % from samples every {h:.3g} s, {over_half:.3g} % from every "
                            "other sample: the recording does not resolve it")
    n, n_half = metrics.oscillations(e, band), metrics.oscillations(half, band)
    if abs(n - n_half) > max(1.0, RESOLVED * max(n, n_half)):
        out["oscillations"] = (f"{n} sign changes from samples every {h:.3g} s, {n_half} from every other sample: "
                               "the recording does not resolve the oscillation")
    return out


def finite_or_none(x):
    """A JSON value: non-finite numbers (a band never reached) become null; containers recursively."""
    if isinstance(x, dict):
        return {k: finite_or_none(v) for k, v in x.items()}
    if isinstance(x, (list, tuple, np.ndarray)):
        return [finite_or_none(v) for v in x]
    if isinstance(x, (float, np.floating)):
        return float(x) if math.isfinite(x) else None
    if isinstance(x, np.integer):
        return int(x)
    return x


NOT_REACHED = "not reached"
"""What a table says for a time into the 2 % band that is not reached within the horizon (inf): the metrics
table of `reproduce`, the claims report and the sweep's table and plots say the same words (`settling_text`)."""


def settling_text(value: float, digits: int = 4) -> str:
    """A time into the 2 % band [s] as a table shows it: NOT_REACHED for inf (|e| does not stay in the band
    within the horizon), else the number to `digits` significant digits."""
    return NOT_REACHED if value == math.inf else f"{value:.{digits}g}"


def metrics_table(runs: dict[str, Run]) -> tuple[str, dict]:
    """(Markdown table, strict-JSON dict) of the metrics of every run. JSON: a settling time that is
    not reached within the horizon is null; `horizon_s` is the horizon of the run."""
    data = {}
    for name, r in runs.items():
        data[name] = {**asdict(run_metrics(r)), "horizon_s": float(r.t[-1])}
    head = ("| case | horizon [s] | time into 2 % band [s] | overshoot [%] | oscillations | ISE [m^2 s] "
            "| final error [m] | max abs u [V] | recorded every [s] | note |\n|---|---|---|---|---|---|---|---|---|---|")
    rows = []
    for n, m in data.items():
        settle = settling_text(m["settling_time_2pct"])
        note = "; ".join([*runs[n].notes, *m["unresolved"].values()]) + ("; run shortened" if runs[n].shortened else "")
        rows.append(f"| {n} | {m['horizon_s']:.4g} | {settle} | {m['overshoot']:.3g} | {m['oscillations']} | "
                    f"{m['ise']:.3g} | {m['final_error']:.3g} | {m['max_abs_u']:.4g} | {m['resolution']:.3g} | "
                    f"{note.strip('; ')} |")
    return "\n".join([head, *rows]), finite_or_none(data)


# ---- the convergence test ----------------------------------------------------------------------------

@dataclass
class Decay:
    """How the position error decays over the run (see `decay`)."""

    settled: bool                  # |e| enters the 2 % band of |e(0)| and stays in it up to the end of the run
    settling_time: float           # s (inf if not settled)
    rate: float | None             # fitted exponential decay rate of the error envelope [1/s]
    r2: float | None               # coefficient of determination of that fit (of log envelope over t)
    windows: int                   # envelope windows in the fit
    projected: float | None        # s: when the fitted envelope reaches the band (if not settled)


def decay(run: Run, n_windows: int = N_WINDOWS, floor: float = FLOOR) -> Decay:
    """Envelope of |e|: its maximum over each of n_windows equal windows of the run, at the time of
    that maximum. A least-squares line through log(envelope) over time gives the decay rate and R^2;
    windows after the envelope falls below floor x its first value (the accuracy floor) are left out;
    fewer than 3 windows: no fit."""
    t, e = run.t, np.abs(run.e)
    band = band_of(run.e)
    settle = metrics.settling_time(t, run.e, band)
    edges = np.linspace(0, len(e), min(n_windows, len(e)) + 1).astype(int)
    peaks, times = [], []
    for a, b in zip(edges[:-1], edges[1:]):
        k = a + int(np.argmax(e[a:b]))
        if peaks and e[k] < floor * peaks[0]:
            break
        peaks.append(e[k])
        times.append(t[k])
    rate = r2 = projected = None
    if len(peaks) >= 3 and min(peaks) > 0:
        y = np.log(peaks)
        slope, intercept = np.polyfit(times, y, 1)
        residual = y - (slope * np.asarray(times) + intercept)
        total = np.sum((y - y.mean()) ** 2)
        rate, r2 = float(-slope), float(1 - np.sum(residual ** 2) / total) if total > 0 else 1.0
        if not math.isfinite(settle) and rate > 0:
            projected = float((intercept - math.log(band)) / rate)
    return Decay(bool(math.isfinite(settle)), float(settle), rate, r2, len(peaks), projected)


def convergence(run: Run) -> tuple[str, str, dict]:
    """(verdict, reason, numbers) of 'the error converges to zero' on this run: holds if |e| enters
    the 2 % band of |e(0)| and stays there up to the end of the scenario's horizon; does not hold if
    the envelope does not decay (fitted rate <= 0 with R^2 >= MIN_R2, or the last window's envelope
    at least the first's); not decided otherwise (decaying but the band is not reached within the
    horizon, a poor fit, or a shortened run)."""
    d = decay(run)
    nums = {"time into 2 % band [s]": d.settling_time, "fitted decay rate [1/s]": d.rate, "fit R^2": d.r2,
            "horizon [s]": float(run.t[-1])}
    if run.shortened:
        return UNDECIDED, _shortened(run), nums
    peaks = metrics.window_peaks(run.e, N_WINDOWS)
    if (d.rate is not None and d.rate <= 0 and d.r2 >= MIN_R2) or peaks[-1] >= peaks[0]:
        return FAILS, "the error envelope does not decay", nums
    if d.settled:
        return HOLDS, "in the 2 % band within the horizon", nums
    if d.rate is not None and d.rate > 0 and d.r2 >= MIN_R2:
        nums["2 % band projected at [s]"] = d.projected
        return UNDECIDED, (f"decays (rate {d.rate:.3g} 1/s, R^2 {d.r2:.3f}) but reaches the 2 % band only at about "
                           f"{d.projected:.3g} s, after the {run.t[-1]:g} s horizon"), nums
    return UNDECIDED, "the band is not reached within the horizon and the envelope fits no exponential decay", nums


# ---- claims ------------------------------------------------------------------------------------------

@dataclass
class Claim:
    text: str                      # what the paper says
    where: str                     # where it says it
    test: str                      # quantity, threshold, horizon
    verdict: str                   # HOLDS, FAILS or UNDECIDED
    reason: str = ""
    numbers: dict = field(default_factory=dict)
    notes: list[str] = field(default_factory=list)


def _all(verdicts: list[str]) -> str:
    if all(v == HOLDS for v in verdicts):
        return HOLDS
    return FAILS if FAILS in verdicts else UNDECIDED


def _notes(*runs: Run) -> list[str]:
    """The runs' notes, each once, with the runs it concerns ("case 1, case 3: violates ...")."""
    by_text: dict[str, list[str]] = {}
    for r in runs:
        for n in r.notes:
            by_text.setdefault(n, []).append(r.label.split(";")[0].split(":")[0])
    return [f"{' and '.join(who)}: {text}" for text, who in by_text.items()]


def _reasons(*texts: str) -> str:
    return "; ".join(dict.fromkeys(t for t in texts if t))


def _horizons(*runs: Run) -> str:
    hs = sorted({float(r.t[-1]) for r in runs})
    return " and ".join(f"{h:g} s" for h in hs)


def _shortened(*runs: Run) -> str:
    short = [r for r in runs if r.shortened]
    return f"run shortened to {short[0].t[-1]:g} s of its {short[0].horizon:g} s horizon" if short else ""


def _judged(R: dict[str, Run], role: str) -> Run:
    """The run a convergence claim of `role` is judged on: its decision run (role + DECISION, a longer run
    of the same scenario that `emcosim reproduce` makes where the scenario's horizon leaves the claim
    open), else the scenario's run."""
    return R.get(role + DECISION, R[role])


def _decision_text(judged: list[Run], own: list[Run]) -> str:
    """What the test says about decision runs (nothing where every run is the scenario's own)."""
    longer = [(j, r) for j, r in zip(judged, own) if j is not r]
    if not longer:
        return ""
    which = longer[0][1].name if len(longer) == 1 else f"each of the {len(longer)} scenarios"
    return (f" (a decision run of {which} to {_horizons(*[j for j, _ in longer])} at its default step: the "
            f"scenario horizon of {_horizons(*[r for _, r in longer])} leaves the claim open)")


def _scenario_verdict(judged: Run, own: Run, prefix: str = "") -> dict:
    """The verdict over the scenario's own horizon, beside a decision run's."""
    if judged is own:
        return {}
    v, why, _ = convergence(own)
    return {f"{prefix}verdict over the scenario's {own.t[-1]:g} s horizon": f"{v} ({why})"}


def _unresolved(m: Metrics, *names: str) -> str:
    """Why the metrics `names` cannot decide a claim (empty if they can)."""
    return "; ".join(m.unresolved[n] for n in names if n in m.unresolved)


def _oscillates(run: Run, m: Metrics) -> tuple[str, str]:
    if _unresolved(m, "oscillations"):
        return UNDECIDED, _unresolved(m, "oscillations")
    if m.oscillations >= OSCILLATING:
        return HOLDS, f"{m.oscillations} sign changes of e outside the 2 % band"
    if run.shortened:
        return UNDECIDED, _shortened(run)
    return FAILS, f"only {m.oscillations} sign change(s) of e outside the 2 % band"


def _no_oscillation(run: Run, m: Metrics) -> tuple[str, str]:
    if _unresolved(m, "oscillations", "overshoot"):
        return UNDECIDED, _unresolved(m, "oscillations", "overshoot")
    if m.oscillations > 0 or m.overshoot >= 100 * BAND:
        return FAILS, f"{m.oscillations} sign change(s), overshoot {m.overshoot:.3g} %"
    if run.shortened:
        return UNDECIDED, _shortened(run)
    return HOLDS, "no sign change and no overshoot beyond the band"


def _fewer(a: Metrics, b: Metrics) -> str:
    """Does run a oscillate less than run b? Counts over a horizon are lower bounds for a run that
    has not settled: a < b is decided if a settled; a >= b is decided if b settled. Counts the recording does
    not resolve decide nothing."""
    if _unresolved(a, "oscillations") or _unresolved(b, "oscillations"):
        return UNDECIDED
    if a.oscillations < b.oscillations:
        return HOLDS if math.isfinite(a.settling_time_2pct) else UNDECIDED
    return FAILS if math.isfinite(b.settling_time_2pct) else UNDECIDED


def claims(runs: dict[str, Run], cases: dict[str, str], facts: dict | None = None) -> list[Claim]:
    """Evaluate the Section 7 claims. `cases` maps roles to run names: mems_reg_0, mems_reg_1
    (D_d = 0, -1), mems_track_0, mems_track_1 (D_d = 0, -0.4), maglev_1 .. maglev_4 (the paper's
    cases 1-4); ROLE + DECISION (e.g. mems_reg_0_decision), where given, is a longer run of ROLE's
    scenario on which ROLE's convergence claim is judged (emcosim.paper.reproduce.DECISION_RUNS; every
    other claim keeps the scenario's run). `facts` (emcosim.paper.reproduce.design_facts_of) adds what the linearization and
    Theorem 1 say: 'modes' (role -> dominant mode), 'iii' (plant -> Theorem 1 (iii) results) and
    'overdamping' (rows of the R_e_bar study)."""
    facts = facts or {}
    modes = facts.get("modes", {})
    R = {role: runs[name] for role, name in cases.items() if name in runs}
    M = {role: run_metrics(r) for role, r in R.items()}
    out: list[Claim] = []
    conv_test = (f"|e| = |q - q*| enters the 2 % band of |e(0)| and stays in it to the end of the horizon "
                 f"(holds); envelope of |e| ({N_WINDOWS} windows) fitted by an exponential: a rate <= 0 with "
                 f"R^2 >= {MIN_R2} does not hold; decaying without reaching the band: not decided")

    def zeta(role: str) -> dict:
        m = modes.get(role)
        return {} if m is None else {"damping ratio of the linearization's slowest mode": m["zeta"],
                                     "its decay rate [1/s]": m["rate"]}

    if {"mems_reg_0", "mems_reg_1"} <= R.keys():
        a, b = R["mems_reg_0"], R["mems_reg_1"]
        judged = _judged(R, "mems_reg_0")
        v, why, nums = convergence(judged)
        out.append(Claim("MEMS regulation, D_d = 0: the states converge to eta_d", "Sec. 7.1, Fig. 1",
                         f"{conv_test}; horizon {_horizons(judged)}{_decision_text([judged], [a])}", v, why,
                         {**nums, **_scenario_verdict(judged, a)}, _notes(a)))
        v, why = _oscillates(a, M["mems_reg_0"])
        out.append(Claim("MEMS regulation, D_d = 0: the transient oscillates before reaching eta_d", "Sec. 7.1, Fig. 1",
                         f"at least {OSCILLATING} sign changes of e outside the 2 % band over {_horizons(a)}", v, why,
                         {"sign changes": M["mems_reg_0"].oscillations, "overshoot [%]": M["mems_reg_0"].overshoot,
                          **zeta("mems_reg_0")}, _notes(a)))
        v1, why1, nums = convergence(b)
        v2, why2 = _no_oscillation(b, M["mems_reg_1"])
        out.append(Claim("MEMS regulation, D_d = -1: converges to eta_d with no oscillations", "Sec. 7.1, Fig. 1",
                         f"converges ({conv_test}), no sign change of e outside the 2 % band and overshoot below "
                         f"2 %, over {_horizons(b)}", _all([v1, v2]), _reasons(why1, why2),
                         {**nums, "sign changes": M["mems_reg_1"].oscillations, "overshoot [%]": M["mems_reg_1"].overshoot,
                          **zeta("mems_reg_1")}, _notes(b)))
    if {"mems_track_0", "mems_track_1"} <= R.keys():
        a, b = R["mems_track_0"], R["mems_track_1"]
        v1, why1, nums = convergence(a)
        v2, why2 = _oscillates(a, M["mems_track_0"])
        out.append(Claim("MEMS tracking, D_d = 0: converges to the reference with oscillating responses",
                         "Sec. 7.1, Fig. 2", f"converges ({conv_test}) and at least {OSCILLATING} sign changes of e "
                         f"outside the 2 % band, over {_horizons(a)}", _all([v1, v2]), _reasons(why1, why2),
                         {**nums, "sign changes": M["mems_track_0"].oscillations, **zeta("mems_track_0")}, _notes(a)))
        v1, why1, nums = convergence(b)
        v2, why2 = _no_oscillation(b, M["mems_track_1"])
        out.append(Claim("MEMS tracking, D_d = -0.4: tracks q* exponentially without oscillations", "Sec. 7.1, Fig. 2",
                         f"converges ({conv_test}), no sign change of e outside the 2 % band and overshoot below 2 %, "
                         f"over {_horizons(b)}", _all([v1, v2]), _reasons(why1, why2),
                         {**nums, "sign changes": M["mems_track_1"].oscillations,
                          "overshoot [%]": M["mems_track_1"].overshoot, **zeta("mems_track_1")}, _notes(b)))
    roles = [f"maglev_{i}" for i in range(1, 5)]
    if set(roles) <= R.keys():
        out += _maglev_claims([R[r] for r in roles], [M[r] for r in roles], [modes.get(r) for r in roles], conv_test,
                              [_judged(R, r) for r in roles])
    if "iii" in facts:
        out += [_theorem1_iii_claim(plant, f) for plant, f in facts["iii"].items()]
    if "overdamping" in facts:
        out.append(_overdamping_claim(facts["overdamping"]))
    return out


def _maglev_claims(runs: list[Run], m: list[Metrics], modes: list[dict | None], conv_test: str,
                   judged: list[Run] | None = None) -> list[Claim]:
    """The maglev claims on the four cases' runs; `judged`: the runs their convergence is judged on
    (decision runs, see `_judged`; default the cases' runs)."""
    judged = judged or runs
    notes = _notes(*runs)
    horizon = _horizons(*runs)
    short = _shortened(*runs)
    out = []
    conv = [convergence(r) for r in judged]
    decided = _decision_text(judged, runs)
    before = {k: v for i, (j, r) in enumerate(zip(judged, runs), 1) for k, v in _scenario_verdict(j, r, f"case {i} ").items()}
    out.append(Claim("Maglev: all four cases converge to the desired trajectory", "Sec. 7.2, Fig. 3",
                     f"each case converges ({conv_test}); horizon {_horizons(*judged)}{decided}",
                     _all([c[0] for c in conv]), "; ".join(f"case {i}: {c[0]} ({c[1]})" for i, c in enumerate(conv, 1)),
                     {**{f"case {i} {k}": v for i, c in enumerate(conv, 1) for k, v in c[2].items()
                         if k != "horizon [s]"}, **before}, notes))
    fewer = [_fewer(m[2], m[0]), _fewer(m[3], m[1])]
    zetas = {f"case {i} damping ratio (linearization)": md["zeta"] for i, md in enumerate(modes, 1) if md}
    out.append(Claim("Maglev: q oscillates less with coupled damping (case 3 fewer than case 1, case 4 fewer than case 2)",
                     "Sec. 7.2, Fig. 3", f"sign changes of e outside the 2 % band over {horizon} (a count is a lower "
                     "bound for a case that has not settled: decided only where that bound suffices)",
                     _all(fewer), short or (f"case 3: {m[2].oscillations} vs case 1: {m[0].oscillations}; case 4: "
                                            f"{m[3].oscillations} vs case 2: {m[1].oscillations}"),
                     {**{f"case {i} sign changes": x.oscillations for i, x in enumerate(m, 1)},
                                                **zetas}, notes))
    decays = [decay(r) for r in runs]
    fits = all(d.rate is not None and d.r2 >= MIN_R2 for d in decays)
    slower = decays[1].rate < decays[0].rate and decays[3].rate < decays[2].rate if fits else None
    verdict = UNDECIDED if (short or not fits) else (HOLDS if slower else FAILS)
    why = short or ("a decay fit is missing or poor" if not fits else
                    f"case 2 decays at {decays[1].rate:.3g} 1/s against {decays[0].rate:.3g} for case 1, case 4 at "
                    f"{decays[3].rate:.3g} against {decays[2].rate:.3g} for case 3")
    out.append(Claim("Maglev: larger electrical damping (cases 2, 4) converges more slowly than cases 1, 3",
                     "Sec. 7.2, Fig. 4", f"fitted exponential decay rate of the envelope of |e| over {horizon} (fit "
                     f"R^2 >= {MIN_R2}): rate(case 2) < rate(case 1) and rate(case 4) < rate(case 3)",
                     verdict, why,
                     {**{f"case {i} fitted decay rate [1/s]": d.rate for i, d in enumerate(decays, 1)},
                      **{f"case {i} fit R^2": d.r2 for i, d in enumerate(decays, 1)},
                      **{f"case {i} decay rate of the linearization [1/s]": md["rate"] for i, md in enumerate(modes, 1) if md}},
                     notes))
    early = []
    for r in runs:
        keep = r.t <= 0.25 * r.horizon if np.isfinite(r.horizon) else r.t <= 0.25 * r.t[-1]
        early.append(float(np.trapezoid(r.error_norm[keep], r.t[keep])))
    verdict = UNDECIDED if short else (HOLDS if early[2] < early[0] and early[3] < early[1] else FAILS)
    out.append(Claim("Maglev: coupled damping (cases 3, 4) reduces the error norm in the initial interval",
                     "Sec. 7.2, Fig. 4", "integral of the scaled error norm |(eta - eta*)/s|_2 of Fig. 4 over the first "
                     "quarter of the horizon: case 3 < case 1 and case 4 < case 2", verdict,
                     short or f"case 3: {early[2]:.3g} vs case 1: {early[0]:.3g}; case 4: {early[3]:.3g} vs case 2: "
                              f"{early[1]:.3g}",
                     {f"case {i} integral over the first quarter [s]": x for i, x in enumerate(early, 1)}, notes))
    ise = [x.ise for x in m]
    best = int(np.argmin(ise)) + 1
    out.append(Claim("Maglev: case 3 (coupled damping, R_e_bar = 0.82) has the smallest error", "Sec. 7.2",
                     f"ISE = integral of e^2 over {horizon}: smallest for case 3", UNDECIDED if short else
                     (HOLDS if best == 3 else FAILS), short or f"case {best} has the smallest ISE",
                     {f"case {i} ISE [m^2 s]": x for i, x in enumerate(ise, 1)}, notes))
    out.append(Claim("Maglev: coupled damping helps more than larger electrical damping (case 3 better than case 2)",
                     "Sec. 7.2", f"ISE over {horizon}: case 3 < case 2", UNDECIDED if short else
                     (HOLDS if ise[2] < ise[1] else FAILS), short or f"case 3: {ise[2]:.3g} vs case 2: {ise[1]:.3g} m^2 s",
                     {"case 3 ISE [m^2 s]": ise[2], "case 2 ISE [m^2 s]": ise[1]},
                     notes))
    return out


def _theorem1_iii_claim(plant: str, f: dict) -> Claim:
    """f: 'paper' (scenario -> theorem1_iii result at the paper's gains), 'search' (theorem1_iii_search
    result), 'grid' (the gains tried)."""
    paper = f["paper"]
    held = [n for n, r in paper.items() if r["verdict"] == "holds"]
    search = f["search"]
    verdict = HOLDS if (held or search["holds"]) else FAILS
    where = {"MEMS": "Sec. 7.1, eq. (cond3T2)", "Maglev": "Sec. 7.2"}[plant]
    grid = "; ".join(f"{k} in {{{', '.join(f'{v:g}' for v in vals)}}}" for k, vals in f["grid"].items())
    worst = max(paper.values(), key=lambda r: r["gamma1/gamma2"] or 0)
    nums = {"scenarios at the paper's gains where (iii) holds": f"{len(held)} of {len(paper)}",
            "largest gamma1/gamma2 at the paper's gains": worst["gamma1/gamma2"],
            "its S = sup_w |(jwI - F_d)^-1 F_d|": worst["S"],
            "(iii) needs gamma1/gamma2 >": f"{1 - 1 / worst['S']:.7g}" if worst["S"] else None,
            "gain combinations tried": search["tried"], "accepted by the controller": search["accepted"],
            "where (iii) holds": search["holds"]}
    reason = (f"(iii) holds at the paper's gains in {', '.join(held)}" if held else
              f"(iii) holds for {search['holds']} of the {search['accepted']} gain combinations tried"
              + (f", e.g. {search['first']}" if search["first"] else ""))
    reason += ("; (iii) is equivalent to (1 - gamma1/gamma2) S < 1 and S >= 1, so it needs hess H_d nearly "
               "isotropic: gamma1/gamma2 is set by the plant's Hessian (docs/claims.md)")
    return Claim(f"{plant}: condition (iii) of Theorem 1 holds through appropriate selection of the closed-loop "
                 "parameters", where,
                 "Theorem 1 (iii) as emcosim certify evaluates it (Q of eq. Eq:N has no eigenvalue on the imaginary "
                 "axis for some eps in [1e-8, 1e3]; gamma1, gamma2 of (ii) sampled over a tube of +-10 % of each "
                 f"state's scale around the target over the horizon), at the paper's gains and on the grid {grid}",
                 verdict, reason, nums)


def _overdamping_claim(rows: list[dict]) -> Claim:
    """rows: {'D_d paper', 'R_e_bar', 'zeta', 'rate'} of the linearized maglev tracking loop."""
    by = {(r["D_d paper"], r["R_e_bar"]): r for r in rows}
    Ds = sorted({r["D_d paper"] for r in rows}, reverse=True)
    ok = all(by[(D, 2.82)]["zeta"] >= 1.0 and by[(D, 2.82)]["rate"] < by[(D, 0.82)]["rate"] for D in Ds)
    nums = {}
    for D in Ds:
        mine = sorted((r for r in rows if r["D_d paper"] == D), key=lambda r: r["R_e_bar"])
        at = ", ".join(f"{r['R_e_bar']:g}" for r in mine)
        nums[f"D_d = {D:g}, damping ratio at R_e_bar = {at}"] = ", ".join(f"{r['zeta']:.3g}" for r in mine)
        nums[f"D_d = {D:g}, decay rate [1/s] at R_e_bar = {at}"] = ", ".join(f"{r['rate']:.3g}" for r in mine)
    top = {D: max(r["zeta"] for r in rows if r["D_d paper"] == D) for D in Ds}
    reason = ("at R_e_bar = 2.82 the slowest mode is still an oscillation (damping ratio "
              + ", ".join(f"{by[(D, 2.82)]['zeta']:.3g} for D_d = {D:g}" for D in Ds)
              + ") and decays faster than at 0.82; the damping ratio rises with R_e_bar but levels off at about "
              + ", ".join(f"{top[D]:.2g}" for D in Ds) + " (never overdamped), and only much larger R_e_bar slows "
              "the decay") if not ok else "overdamped and slower at R_e_bar = 2.82"
    return Claim("Maglev: larger electrical damping R_e_bar makes the response tend to an overdamped one, with a "
                 "remarkably slow convergence, particularly in q", "Sec. 7.2",
                 "slowest mode of the closed loop linearized at the reference (plant + controller Jacobian, smallest "
                 "damping ratio over the horizon): holds if at R_e_bar = 2.82 it is overdamped (damping ratio >= 1) "
                 "and decays more slowly than at R_e_bar = 0.82, for both paper D_d; larger R_e_bar shown for the trend",
                 HOLDS if ok else FAILS, reason, nums)


# ---- the report files -------------------------------------------------------------------------------

def _fmt(v) -> str:
    if isinstance(v, float):
        return settling_text(v)
    if v is None:
        return "n/a"
    return str(v)


def claims_markdown(cl: list[Claim]) -> str:
    """A summary table, then per claim: the test, the numbers, the verdict and its reason."""
    lines = ["| # | claim (paper) | verdict |", "|---|---|---|"]
    lines += [f"| {i} | {c.text} ({c.where}) | {_verdict_md(c.verdict)} |" for i, c in enumerate(cl, 1)]
    for i, c in enumerate(cl, 1):
        lines += ["", f"### {i}. {c.text}", "", f"*Where*: {c.where}.  ", f"*Test*: {c.test}.  ",
                  "*Numbers*: " + "; ".join(f"{k} = {_fmt(v)}" for k, v in c.numbers.items()) + ".  ",
                  f"*Verdict*: {_verdict_md(c.verdict)}" + (f": {c.reason}." if c.reason else ".")]
        if c.notes:
            lines.append("  \n*Note*: " + " ".join(f"{n}." for n in c.notes))
    return "\n".join(lines)


def _verdict_md(v: str) -> str:
    return {HOLDS: "holds", FAILS: "**does not hold**", UNDECIDED: "*not decided*"}[v]


def write_reports(runs: dict[str, Run], cases: dict[str, str], out: Path, choices: list[str],
                  facts: dict | None = None, banner: str = "") -> dict:
    """metrics.md/json and claims.md/json into `out`; `choices` are the paragraphs of 'Choices the
    paper does not make', `banner` a warning put first (e.g. shortened runs). Returns the content."""
    table_md, table = metrics_table(runs)
    cl = claims(runs, cases, facts)
    top = [f"> **{banner}**\n"] if banner else []
    horizons = "\n".join(f"| {n} | {r.t[-1]:g} | {r.horizon:g} | {r.t[1] - r.t[0]:g} |" for n, r in runs.items())
    (out / "metrics.md").write_text("\n".join([
        "# Metrics per case\n", *top,
        f"Position error e = q - q*; band = 2 % of |e(0)|; overshoot in % of |e(0)|; '{NOT_REACHED}': |e| does not "
        "stay in the band within the horizon (null in metrics.json).\n", table_md, ""]))
    (out / "metrics.json").write_text(json.dumps(table, indent=1, allow_nan=False))
    body = ["# Claims of Section 7, checked\n", *top,
            "Each claim the paper makes about these simulations: the test it is held to (quantity, threshold, "
            "horizon), the numbers of our runs and the verdict: *holds*, **does not hold**, or *not decided* "
            "(the horizon or a shortened run cannot decide it). docs/claims.md explains the tests.\n",
            "| scenario | horizon run [s] | scenario horizon [s] | communication step [s] |", "|---|---|---|---|",
            horizons, *_decision_legend(runs), "", claims_markdown(cl), "", "## Choices the paper does not make\n",
            *[f"{p}\n" for p in choices]]
    (out / "claims.md").write_text("\n".join(body))
    content = [finite_or_none({"id": i, **asdict(c)}) for i, c in enumerate(cl, 1)]
    (out / "claims.json").write_text(json.dumps({"banner": banner or None, "claims": content}, indent=1,
                                                allow_nan=False))
    return {"metrics": table, "claims": content}


def _decision_legend(runs: dict[str, Run]) -> list[str]:
    """The sentence under the horizons table that says what the decision runs are (none: nothing)."""
    longer = [n for n, r in runs.items() if np.isfinite(r.horizon) and r.t[-1] > r.horizon * (1 + 1e-9)]
    if not longer:
        return []
    return ["", f"{', '.join(longer)}: decision runs, longer runs of a scenario at its default step that decide "
                "a convergence claim its horizon leaves open (the claim's test names them); every other claim "
                "is judged on the scenarios' horizons."]


# ---- figures ----------------------------------------------------------------------------------------

CASE_STYLES = [                     # colour (Okabe-Ito), line style, width, z-order: case 3 drawn over case 4
    (OKABE_ITO[1], "-", 1.6, 2.0),   # orange, solid
    (OKABE_ITO[0], "--", 1.6, 2.1),  # blue, dashed
    (OKABE_ITO[2], "-.", 1.8, 2.4),  # bluish green, dash-dot
    (OKABE_ITO[3], ":", 2.2, 2.3),   # reddish purple, dotted
]
TARGET_STYLE = ("black", (0, (1.5, 2.5)), 1.0)


def _style(i: int) -> dict:
    color, style, width, z = CASE_STYLES[i % len(CASE_STYLES)]
    return dict(color=color, style=style, width=width, zorder=z)


def states_figure(runs: list[Run], title: str, star_label: str) -> FigureSpec:
    """Four panels (q, p, x_e, u) with every run overlaid and the target dotted, in SI units with
    prefixes (um, ms for the MEMS); one legend under the panels."""
    u = units(runs[0].plant)
    t_factor, t_unit = scale_unit(np.concatenate([r.t for r in runs]), "s")
    panels = []
    for k, var in enumerate(["q", "p", "x_e", "u"]):
        data = np.concatenate([getattr(r, var) for r in runs])
        factor, unit = scale_unit(data, u[var])
        series = [Series(r.label, r.t * t_factor, getattr(r, var) * factor, **_style(i)) for i, r in enumerate(runs)]
        if var != "u":
            color, style, width = TARGET_STYLE
            series.append(Series(star_label, runs[0].t * t_factor, runs[0].eta_star[:, k] * factor, color, style,
                                 width, zorder=3.0))
        panels.append(Panel(label(NAMES[var], unit), series))
    return FigureSpec(title, panels, label("time t", t_unit), columns=2, legend="below", size=(11, 7.5))


def error_norm_figure(runs: list[Run], control_run: Run) -> FigureSpec:
    """The paper's Fig. 4: scaled error norms of the four maglev cases (log scale), the position
    errors, and u of case 3."""
    s = runs[0].state_scales
    u = units(runs[0].plant)
    t_factor, t_unit = scale_unit(runs[0].t, "s")
    note = ("norm of (q - q*, p - p*, x_e - x_e*) with each state divided by its largest target magnitude: "
            f"{s[0]:.3g} {u['q']}, {s[1]:.3g} {u['p']}, {s[2]:.3g} {u['x_e']}")
    norms = Panel("|(eta - eta*)/s|_2 [1]", [Series(r.label, r.t * t_factor, r.error_norm, **_style(i))
                                             for i, r in enumerate(runs)], title="Error norms", yscale="log")
    e_factor, e_unit = scale_unit(np.concatenate([r.e for r in runs]), u["q"])
    errors = Panel(label("q - q*", e_unit), [Series(r.label, r.t * t_factor, r.e * e_factor, **_style(i))
                                             for i, r in enumerate(runs)], title="Position errors")
    i = runs.index(control_run) if control_run in runs else 2
    u_factor, u_unit = scale_unit(control_run.u, u["u"])
    control = Panel(label("input u", u_unit), [Series(control_run.label, control_run.t * t_factor,
                                                      control_run.u * u_factor, **_style(i))],
                    title=f"Control signal, {control_run.label}")
    for r in runs:
        if not np.allclose(r.state_scales, s):
            raise ValueError("error_norm_figure: the runs have different state scales")
    return FigureSpec("Maglev tracking: error norms (Fig. 4)", [norms, errors, control], label("time t", t_unit),
                      legend="below", note=note, size=(10, 9))


def save_figure(spec: FigureSpec, stem: Path) -> list[Path]:
    """PNG and SVG of the spec at `stem`."""
    return save(draw(spec), stem, ("png", "svg"))
