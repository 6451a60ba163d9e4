"""The two examples of issue 34, end to end: the ball between two electromagnets (n_m = 1, n_e = 2, flux-driven,
operating point by a bias) and the charge-driven parallel-plate actuator (x_e ~ 3e-12 C, Gamma and phi in its
scale). Each is built by `emcosim plant build`, its FMUs pass `fmpy validate`, and its committed scenarios
(regulation with Proposition 2, tracking with Theorem 3) run as Co-Simulation and as Model Exchange to the
set-point and along the reference.

Independent truths, written here from the paper and not from components/: the plant (eq. open-loop elecmech) of
each device, the laws (u2) and (tracker2) with Phi_2 / Theta_2 = 1/2 (z - L)^T K_c (z - L), z of eq. (z), L from
grad H_d(eta_d) = 0 (erratum 3) and L_3 from eq. (L2) with G_e (erratum 8), the factorization by the rule of
docs/plant-description.md (s_i = |x_e_d_i| / |(Gamma_0^T q_d)_i|), the references' x_e*(t) by the force balance,
all integrated by scipy's Radau at rtol 1e-10 (the monolithic reference); the matching identity of every design
built at random states.
"""
from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest
from fmpy.validation import validate_fmu
from scipy.integrate import solve_ivp

from components import differentiation
from emcosim.cli import main
from emcosim.devices import registry
from emcosim.devices.scenario import StackedReference, reference_components
from emcosim.engine.results import read_csv
from tests.helpers import random_state_near

ROOT = Path(__file__).resolve().parents[1]
BALL = ROOT / "examples" / "two_magnet_ball" / "two_magnet_ball.toml"
PLATE = ROOT / "examples" / "parallel_plate" / "parallel_plate.toml"
DEVICES = {"TwoMagnetBall": (BALL, {"Proposition2", "Theorem3"}),
           "ParallelPlate": (PLATE, {"Proposition1", "Proposition2", "Theorem2", "Theorem3"})}


def _sig6(x: float) -> float:
    return float(f"{x:.6g}")


# ---- the two devices and the laws, from the paper ---------------------------------------------------------

class Ball:
    """m q'' = -b + x_1^2/(2k) - x_2^2/(2k); x_i' = -R_c Psi_ii x_i + u_i, Psi = diag((c - q)/k, q/k)."""

    m, b, c, k, R_c = 0.0844, 0.8280, 0.01, 0.64042, 2.25
    q_d, bias = 0.005, 0.5
    omega_m = 76.0                  # the ball's closed-loop mechanical frequency [1/s]
    R_bar, K_c = 1000.0 * np.eye(2), 1000.0 * np.eye(2)
    G, R_e = np.eye(2), 2.25 * np.eye(2)

    def __init__(self):
        x_d = self.x_e_star(self.q_d, 0.0, 0.0)[0]
        gamma_0 = np.array([1 / (2 * self.k), -1 / (2 * self.k)])     # -(dPsi_ii/dq)/2, Section 7.2
        self.s = np.array([_sig6(abs(x_d[i]) / abs(gamma_0[i] * self.q_d)) for i in range(2)])
        self.Gamma = (gamma_0 * self.s).reshape(1, 2)

    def psi(self, q):
        return np.diag([(self.c - q) / self.k, q / self.k])

    def f(self, eta, u):
        q, p, x = eta[0], eta[1], eta[2:]
        force = -self.b + x[0] ** 2 / (2 * self.k) - x[1] ** 2 / (2 * self.k)
        return np.concatenate([[p / self.m, force], -self.R_e @ self.psi(q) @ x + self.G @ u])

    def x_e_star(self, q, qdd, qddd):
        """The bias rule: x_2 = 0.5, x_1 from the force balance; (x_e*, x_e*')."""
        x1 = math.sqrt(2 * self.k * (self.m * qdd + self.b) + self.bias ** 2)
        return np.array([x1, self.bias]), np.array([self.k * self.m * qddd / x1, 0.0])

    def grad_phi(self, x):
        return x ** 2 / self.s


class Plate:
    """m q'' = -k_s q - R_m q' + x^2/(2 eps_A); x' = (u - Psi x)/r, Psi = (g0 - q)/eps_A."""

    m, k_s, R_m, g0, eps_A, r = 1e-7, 10.0, 1e-4, 2e-6, 8.854e-19, 1e8
    q_d = 0.5e-6
    omega_m = 1e4                   # sqrt(k_s / m) [1/s]
    R_bar, K_c = 2e-8 * np.eye(1), 1e12 * np.eye(1)
    G, R_e = np.eye(1) / 1e8, np.eye(1) / 1e8

    def __init__(self):
        x_d = self.x_e_star(self.q_d, 0.0, 0.0, 0.0)[0]
        gamma_0 = 1 / (2 * self.eps_A)
        self.s = np.array([_sig6(abs(x_d[0]) / abs(gamma_0 * self.q_d))])
        self.Gamma = np.array([[gamma_0 * self.s[0]]])

    def psi(self, q):
        return np.array([[(self.g0 - q) / self.eps_A]])

    def f(self, eta, u):
        q, p, x = eta[0], eta[1], eta[2:]
        force = -self.k_s * q - self.R_m * p / self.m + x[0] ** 2 / (2 * self.eps_A)
        return np.concatenate([[p / self.m, force], -self.R_e @ self.psi(q) @ x + self.G @ u])

    def x_e_star(self, q, qd, qdd, qddd=0.0):
        F = self.m * qdd + self.R_m * qd + self.k_s * q
        F_dot = self.m * qddd + self.R_m * qdd + self.k_s * qd
        x = math.sqrt(2 * self.eps_A * F)
        return np.array([x]), np.array([self.eps_A * F_dot / x])

    def grad_phi(self, x):
        return x ** 2 / self.s


def law(dev, eta, x_star=None, x_star_dot=None, q_star=None, p_star=0.0, D_d=None):
    """eq. (u2) (x_star None: regulation at q_d) or eq. (tracker2), J_e = 0, coupled damping D_d (n_e-vector)."""
    q, p, x = eta[0], eta[1], eta[2:]
    D = np.zeros(len(x)) if D_d is None else np.asarray(D_d, dtype=float)
    JR = -dev.R_bar
    A = -dev.G.T @ np.linalg.inv(JR).T                  # z = A (Gamma^T q + x_e), eq. (z)
    K_inv_G_inv = np.linalg.solve(dev.K_c, np.linalg.inv(dev.G))
    if x_star is None:
        x_d = dev.x_e_star(dev.q_d, *([0.0] * (2 if isinstance(dev, Ball) else 3)))[0]
        z_d = A @ (dev.Gamma.T[:, 0] * dev.q_d + x_d)
        L = z_d - K_inv_G_inv @ (JR @ dev.grad_phi(x_d))
    else:
        z_s = A @ (dev.Gamma.T[:, 0] * q_star + x_star)
        L = z_s - K_inv_G_inv @ ((D - dev.Gamma.T[:, 0]) * p_star / dev.m + JR @ dev.grad_phi(x_star) - x_star_dot)
    z = A @ (dev.Gamma.T[:, 0] * q + x)
    return np.linalg.solve(dev.G, dev.R_e @ dev.psi(q) @ x + (D - dev.Gamma.T[:, 0]) * p / dev.m
                           + JR @ dev.grad_phi(x)) - dev.K_c @ (z - L)


def reference_law(dev, omega, offset, amplitude, D_d=None):
    def u(t, eta):
        qs = offset + amplitude * math.sin(omega * t)
        qd = amplitude * omega * math.cos(omega * t)
        qdd = -amplitude * omega ** 2 * math.sin(omega * t)
        qddd = -amplitude * omega ** 3 * math.cos(omega * t)
        x_s, x_s_dot = dev.x_e_star(qs, qdd, qddd) if isinstance(dev, Ball) else dev.x_e_star(qs, qd, qdd, qddd)
        return law(dev, eta, x_s, x_s_dot, qs, dev.m * qd, D_d)
    return u


def monolithic(dev, u, eta0, t):
    """q(t) of the plant in closed loop with u, by Radau on the states scaled to their size (the momentum's at
    the mechanical frequency omega_m: p ~ m q_d omega_m)."""
    scale = np.maximum(np.abs(eta0), [dev.q_d, dev.m * dev.q_d * dev.omega_m] + [1e-3 * np.max(np.abs(eta0[2:]))]
                       * (len(eta0) - 2))
    sol = solve_ivp(lambda s, xi: dev.f(xi * scale, u(s, xi * scale)) / scale, (0.0, t[-1]), eta0 / scale,
                    method="Radau", t_eval=t, rtol=1e-10, atol=1e-12)
    assert sol.success, sol.message
    return sol.y[0] * scale[0]


# ---- the tests ---------------------------------------------------------------------------------------------

@pytest.fixture(scope="module")
def built(tmp_path_factory) -> dict[str, Path]:
    out = {}
    for name, (path, _) in DEVICES.items():
        folder = tmp_path_factory.mktemp(name)
        assert main(["plant", "build", str(path), "--out", str(folder)]) == 0
        out[name] = folder
    return out


@pytest.mark.parametrize("name", list(DEVICES))
def test_the_designs_that_apply_are_built_and_valid(name, built):
    fmus = {p.stem for p in built[name].glob("*.fmu")}
    assert fmus == {name, "Reference"} | {f"{name}_{d}" for d in DEVICES[name][1]}
    for fmu in sorted(built[name].glob("*.fmu")):
        assert validate_fmu(str(fmu)) == [], fmu.name


@pytest.mark.parametrize("design", ["Proposition2", "Theorem3"])
def test_matching_identity_of_the_ball(design):
    _, _, device = registry.load(BALL)
    ctrl = device.controller(design)
    rng = np.random.default_rng(5)
    ref = StackedReference(reference_components(device.q, [{"kind": "sinusoid", "offset": 0.005, "amplitude": 0.001,
                                                             "omega": 5.0}], "ball")) if ctrl.tracking else None
    F_d, worst = ctrl.F_d(), 0.0
    for _ in range(100):
        jet = None if ref is None else ref.jet(rng.uniform(0.0, 2.0))
        eta = random_state_near(ctrl.target(jet), rng, ctrl.plant)
        lhs = ctrl.plant.f(eta, ctrl.u(eta, jet))
        gH = differentiation.gradient(lambda e: ctrl.H_d(e, jet), eta, scale=np.abs(eta) + 1e-30)
        worst = max(worst, float(np.max(np.abs(lhs - F_d @ gH) / (np.abs(F_d) @ np.abs(gH)))))
    assert worst < 1e-9, worst


def test_the_laws_written_here_are_the_controllers():
    """The monolithic reference's laws equal the built controllers' at random states (to rounding)."""
    rng = np.random.default_rng(2)
    for dev, path in ((Ball(), BALL), (Plate(), PLATE)):
        device = registry.load(path)[2]
        for design in ("Proposition2", "Theorem3"):
            D_d = [3.0, -2.0] if isinstance(dev, Ball) and design == "Theorem3" else None
            ctrl = device.controller(design, {"D_d_1_1": 3.0, "D_d_2_1": -2.0} if D_d else {})
            ref = StackedReference(reference_components(device.q, [{"kind": "sinusoid", "offset": dev.q_d,
                                                                    "amplitude": 0.2 * dev.q_d, "omega": 7.0}], "x"))
            for _ in range(20):
                t = rng.uniform(0, 1)
                jet = ref.jet(t) if ctrl.tracking else None
                eta = random_state_near(ctrl.target(jet), rng, ctrl.plant)
                mine = law(dev, eta) if jet is None else reference_law(dev, 7.0, dev.q_d, 0.2 * dev.q_d, D_d)(t, eta)
                assert np.asarray(ctrl.u(eta, jet)) == pytest.approx(mine, rel=1e-7, abs=1e-9 * np.max(np.abs(mine)))


def _run(folder: Path, fmu_dir: Path, tmp_path: Path, interface: str) -> dict[str, np.ndarray]:
    out = tmp_path / f"{folder.parent.name}_{folder.name}_{interface}.csv"
    assert main(["run", str(folder), "--fmu-dir", str(fmu_dir), "--interface-type", interface, "--output", str(out),
                 "--no-progress"]) == 0
    return read_csv(out)          # the results' comment lines (the run's error estimate) skipped


CASES = [("TwoMagnetBall", "scenario", None), ("TwoMagnetBall", "tracking", (5.0, 0.005, 0.001, [100.0, -100.0])),
         ("ParallelPlate", "scenario", None), ("ParallelPlate", "tracking", (3000.0, 5e-7, 1e-7))]


@pytest.mark.slow
@pytest.mark.parametrize("interface", ["CoSimulation", "ModelExchange"])
@pytest.mark.parametrize("name, which, sinusoid", CASES)
def test_the_scenarios_run_to_the_set_point_and_along_the_reference(name, which, sinusoid, interface, built, tmp_path):
    folder = DEVICES[name][0].parent / which
    r = _run(folder, built[name], tmp_path, interface)
    dev = Ball() if name == "TwoMagnetBall" else Plate()
    states = ["plant.q", "plant.p"] + (["plant.x_1", "plant.x_2"] if name == "TwoMagnetBall" else ["plant.x_e"])
    eta0 = np.array([r[s][0] for s in states])
    u = (lambda t, e: law(dev, e)) if sinusoid is None else reference_law(dev, *sinusoid)
    q_truth = monolithic(dev, u, eta0, r["time"])
    span = float(np.ptp(q_truth))
    assert np.max(np.abs(r["plant.q"] - q_truth)) < 1e-3 * span
    target = (np.full_like(r["time"], dev.q_d) if sinusoid is None
              else sinusoid[1] + sinusoid[2] * np.sin(sinusoid[0] * r["time"]))
    error = np.abs(r["plant.q"] - target)
    assert error[-1] < 0.01 * error[0]


@pytest.mark.parametrize("name, which", [(n, w) for n, w, _ in CASES])
def test_the_committed_scenarios_are_what_plant_scenario_writes(name, which, tmp_path):
    import re
    folder = DEVICES[name][0].parent / which
    command = (folder.parent / f"{which}.args").read_text().split()
    out = tmp_path / which
    assert main(["plant", "scenario", str(DEVICES[name][0]), *command, "--out", str(out),
                 "--fmu-dir", str(ROOT / "build" / name)]) == 0

    def text(path: Path) -> str:
        return re.sub(r'source="[^"]*/([A-Za-z0-9_]+\.fmu)"', r'source="\1"', path.read_text())
    written = {p.name: text(p) for p in out.iterdir() if p.name != ".emcosim"}   # the output folder's manifest
    assert written == {p.name: text(p) for p in folder.iterdir()}
