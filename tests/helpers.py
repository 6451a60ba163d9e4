"""Helpers shared by the test modules (no test module imports another): scenario builders over the C toy
FMUs, the paper's scenarios, controller cases, numerical derivatives, an FMU addressed by variable names.
Fixtures live in conftest.py."""
from __future__ import annotations

from pathlib import Path

import numpy as np
from fmpy import calloc, free, read_model_description
from fmpy.fmi1 import FMICallException
from fmpy.fmi2 import (
    FMU2Slave,
    fmi2CallbackAllocateMemoryTYPE,
    fmi2CallbackFreeMemoryTYPE,
    fmi2CallbackFunctions,
    fmi2CallbackLoggerTYPE,
)

from components.maglev import D_d_from_paper, Maglev
from components.mems import MEMS, R_e_bar_from_rbar_e
from components.proposition1 import Proposition1
from components.proposition2 import Proposition2
from components.references import Sinusoid, SmoothStep
from components.theorem2 import Theorem2
from components.theorem3 import Theorem3
from emcosim.engine.ssd import Connector, read_scenario
from tests.plants_for_tests import TwoAxisLevitator, VectorSinusoid

ROOT = Path(__file__).resolve().parents[1]


# ---- loops of the C toy FMUs (tests/toy_fmus.py; the `make` fixture builds them) ------------------------
DYNAMIC = [Connector("u", "input", "Real"), Connector("x", "output", "Real")]
STATIC = [Connector("u1", "input", "Real"), Connector("u2", "input", "Real"), Connector("y", "output", "Real")]
SINE = [Connector("y", "output", "Real")]


def loop(make, k=-1.0, order=3, interpolate=True, factor=1.0, stop_time=1.0, step_size=0.01):
    """plant (ToyDynamic, x' = u) and ctrl (ToyStatic, y = k1 u1) in a loop: x' = k x."""
    return make([("plant", "dynamic", DYNAMIC, interpolate, order), ("ctrl", "static", STATIC, interpolate, order)],
                [("plant.x", "ctrl.u1"), ("ctrl.y", "plant.u", factor)],
                {"ctrl": {"k1": k}, "plant": {"x0": 1.0}}, stop_time, step_size)


# ---- the paper's scenarios ------------------------------------------------------------------------------
def scenario(name: str, fmu_dir: Path):
    return read_scenario(ROOT / "scenarios" / name, fmu_dir=fmu_dir)


def declares_derivatives(s) -> bool:
    from fmpy import read_model_description
    mds = [read_model_description(str(c.source)) for c in s.components]
    return all(md.coSimulation.canInterpolateInputs for md in mds if any(
        v.causality == "input" for v in md.modelVariables)) and all(
        md.coSimulation.maxOutputDerivativeOrder >= 1 for md in mds)


TIGHT = {"plant.rtol": 1e-9}     # the plant's integration error far below the coupling's at the smallest steps


# ---- controller cases (components/) ---------------------------------------------------------------------
MAGLEV_REF = Sinusoid(offset=0.0025, amplitude=0.001, omega=5.0)
TWO_AXIS_REF = VectorSinusoid([0.1, 0.2], [0.05, 0.03], [2.0, 3.0], [0.0, 1.0])
RBAR = R_e_bar_from_rbar_e(100.0)


def cases():
    mems, mag, two, two_damped = MEMS(), Maglev(), TwoAxisLevitator(), TwoAxisLevitator(damped=True)
    D1 = np.array([[0.03, -0.01], [0.0, 0.02]])          # satisfies eq. (pHcondition) strictly for two_damped
    D2 = np.array([[0.03, 0.0], [0.01, 0.0]])            # R_m = diag(0.1, 0): second column must vanish
    return {
        "MEMS Prop1": (Proposition1(mems, 3e-5, RBAR, D_d=1e-4), None, 1),
        "MEMS Thm2 sinusoid": (Theorem2(mems, RBAR, D_d=-0.4), Sinusoid(), 0.2),
        "MEMS Thm2 smooth step": (Theorem2(mems, RBAR, D_d=-1.0), SmoothStep(q_from=1e-5, q_to=3e-5, duration=1e-3), 1e-3),
        "maglev Prop2": (Proposition2(mag, 0.0025, 2.82, k_c=20.0), None, 1),
        "maglev Thm3": (Theorem3(mag, 0.82, k_c=20.0, D_d=D_d_from_paper(-1.0)), MAGLEV_REF, 2.0),
        "2-axis Prop1": (Proposition1(two_damped, [0.1, 0.2], np.diag([1.5, 2.5]), D_d=D1), None, 1),
        "2-axis Thm2": (Theorem2(two, np.array([[1.5, 0.2], [0.1, 2.5]]), D_d=[[0.3, -1.0], [2.0, 0.1]]), TWO_AXIS_REF, 3.0),
        "2-axis Prop2": (Proposition2(two, [0.1, 0.2], np.diag([1.5, 2.5]), k_c=[[3.0, 0.5], [0.5, 2.0]], D_d=D2), None, 1),
        "2-axis Thm3": (Theorem3(two, np.array([[1.5, 0.2], [0.1, 2.5]]), k_c=[[3.0, 0.5], [0.5, 2.0]],
                                 D_d=[[0.3, -1.0], [2.0, 0.1]]), TWO_AXIS_REF, 3.0),
    }


CASES = cases()


def random_state_near(eta_star, rng, plant):
    """A random admissible state: each coordinate of the target perturbed by up to 50% of its block's size
    (the momentum block of a set-point, where p* = 0, by sqrt(m x 1 N/m) |q*|)."""
    q, p, x = plant.split(eta_star)
    p_floor = np.sqrt(1.0 / np.diag(plant.M_inv(q))) * np.max(np.abs(q))
    scale = np.concatenate([np.abs(q) + 0.1 * np.max(np.abs(q)),
                            np.abs(p) + 0.1 * np.max(np.abs(p)) + p_floor,
                            np.abs(x) + 0.1 * np.max(np.abs(x))])
    for _ in range(100):
        eta = eta_star + 0.5 * scale * rng.uniform(-1, 1, eta_star.size)
        if plant.domain_margin(eta) > 0:
            return eta
    raise AssertionError("no admissible sample")


# ---- numerical derivatives ------------------------------------------------------------------------------
def richardson_derivative(fun, x: np.ndarray, v: np.ndarray, scale: float, decades=(12, -12)):
    """d/de fun(x + e v) at e = 0 by central differences with one Richardson step, (4 D(h/2) - D(h)) / 3,
    for h = scale * 10^k, k = decades[0] .. decades[1]: the estimate of the three consecutive steps that
    agree best (steps whose evaluation fails, e.g. outside the domain, are skipped, and so are steps whose
    differences are below 1e-10 of |fun(x)|: there the rounding of fun, a few ulps, is > 1e-6 of the estimate,
    and consecutive estimates can agree exactly, by the same rounding, on a wrong value)."""
    estimates = []
    size = float(np.max(np.abs(np.atleast_1d(fun(x)))))
    for k in range(decades[0], decades[1] - 1, -1):
        h = scale * 10.0 ** k
        try:
            d1, d2 = fun(x + h * v) - fun(x - h * v), fun(x + 0.5 * h * v) - fun(x - 0.5 * h * v)
            D1, D2 = d1 / (2 * h), d2 / h
            R = np.atleast_1d((4 * D2 - D1) / 3)
            if float(np.max(np.abs(np.atleast_1d(d2)))) < 1e-10 * size:
                R = None                                   # rounding-dominated
        except (ValueError, ArithmeticError):
            R = None
        estimates.append(R if R is not None and np.all(np.isfinite(R)) else None)
    best = None
    for a, b, c in zip(estimates, estimates[1:], estimates[2:]):
        if a is None or b is None or c is None or not (np.any(a) or np.any(b)):
            continue
        spread = max(np.max(np.abs(a - b)), np.max(np.abs(c - b))) / max(np.max(np.abs(a)), np.max(np.abs(b)))
        if best is None or spread < best[0]:
            best = (spread, b)
    return np.zeros_like(np.atleast_1d(fun(x))) if best is None else best[1]


# ---- an FMU addressed by variable names -------------------------------------------------------------------
class Slave:
    """An FMU2Slave addressed by variable names, with the FMU's log messages captured."""

    def __init__(self, path, name="instance"):
        self.md = read_model_description(str(path))
        from fmpy import extract

        self.unzipdir = extract(str(path))
        self.vr = {v.name: v.valueReference for v in self.md.modelVariables}
        self.integer = {v.name for v in self.md.modelVariables if v.type == "Integer"}
        self.messages: list[tuple[int, str]] = []
        self.callbacks = fmi2CallbackFunctions()
        self.callbacks.logger = fmi2CallbackLoggerTYPE(
            lambda env, inst, status, cat, msg: self.messages.append((status, msg.decode())))
        self.callbacks.allocateMemory = fmi2CallbackAllocateMemoryTYPE(calloc)
        self.callbacks.freeMemory = fmi2CallbackFreeMemoryTYPE(free)
        self.fmu = FMU2Slave(guid=self.md.guid, unzipDirectory=self.unzipdir,
                             modelIdentifier=self.md.coSimulation.modelIdentifier, instanceName=name)
        self.fmu.instantiate(callbacks=self.callbacks, loggingOn=True)

    def init(self, start_time=0.0, **values) -> int:
        self.fmu.setupExperiment(startTime=start_time)
        self.fmu.enterInitializationMode()
        self.set(**values)
        return self.call(self.fmu.fmi2ExitInitializationMode, self.fmu.component)

    def set(self, **values) -> None:
        for name, value in values.items():
            if name in self.integer:
                self.fmu.setInteger([self.vr[name]], [int(value)])
            else:
                self.fmu.setReal([self.vr[name]], [float(value)])

    def get(self, *names) -> list[float]:
        return self.fmu.getReal([self.vr[n] for n in names])

    def step(self, t, h) -> int:
        return self.call(self.fmu.fmi2DoStep, self.fmu.component, t, h, 1)

    @staticmethod
    def call(function, *args) -> int:
        try:
            return function(*args)
        except FMICallException as exc:
            return exc.status

    def errors(self) -> str:
        return "\n".join(m for s, m in self.messages if s >= 3)

    def free(self) -> None:
        self.fmu.fmi2FreeInstance(self.fmu.component)
