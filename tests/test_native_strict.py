"""strict = 0 and strict = 1 of the native controller FMUs against their pythonfmu twins (issue 32).

The twin (fmus/controller.py) checks components.certificates.design_checks at fmi2ExitInitializationMode: a
violated condition is a warning with strict = 0 ("...; running anyway (strict = 0)") and a refusal with strict = 1.
The native FMU decides the same conditions in C (emc_controller.c: Jacobi eigenvalues, the unit-diagonal scaled
definiteness test, Routh-Hurwitz) from the matrices components.laws.design_matrices states. For each native
controller (the paper's four, the examples' twelve) and parameter values from the paper's and the examples' numbers,
kept and deliberately broken, both FMUs run through fmpy with their log captured: the statuses must be equal and
the messages equal word for word, their numbers to the 4 digits printed (the twin's eigenvalues are numpy's, the
native ones Jacobi's and Durand-Kerner's; a real part on the imaginary axis prints as 0 or -0).

Independent truths beside the twin: which conditions fail, reasoned from the paper's formulas in CASES' comments.
"""
from __future__ import annotations

import re
import shutil
from ctypes import byref
from pathlib import Path

import pytest
from fmpy import extract, read_model_description
from fmpy.fmi1 import FMICallException
from fmpy.fmi2 import (
    FMU2Slave,
    calloc,
    fmi2CallbackAllocateMemoryTYPE,
    fmi2CallbackFreeMemoryTYPE,
    fmi2CallbackFunctions,
    fmi2CallbackLoggerTYPE,
    free,
    printLogMessage,
)
from fmpy.logging import addLoggerProxy

needs_gcc = pytest.mark.skipif(shutil.which("gcc") is None, reason="needs gcc")
OK, WARNING, ERROR = 0, 1, 3
K_E = "K_e = R_e_bar - R_e"
HURWITZ = "Theorem 1 (i): F_d Hurwitz"

# identifier: [(parameter values, the names of the conditions they violate)]
PAPER_CASES = {
    "MEMS_Proposition1": [({}, []),
                          ({"rbar_e": 200.0}, [f"{K_E} >= 0 (Proposition 1)"])],       # R_e_bar = 1/rbar_e < 1/r_e
    "MEMS_Theorem2": [({}, []),
                      ({"rbar_e": 200.0}, [f"{K_E} >= 0 (Theorem 2)"]),
                      # R_m = 0: det(s I - F_d) = (s + R_e_bar)(s^2 + 1): roots on the imaginary axis
                      ({"R_m": 0.0}, ["Assumption 3: R_m > 0", HURWITZ])],
    "Maglev_Proposition2": [({}, []),
                            ({"R_e_bar": 0.82}, [f"{K_E} >= 0 (Proposition 2)"])],    # the R0.82 scenarios
    "Maglev_Theorem3": [({}, []),
                        ({"R_e_bar": 0.82}, [f"{K_E} > 0 (Theorem 3)"]),
                        # s^3 + R_e_bar s^2 + (1 + Gamma (Gamma - D_d)) s + R_e_bar: a negative coefficient
                        ({"D_d": 50.0}, [HURWITZ]),
                        ({"D_d": 50.0, "R_e_bar": 1.0}, [f"{K_E} > 0 (Theorem 3)", HURWITZ]),
                        ({"q_star": 0.006}, [])],           # past the magnet: Assumption 4 not applicable
}
EXAMPLE_CASES = {
    "Solenoid_Proposition1": [({}, []),
                              # W = 1: the Schur complement of eq. (phi12) needs W > ~100 /H (solenoid.toml)
                              ({"W": 1.0}, ["eq. (phi12): hess H_d(eta_d) > 0"]),
                              ({"R_e_bar": 3.0}, [f"{K_E} >= 0 (Proposition 1)"]),          # R_c = 5 Ohm
                              # past the spring's reach V'' < the magnetic stiffness: hess_q H(eta_d) < 0
                              ({"q_d": 0.0015}, ["Assumption 1", "eq. (phi12): hess H_d(eta_d) > 0"])],
    "Solenoid_Theorem2": [({}, []),
                          ({"R_m": 0.0}, ["Assumption 3: R_m > 0", HURWITZ]),
                          ({"R_e_bar": 3.0}, [f"{K_E} >= 0 (Theorem 2)"])],
    "ParallelPlate_Proposition1": [({}, []),
                                   ({"R_e_bar": 5e-9}, [f"{K_E} >= 0 (Proposition 1)"]),     # 1/r = 1e-8
                                   ({"q_d": 1.2e-6}, ["eq. (phi12): hess H_d(eta_d) > 0"])],  # past pull-in g0/3
    "ParallelPlate_Proposition2": [({}, []),
                                   ({"R_e_bar": 5e-9}, [f"{K_E} >= 0 (Proposition 2)"])],
    "ParallelPlate_Theorem2": [({}, []),
                               ({"R_m": 0.0}, ["Assumption 3: R_m > 0", HURWITZ])],
    "ParallelPlate_Theorem3": [({}, []),
                               ({"D_d": 1e3}, []),
                               ({"R_e_bar": 5e-9}, [f"{K_E} > 0 (Theorem 3)"]),
                               # R_m = 0: real parts -R_e_bar Gamma^2 / 2 ~ -4e-19, within rounding of the axis
                               ({"R_m": 0.0}, [HURWITZ])],
    # n_m = n_e = 2 (Newton's reference in C); Proposition 1 is refused by both at construction (R_m = 0: the strict
    # pH condition), Phic22 and Assumption 2 hold for any gains (hess phi = diag(2 x_e) at x_e_d > 0, Gamma invertible)
    "LevitatedBar_Proposition2": [({}, []),
                                  ({"R_e_bar_1_1": 2.0}, [f"{K_E} >= 0 (Proposition 2)"])],     # R_c = 2.25 Ohm
    # R_m = 0: F_d has +-i twice (a double root: Durand-Kerner alone prints 1.87e-09, the twin -0)
    "LevitatedBar_Theorem2": [({}, ["Assumption 3: R_m > 0", HURWITZ]),
                              ({"R_e_bar_1_1": 2.0}, ["Assumption 3: R_m > 0", f"{K_E} >= 0 (Theorem 2)", HURWITZ])],
    "LevitatedBar_Theorem3": [({}, []),
                              ({"R_e_bar_2_2": 2.25}, [f"{K_E} > 0 (Theorem 3)"]),
                              ({"D_d_1_1": 500.0, "D_d_2_2": 500.0}, [HURWITZ])],               # abscissa 18.79
    # n_e = 2 > n_m = 1: the bias operating point
    "TwoMagnetBall_Proposition2": [({}, []),
                                   ({"R_e_bar_1_1": 2.0}, [f"{K_E} >= 0 (Proposition 2)"])],
    "TwoMagnetBall_Theorem2": [({}, ["Assumption 3: R_m > 0", HURWITZ])],
    "TwoMagnetBall_Theorem3": [({}, []),
                               ({"D_d_1_1": 100.0, "D_d_2_1": -100.0}, []),                    # tracking.args
                               ({"R_e_bar_2_2": 2.25}, [f"{K_E} > 0 (Theorem 3)"]),
                               ({"D_d_1_1": 2e4}, [HURWITZ])],                                   # abscissa 1683
}


# fmpy's logger proxy (fmpy.logging) keeps the logger it formats for in one global of its C library, for every
# FMU of the process: each Logged's logger stays alive here, and the module's end gives fmpy's own back
# (printLogMessage), or later FMUs of the session would call a freed callback (measured: a segmentation fault).
_LOGGERS: list = []


@pytest.fixture(autouse=True, scope="module")
def _fmpy_logger_given_back():
    yield
    mine = fmi2CallbackFunctions()
    _LOGGERS.append(fmi2CallbackLoggerTYPE(printLogMessage))
    mine.logger = _LOGGERS[-1]
    addLoggerProxy(byref(mine))


class Logged:
    """An FMU2Slave with its log captured through fmpy's proxy, which formats each message as a C host does
    (the framework sends plain text with '%' doubled, emc_fmi2.c log_to)."""

    def __init__(self, path: Path):
        md = read_model_description(str(path))
        self.vr = {v.name: v.valueReference for v in md.modelVariables}
        self.messages: list[tuple[int, str]] = []
        self.callbacks = fmi2CallbackFunctions()
        self.callbacks.logger = fmi2CallbackLoggerTYPE(
            lambda env, inst, status, category, message: self.messages.append((status, message.decode())))
        _LOGGERS.append(self.callbacks.logger)
        self.callbacks.allocateMemory = fmi2CallbackAllocateMemoryTYPE(calloc)
        self.callbacks.freeMemory = fmi2CallbackFreeMemoryTYPE(free)
        addLoggerProxy(byref(self.callbacks))
        self.fmu = FMU2Slave(guid=md.guid, unzipDirectory=extract(str(path)),
                             modelIdentifier=md.coSimulation.modelIdentifier, instanceName="strict")
        self.fmu.instantiate(callbacks=self.callbacks, loggingOn=True)

    def initialize(self, strict: int, values: dict[str, float]) -> int:
        self.fmu.setupExperiment(startTime=0.0)
        self.fmu.enterInitializationMode()
        for name, value in values.items():
            self.fmu.setReal([self.vr[name]], [value])
        self.fmu.setInteger([self.vr["strict"]], [strict])
        try:
            return self.fmu.exitInitializationMode() or OK
        except FMICallException as exc:
            return exc.status

    def free(self) -> None:
        self.fmu.freeInstance()


NUMBER = re.compile(r"-?\d+(?:\.\d+)?(?:e[-+]?\d+)?")


def _reason(text: str) -> str:
    """From "the parameters violate" on: the twin's refusal wraps it in "initialization failed: <id>: ", the
    native one in "fmi2ExitInitializationMode: "."""
    return text[text.index("the parameters violate"):]


def _agree(mine: str, twin: str) -> None:
    """Word for word, numbers to the 4 significant digits printed (and 0 within 1e-12, the axis)."""
    assert NUMBER.split(mine) == NUMBER.split(twin), (mine, twin)
    for a, b in zip(NUMBER.findall(mine), NUMBER.findall(twin)):
        x, y = float(a), float(b)
        assert abs(x - y) <= 1e-3 * max(abs(x), abs(y)) + 1e-12, (a, b, mine, twin)


def _violated(text: str) -> list[str]:
    """The names of the violated conditions in a message (each is followed by its numbers in parentheses)."""
    body = re.sub(r"; running anyway \(strict = 0\)$| \(strict = 1\)$", "", text.split("conditions: ", 1)[1])
    return [re.split(r" \((?:min|max) ", part)[0] for part in body.split("; ")]


def _compare(native: Path, twin: Path, cases) -> None:
    for values, violated in cases:
        for strict in (0, 1):
            runs = []
            for path in (native, twin):
                f = Logged(path)
                runs.append((f.initialize(strict, values), f.messages))
                f.free()
            (status, log), (twin_status, twin_log) = runs
            where = f"{native.stem} {values} strict = {strict}"
            assert status == twin_status == (ERROR if violated and strict else OK), (where, runs)
            assert [s for s, _ in log] == [s for s, _ in twin_log], (where, runs)
            if not violated:
                assert log == [], (where, log)
                continue
            assert len(log) == 1, (where, log)
            (level, text), (_, twin_text) = log[0], twin_log[0]
            assert level == (ERROR if strict else WARNING)
            _agree(_reason(text), _reason(twin_text))
            assert _violated(_reason(text)) == violated, (where, text)


@pytest.mark.slow                         # ~2 CPU-s of sympy: the quick set has no room left
@pytest.mark.parametrize("identifier, jet", [("MEMS_Proposition1", None), ("MEMS_Theorem2", (2e-5, 1e-4, -0.5, 3.0)),
                                             ("Maglev_Proposition2", None), ("Maglev_Theorem3", (0.002, 0.01, 0.3, -2.0))])
def test_design_matrices_are_the_numpy_ones(identifier: str, jet) -> None:
    """components.laws.design_matrices (what the C decides) at the twin's default gains equal the hand-written
    numpy forms the twin decides: Controller.hess_H_d(target), closed_loop.F_d, K_e, plant.hess_phi(x_e*),
    plant.hess_H(eta_d)[q, q], R_m (to 1e-12 relative)."""
    import numpy as np
    import sympy

    from components.description import load
    from components.laws import design_law, design_matrices
    from components.ph_plant import Jet
    from fmus.native_build import PAPER_PLANTS, _twin

    slave = _twin(identifier)
    plant_name, _, design = identifier.partition("_")
    desc = load(PAPER_PLANTS[plant_name])
    gains = tuple(p.name for p in slave.device.designs[design].gains.values())
    D = design_matrices(desc, design, gains)
    L = design_law(desc, design, gains)
    controller = slave.make_controller()
    values = {s: slave.values[s.name] for s in desc.parameter_symbols}
    values.update({s: slave.values[s.name] for s in L.gains})
    target_jet = None if jet is None else Jet(*(np.array([v]) for v in jet))
    if jet is not None:
        values.update(dict(zip(L.inputs[3:], jet)))
    eta = controller.target(target_jet)
    m = desc.n_m
    truths = {"hess_H_d": controller.hess_H_d(eta, target_jet), "F_d": controller.F_d(), "K_e": controller.K_e,
              "hess_phi": None if desc.phi is None else controller.plant.hess_phi(eta[2 * m:]),
              "hess_q_H": controller.plant.hess_H(eta)[:m, :m], "R_m": controller.plant.R_m}
    asked = 0
    for field, truth in truths.items():
        M = getattr(D, field)
        if M is None:
            continue
        got = np.array(sympy.Matrix(M).xreplace(values).evalf(), dtype=float)
        want = 0.5 * (truth + truth.T) if field in ("hess_H_d",) else truth
        np.testing.assert_allclose(got, want, rtol=1e-12, atol=1e-12 * np.max(np.abs(want)), err_msg=field)
        asked += 1
    assert asked == {"Proposition1": 4, "Theorem2": 3, "Proposition2": 3, "Theorem3": 3}[design]


@pytest.fixture(scope="module")
def paper_controllers(tmp_path_factory) -> dict[str, Path]:
    from fmus.native_build import build_native_controller
    dest = tmp_path_factory.mktemp("native_strict")
    return {name: build_native_controller(name, dest) for name in PAPER_CASES}


@needs_gcc
@pytest.mark.slow                         # 4 native builds and 26 pairs of initializations: ~9 CPU-s
@pytest.mark.parametrize("name", PAPER_CASES)
def test_paper_controllers_check_as_their_twins(paper_controllers, fmus, name) -> None:
    _compare(paper_controllers[name], fmus[name], PAPER_CASES[name])


@needs_gcc
@pytest.mark.slow                         # 12 native and 12 twin builds: ~40 CPU-s
@pytest.mark.parametrize("example, designs", [("solenoid", ["Proposition1", "Theorem2"]),
                                              ("parallel_plate", ["Proposition1", "Proposition2", "Theorem2",
                                                                  "Theorem3"]),
                                              ("levitated_bar", ["Proposition2", "Theorem2", "Theorem3"]),
                                              ("two_magnet_ball", ["Proposition2", "Theorem2", "Theorem3"])])
def test_example_controllers_check_as_their_twins(tmp_path: Path, example: str, designs: list[str]) -> None:
    from fmus.build import build_description
    from fmus.native_build import build_native_description_fmus
    toml = Path(__file__).resolve().parents[1] / "examples" / example / f"{example}.toml"
    twins = build_description(toml, tmp_path / "twins", designs)
    natives = build_native_description_fmus(toml, designs, tmp_path / "native")
    controllers = sorted(name for name in natives if "_" in name)
    assert controllers == sorted(n for n in EXAMPLE_CASES if n.startswith(next(iter(natives)) + "_"))
    for name in controllers:
        _compare(natives[name], twins[name], EXAMPLE_CASES[name])


# tests/test_described_plants.VARIABLE_MASS: M(q) = [[m + mu theta^2, 0.01 m], [0.01 m, J]], n_m = n_e = 2 (Newton)
VARIABLE_MASS_CASES = {
    # V = b z + kt theta^2 / 2 and Psi linear in q: hess_q H(eta_d) = diag(0, kt) (Assumption 1 asks > 0), and the
    # z-row of hess H_d(eta_d) is zero but for its coupling to x_e: indefinite
    "Bar_Proposition1": [({}, ["Assumption 1", "eq. (phi12): hess H_d(eta_d) > 0"])],
    "Bar_Proposition2": [({}, []),
                         ({"R_e_bar_1_1": 1.0}, [f"{K_E} >= 0 (Proposition 2)"]),             # R = 2 Ohm
                         ({"mu": 50.0}, [])],                                # M(q): p* = 0 at eta_d, no effect
    "Bar_Theorem2": [({}, []),
                     ({"R_e_bar_1_1": 1.0}, [f"{K_E} >= 0 (Theorem 2)"])],
    "Bar_Theorem3": [({}, []),
                     ({"R_e_bar_2_2": 2.0}, [f"{K_E} > 0 (Theorem 3)"])],
}


@needs_gcc
@pytest.mark.slow                         # 4 native and 4 twin builds: ~15 CPU-s
def test_variable_mass_controllers_check_as_their_twins(tmp_path: Path) -> None:
    """The design checks at Newton's reference of a plant with M(q) (its Hessians at eta_d with p* = 0)."""
    from fmus.build import build_description
    from fmus.native_build import build_native_description_fmus
    from tests.test_described_plants import VARIABLE_MASS
    toml = tmp_path / "variable_mass.toml"
    toml.write_text(VARIABLE_MASS)
    designs = ["Proposition1", "Proposition2", "Theorem2", "Theorem3"]
    twins = build_description(toml, tmp_path / "twins", designs)
    natives = build_native_description_fmus(toml, designs, tmp_path / "native")
    for name, cases in VARIABLE_MASS_CASES.items():
        _compare(natives[name], twins[name], cases)


@needs_gcc
@pytest.mark.slow                         # a C compile: the quick set has no room left
def test_design_linear_algebra_against_numpy(tmp_path: Path) -> None:
    """emc_design.c (tests/native/design_numerics.c) at random matrices of orders 1 to 16 against numpy: the smallest
    eigenvalue of the symmetric part (Jacobi) to 1e-13 |A|; the scaled definiteness's verdict and number as
    components.certificates.definiteness, also with entries spanning 40 orders of magnitude (a charge device's
    Hessian); Routh-Hurwitz's verdict as numpy's eigenvalues with the abscissa 0.05 to 1 from the axis; the printed
    abscissa (Durand-Kerner) to 1e-8 |A|; an F_d with roots on the imaginary axis is not Hurwitz."""
    import subprocess

    import numpy as np

    from components.certificates import FAILS, HOLDS, INCONCLUSIVE, definiteness
    native = Path(__file__).resolve().parents[1] / "fmus" / "native"
    host = tmp_path / "design_numerics"
    subprocess.run(["gcc", "-std=c99", "-Wall", "-Wextra", "-Werror", "-I", str(native),
                    str(Path(__file__).resolve().parent / "native" / "design_numerics.c"), str(native / "emc_design.c"),
                    "-o", str(host), "-lm"], check=True, capture_output=True, text=True)
    rng = np.random.default_rng(32)
    general, symmetric = [], []
    for n in range(1, 17):
        for _ in range(6):
            A = rng.normal(size=(n, n))
            abscissa = rng.choice([-1, 1]) * rng.uniform(0.05, 1.0)
            general.append(A - (np.max(np.linalg.eigvals(A).real) - abscissa) * np.eye(n))
            Q = np.linalg.qr(rng.normal(size=(n, n)))[0]
            lam = rng.uniform(0.1, 2.0, n) * np.where(rng.uniform(size=n) < 0.3, -1.0, 1.0)
            scale = np.diag(10.0 ** rng.uniform(-20, 20, n))
            symmetric.append(scale @ (Q * lam) @ Q.T @ scale)
    on_axis = np.array([[0.0, 1.0, 0.0], [-1.0, 0.0, 0.0], [0.0, 0.0, -1.0]])        # F_d of R_m = 0, Gamma = 0
    matrices = general + symmetric + [on_axis]
    text = "".join(f"{len(A)} " + " ".join(repr(float(x)) for x in A.ravel()) + "\n" for A in matrices)
    run = subprocess.run([str(host)], input=text, capture_output=True, text=True, check=True, timeout=60)
    rows = [line.split() for line in run.stdout.splitlines()]
    assert len(rows) == len(matrices)
    verdicts = {HOLDS: 0, FAILS: 1, INCONCLUSIVE: 2}
    for A, (min_eig, verdict, number, hurwitz, shift, abscissa) in zip(general, rows):
        size = np.linalg.norm(A, 2)
        assert abs(float(min_eig) - np.min(np.linalg.eigvalsh(0.5 * (A + A.T)))) <= 1e-13 * size
        want = np.max(np.linalg.eigvals(A).real)
        assert int(hurwitz) == int(want < 0), (A, want)
        assert abs(float(abscissa) - want) <= 1e-8 * size, (len(A), abscissa, want)
        assert 0 < float(shift) < 1e-12 * max(1.0, np.max(np.abs(A)))
    for A, (_, verdict, number, *_) in zip(symmetric, rows[len(general):]):
        want_verdict, want_number, _ = definiteness(A)
        assert int(verdict) == verdicts[want_verdict], (A, want_verdict)
        assert float(number) == pytest.approx(want_number, rel=1e-10, abs=1e-12)
    assert rows[-1][3] == "0" and abs(float(rows[-1][5])) < 1e-12
