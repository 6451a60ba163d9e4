"""Compare a co-simulation of a paper scenario with the monolithic closed-loop reference.

Physics-aware, so kept apart from the master: it reads the scenario's .ssv files, builds the same
plant, controller and reference from components/ (mapped by FMU model identifier), integrates
the closed loop as one ODE (components.monolithic, Radau at rtol 1e-10) and measures

    normalised maximum position error  e = max_k |q_cosim(t_k) - q_mono(t_k)| / max_t |q*(t)|

over the monolithic sample times t_k in [t0, t_stop] that are communication points of the
co-simulation, normalised by the largest target position q*(t) (the reference, or the set-point)
over the scenario's whole horizon, so that a run over a shorter horizon is judged on the same
scale (`position_scale`). The samples t_k are communication points (no interpolation: interpolating between
communication points would add an O(h^2) error of its own). `samples_for` gives a monolithic grid that is a
subset of the communication grid.

Runs with error-controlled steps have communication points anywhere: `Truth` evaluates the
monolithic solution at any time by cubic Hermite interpolation of its dense samples with the exact
slope q' = f(eta, u(eta, t))_q of the closed loop, and measures the same norm at the run's own
communication points.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from components import catalog
from components.monolithic import Result as MonolithicResult
from components.monolithic import simulate as simulate_monolithic

from ..engine.ssd import Scenario

TRUTH_SAMPLES = 20001           # samples of `Truth` (Hermite error ~ (dt lambda)^4 / 384 of a mode)
HEAD = 0.01                     # `Truth` samples the first HEAD of the horizon as densely again


@dataclass
class Loop:
    """The monolithic counterpart of a scenario."""

    controller: object
    eta0: np.ndarray
    reference: object | None
    position: str                   # the recorded full name of the plant position, e.g. "plant.q"


def monolithic_loop(scenario: Scenario) -> Loop:
    """Plant, controller, reference and initial state of a paper scenario, from its .ssv values
    (components.catalog maps the FMU model identifiers onto the components)."""
    by_model = {c.source.stem: c for c in scenario.components}
    plant_model = next(m for m in catalog.PLANTS if m in by_model)
    plant_comp = by_model[plant_model]
    pv = {k: p.value for k, p in plant_comp.parameters.items()}
    eta0 = np.array([pv["q_0"], pv["p_0"], pv["x_e_0"]], dtype=float)
    controller_model = next(m for m in catalog.GAINS if m in by_model)
    controller = catalog.controller(controller_model, {k: p.value for k, p in by_model[controller_model].parameters.items()})
    reference = None
    if "Reference" in by_model:
        rv = {k: p.value for k, p in by_model["Reference"].parameters.items()}
        reference = catalog.reference(int(rv.pop("kind", 0)), rv)
    return Loop(controller, eta0, reference, f"{plant_comp.name}.q")


def monolithic(scenario: Scenario, stop_time: float | None = None, n_samples: int = 2001,
               rtol: float = 1e-10) -> MonolithicResult:
    loop = monolithic_loop(scenario)
    t_end = scenario.stop_time if stop_time is None else stop_time
    result = simulate_monolithic(loop.controller, loop.eta0, t_end, reference=loop.reference,
                                 n_samples=n_samples, rtol=rtol)
    if not result.success:
        raise RuntimeError(f"{scenario.name}: monolithic reference failed: {result.message}")
    return result


def samples_for(t_end: float, step_size: float, max_samples: int = 4001) -> int:
    """A number of monolithic samples over [0, t_end] whose spacing is a multiple of step_size."""
    n_steps = int(round(t_end / step_size))
    stride = max(1, -(-n_steps // (max_samples - 1)))
    while n_steps % stride:
        stride += 1
    return n_steps // stride + 1


def position_scale(scenario: Scenario, n: int = 2001) -> float:
    """max |q*(t)| over the scenario's horizon: the target position (reference or set-point)."""
    loop = monolithic_loop(scenario)
    ts = np.linspace(scenario.start_time, scenario.stop_time, n)
    jets = [loop.reference.jet(t) if loop.reference is not None else None for t in ts]
    return float(max(abs(loop.controller.target(j)[0]) for j in jets))


def position_error(t: np.ndarray, q: np.ndarray, reference: MonolithicResult, scale: float,
                   interpolate: bool = False) -> float:
    """Normalised maximum position error of (t, q) against the monolithic reference (module doc);
    scale is `position_scale(scenario)`. interpolate=True (for non-equidistant communication
    points, e.g. error-controlled steps) interpolates (t, q) linearly at the reference's samples."""
    t = np.asarray(t)
    if interpolate:
        return float(np.max(np.abs(np.interp(reference.t, t, q) - reference.q)) / scale)
    idx = np.clip(np.searchsorted(t, reference.t), 0, len(t) - 1)
    idx_left = np.clip(idx - 1, 0, len(t) - 1)
    idx = np.where(np.abs(t[idx_left] - reference.t) < np.abs(t[idx] - reference.t), idx_left, idx)
    tol = 1e-9 * max(1.0, float(np.max(np.abs(reference.t))))
    match = np.abs(t[idx] - reference.t) <= tol
    if match.sum() < min(10, len(reference.t)):
        raise ValueError("the monolithic samples are not communication points of the co-simulation "
                         "(use samples_for to choose n_samples)")
    err = np.abs(np.asarray(q)[idx[match]] - reference.q[match])
    return float(np.max(err) / scale)


@dataclass
class Truth:
    """The monolithic closed loop of a scenario, evaluable at any time in [0, t_end]: cubic Hermite
    interpolation of dense samples with the exact slope, denser over the initial transient (`head`)."""

    t_end: float
    head: float                     # end of the densely sampled initial part [s]
    q_head: object                  # scipy CubicHermiteSpline of the position over [0, head]
    q_rest: object                  # ... over [0, t_end]
    scale: float                    # position_scale of the scenario

    def q(self, t) -> np.ndarray:
        t = np.asarray(t, dtype=float)
        return np.where(t <= self.head, self.q_head(np.minimum(t, self.head)), self.q_rest(t))

    def position_error(self, t, q) -> float:
        """Normalised maximum position error (module doc) of a run at its own communication points."""
        t, q = np.asarray(t, dtype=float), np.asarray(q, dtype=float)
        if t[-1] > self.t_end * (1 + 1e-12):
            raise ValueError(f"the run reaches t = {t[-1]:g} s beyond the reference's {self.t_end:g} s")
        return float(np.max(np.abs(q - self.q(t))) / self.scale)


def truth(scenario: Scenario, stop_time: float | None = None, n_samples: int = TRUTH_SAMPLES,
          rtol: float = 1e-10, head: float = HEAD) -> Truth:
    """The monolithic reference of `monolithic` over [0, stop_time] (default: the scenario's
    horizon), sampled at n_samples points, and over its first `head` fraction at n_samples more."""
    t_end = scenario.stop_time if stop_time is None else stop_time
    return Truth(t_end, head * t_end, _spline(scenario, head * t_end, n_samples, rtol),
                 _spline(scenario, t_end, n_samples, rtol), position_scale(scenario))


def _spline(scenario: Scenario, t_end: float, n_samples: int, rtol: float):
    from scipy.interpolate import CubicHermiteSpline

    from components.monolithic import ClosedLoop

    loop = monolithic_loop(scenario)
    result = monolithic(scenario, t_end, n_samples, rtol)
    closed = ClosedLoop(loop.controller, loop.reference)
    slope = np.array([closed.rhs(t, eta)[0] for t, eta in zip(result.t, result.eta)])
    return CubicHermiteSpline(result.t, result.q, slope)
