"""The control laws stated once (components.laws), printed as Python (components.codegen: the generated
feasible_scalar, law_<family>_at, law_<family>_tracking that Controller.scalars evaluates), against the laws
written by hand in scalars (tests/hand_written_laws.py, components/ before they were generated).

At random parameters, gains, states and reference jets, for the paper's MEMS and maglev and the one-DOF
example devices: u, its complex-step derivative (what fmi2GetDirectionalDerivative returns) and the
feasible reference (Definition 1) agree to 1e-12 relative; an infeasible reference is refused by both."""
from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from components import codegen, maglev, mems
from components.description import load
from components.ph_plant import Jet
from components.proposition1 import Proposition1
from components.proposition2 import Proposition2
from components.theorem2 import Theorem2
from components.theorem3 import Theorem3
from tests.hand_written_laws import feasible_scalar, u_scalar

RTOL = 1e-12
ROOT = Path(__file__).resolve().parents[1]


def close(a, b, rtol=RTOL) -> bool:
    return abs(a - b) <= rtol * max(abs(b), 1e-300)


def _mems(rng):
    plant = mems.MEMS(a1=rng.uniform(0.3, 0.6), r_e=rng.uniform(50, 200), R_m=rng.uniform(1e-7, 1e-6))
    jet = (rng.uniform(1e-6, 0.08), rng.normal(0, 1), rng.normal(0, 30), rng.normal(0, 1e3))
    state = np.array([rng.uniform(-1e-5, 0.1), rng.normal(0, 1e-9), rng.normal(0, 3e-6)])
    return plant, 3e-5, jet, state


def _maglev(rng):
    plant = maglev.Maglev(k=rng.uniform(0.5, 0.8), R_m=rng.uniform(0.0, 0.05))
    jet = (rng.uniform(-0.005, 0.0045), rng.normal(0, 1e-3), rng.normal(0, 1e-2), rng.normal(0, 1e-2))
    state = np.array([rng.uniform(-0.01, 0.0049), rng.normal(0, 0.01), rng.normal(0, 0.5)])
    return plant, 0.0025, jet, state


def _designs(rng, plant, q_d):
    """The four designs where the plant allows them, with random gains that satisfy their conditions."""
    R_e_bar = float(plant.R_e[0, 0]) * rng.uniform(0.5, 3.0)
    D_max = 2.0 * np.sqrt(float(plant.R_m[0, 0]) * R_e_bar)           # eq. (pHcondition), n = 1
    out = [Proposition1(plant, q_d, R_e_bar, D_d=rng.uniform(-0.9, 0.9) * D_max, W=rng.uniform(0.5, 2.0)),
           Theorem2(plant, R_e_bar, D_d=rng.normal(0, 1.0), W=rng.uniform(0.5, 2.0))]
    if getattr(plant, "Gamma", None) is not None:
        out += [Proposition2(plant, q_d, R_e_bar, k_c=rng.uniform(5, 30), D_d=rng.uniform(-0.9, 0.9) * D_max),
                Theorem3(plant, R_e_bar, k_c=rng.uniform(5, 30), D_d=rng.normal(0, 1.0))]
    return out


@pytest.mark.parametrize("make", [_mems, _maglev], ids=["MEMS", "Maglev"])
def test_generated_feasible_reference_equals_the_hand_written(make):
    rng = np.random.default_rng(32)
    for _ in range(40):
        plant, _, jet, _ = make(rng)
        for a, b in zip(plant.feasible_scalar(*jet), feasible_scalar(plant, *jet)):
            assert close(a, b), (plant.name, jet)
        v = rng.normal(size=4) * np.abs(jet)                          # complex step: x_e*, x_e*' along v
        z = [complex(x, 1e-30 * d) for x, d in zip(jet, v)]
        for a, b in zip(plant.feasible_scalar(*z), feasible_scalar(plant, *z)):
            assert close(a.imag, b.imag, 1e-11), (plant.name, jet)


@pytest.mark.parametrize("make", [_mems, _maglev], ids=["MEMS", "Maglev"])
def test_generated_laws_equal_the_hand_written(make):
    rng = np.random.default_rng(32)
    for _ in range(20):
        plant, q_d, jet, eta = make(rng)
        for controller in _designs(rng, plant, q_d):
            assert controller.scalars is not None                      # the generated law, not u_matrix
            ref = jet if controller.tracking else None
            u, truth = controller.u_scalar(*eta, ref), u_scalar(controller, *eta, ref)
            assert isinstance(u, float) and close(u, truth), (controller.name, u, truth)
            x = [*eta, *(jet if controller.tracking else ())]
            v = rng.normal(size=len(x)) * np.abs(x)
            h = 1e-30
            z = [complex(xi, h * vi) for xi, vi in zip(x, v)]
            slope = u_scalar(controller, *z[:3], tuple(z[3:]) if controller.tracking else None).imag / h
            assert close(controller.u_derivative(x, list(v)), slope, 1e-11), controller.name


def test_infeasible_and_outside_references_are_refused_as_before():
    plant = maglev.Maglev()
    controller = Theorem3(plant, 2.82, k_c=10.0)
    falling = (0.0025, 0.0, -20.0, 0.0)                               # faster than free fall: no real x_e*
    for call in (lambda: plant.feasible_scalar(*falling), lambda: controller.u_scalar(0.0025, 0.0, 0.2, falling),
                 lambda: feasible_scalar(plant, *falling)):
        with pytest.raises(ValueError, match=r"infeasible reference at q\* = 0.0025: no real x_e\*"):
            call()
    outside = (0.006, 0.0, 0.0, 0.0)                                  # above the magnet
    for call in (lambda: plant.feasible_scalar(*outside), lambda: controller.u_scalar(0.0025, 0.0, 0.2, outside),
                 lambda: feasible_scalar(plant, *outside)):
        with pytest.raises(ValueError, match="violates q < c"):
            call()


@pytest.mark.parametrize("example", ["parallel_plate", "solenoid"])
def test_generated_laws_of_example_devices(example):
    """Descriptions other than the paper's: the laws printed from their generated modules."""
    desc = load(ROOT / "examples" / example / f"{example}.toml")
    device = codegen.device(desc)
    plant = device.plant()
    rng = np.random.default_rng(5)
    q0 = float(plant.equilibrium(np.array([0.3 * (plant.q_max if np.isfinite(plant.q_max) else 1e-3)]))[0])
    for controller in _designs(rng, plant, q0):
        for _ in range(5):
            eta = plant.equilibrium(np.array([q0])) * rng.uniform(0.8, 1.2, size=3) + rng.normal(0, 1e-9, size=3)
            jet = (q0, 0.0, 0.0, 0.0) if controller.tracking else None
            u, truth = controller.u_scalar(*eta, jet), u_scalar(controller, *eta, jet)
            assert close(u, truth), (example, controller.name, u, truth)


def _reference_jet(plant, rng, q_d):
    m = plant.n_m
    return Jet(np.asarray(q_d, dtype=float), rng.normal(0, 1e-4, m), rng.normal(0, 1e-3, m), rng.normal(0, 1e-2, m))


@pytest.mark.parametrize("example", ["levitated_bar", "two_magnet_ball"])
def test_generated_laws_of_any_n_equal_the_matrix_laws(example):
    """Plants with n > 1 (and their designs' default gains): the law printed from components.laws
    (Controller.vector_law) against the matrix law written with numpy (u_matrix), at random states near the
    target and random reference jets: u to 1e-12 and its complex-step derivative to 1e-11."""
    desc = load(ROOT / "examples" / example / f"{example}.toml")
    device = codegen.device(desc)
    rng = np.random.default_rng(3)
    built = {}
    for design in device.designs:
        try:
            built[design] = device.controller(design, {})
        except ValueError:                                # the defaults violate this design's conditions
            continue
    q_d = next(c.target(None) for c in built.values() if not c.tracking)[:device.n_m]
    assert len(built) >= 3, list(built)
    for design, controller in built.items():
        assert controller.scalars is None and controller.vector_law is not None, design
        n = controller.plant.n
        for _ in range(5):
            jet = _reference_jet(controller.plant, rng, q_d) if controller.tracking else None
            target = controller.target(jet)
            eta = target * rng.uniform(0.9, 1.1, n) + rng.normal(0, 1e-6, n) * np.max(np.abs(target))
            u, truth = controller.u(eta, jet), controller.u_matrix(eta, jet)
            assert np.all(np.abs(u - truth) <= RTOL * np.max(np.abs(truth))), (example, design, u, truth)
            x = [*eta, *(np.concatenate([jet.q, jet.qd, jet.qdd, jet.qddd]) if jet is not None else [])]
            v = rng.normal(size=len(x)) * np.abs(x)
            h = 1e-30
            z = np.array([complex(xi, h * vi) for xi, vi in zip(x, v)])
            zjet = Jet(*np.reshape(z[n:], (4, -1))) if jet is not None else None
            slope = np.imag(controller.u_matrix(z[:n], zjet)) / h
            d = controller.u_derivative(x, list(v))
            assert np.all(np.abs(d - slope) <= 1e-11 * np.max(np.abs(slope))), (example, design, d, slope)
