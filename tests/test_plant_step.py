"""components.plant_step: the plant over one communication step with a held input."""
from __future__ import annotations

import math

import numpy as np
import pytest

from components.maglev import Maglev
from components.mems import MEMS
from components.ph_plant import DomainError
from components.plant_step import (LAYER_DECAY, PlantStepper, _ArrayModel, _ScalarModel, _rodas4_structured,
                                   _solve_structured, nominal_scale, simulate_zoh)

PLANTS = {"MEMS": MEMS, "Maglev": Maglev}


def _states(name, n=20):
    rng = np.random.default_rng(1)
    s = nominal_scale(PLANTS[name]())
    eta = rng.uniform(-1, 1, (n, 3)) * s
    eta[:, 0] = rng.uniform(0.1, 2.0, n) * s[0] if name == "MEMS" else rng.uniform(-0.5, 0.9, n) * s[0]
    return eta


@pytest.mark.parametrize("name", list(PLANTS))
def test_scalar_model_is_the_plants_f_and_jacobian(name):
    plant = PLANTS[name]()
    model = _ScalarModel(plant)
    for eta in _states(name):
        u = 3.0
        f, (J_qp, J_pq, J_pp, J_px, J_xq, J_xx) = model.f_jac(*eta, u)
        assert np.allclose(f, plant.f(eta, np.array([u])), rtol=1e-13, atol=0)
        assert model.f(*eta, u) == f
        J = np.array([[0, J_qp, 0], [J_pq, J_pp, J_px], [J_xq, 0, J_xx]])
        assert np.allclose(J, plant.jacobian(eta), rtol=1e-13, atol=0)


def test_structured_solve_is_the_linear_solve():
    rng = np.random.default_rng(2)
    for _ in range(20):
        g, a, b, c, d, e, k = rng.normal(size=7) * [1, 10, 10, 1, 10, 10, 100]
        g = abs(g) + 5.0
        G = g * np.eye(3) - np.array([[0, a, 0], [b, c, d], [e, 0, k]])
        if abs(np.linalg.det(G)) < 1e-6:
            continue
        lu = (g, a, b, c, d, e, g - k, 1.0 / ((g - c) - a * b / g - a * d * e / (g * (g - k))))
        r = rng.normal(size=3)
        assert np.allclose(_solve_structured(lu, tuple(r)), np.linalg.solve(G, r), rtol=1e-10, atol=1e-12)


@pytest.mark.parametrize("dense", [False, True], ids=["written-out stages", "coefficient loop"])
def test_fourth_order_on_a_smooth_step(dense):
    """One RODAS4 step of the maglev (no electrical layer): the error ratio for h and h/2 is ~2^5,
    for both implementations of the step."""
    plant = Maglev()
    stepper = PlantStepper(plant)
    sq, sp, sx = stepper.scale
    eta = plant.equilibrium([0.0025]) + np.array([0.0, 0.002, 0.01])
    errors = []
    for h in (0.01, 0.005):
        rodas4 = stepper._rodas4_dense if dense else _rodas4_structured
        y, _ = rodas4(_ArrayModel(plant) if dense else stepper.model, (eta[0] / sq, eta[1] / sp, eta[2] / sx), 0.5, h,
                      1 / sq, 1 / sp, 1 / sx, sq, sp, sx)
        ref = simulate_zoh(plant, eta, h, [0.5], rtol=1e-13)[-1]
        errors.append(np.max(np.abs(np.array(y) - ref / stepper.scale)))
    assert 2 ** 4.5 < errors[0] / errors[1] < 2 ** 5.5


def test_electrical_layer_is_applied_only_when_fast_and_complete():
    mems = PlantStepper(MEMS())
    eta = np.array([2e-5, 1e-10, 0.0])
    mems.step(eta, 25.0, 1e-6)
    assert mems.layer_applied and mems.n_substeps == 1
    alpha = (1 / 100.0) / (35.6e-9 * (2e-5 + 15e-6))
    mems.step(eta, 25.0, 0.5 * LAYER_DECAY / alpha)          # the layer would not end inside the step
    assert not mems.layer_applied
    maglev = PlantStepper(Maglev())
    maglev.step(Maglev().equilibrium([0.0025]), 0.0, 1e-3)
    assert not maglev.layer_applied                           # L/R = 114 s: nothing fast


def test_layer_step_matches_reference_after_a_large_jump():
    plant = MEMS()
    stepper = PlantStepper(plant)
    eta = np.array([2e-5, 1e-10, 0.0])                        # no charge, 40 V applied
    y = stepper.step(eta, 40.0, 1e-6)
    ref = simulate_zoh(plant, eta, 1e-6, [40.0], rtol=1e-12)[-1]
    assert np.max(np.abs(y - ref) / nominal_scale(plant)) < 1e-8


def test_proposed_substep_is_state():
    """Steps with different h_next give different (both accurate) results: an FMU must save it."""
    plant = MEMS()
    eta = np.array([2e-5, 1e-10, 3e-11])
    a, b = PlantStepper(plant), PlantStepper(plant)
    b.h_next = 1e-7
    ya, yb = a.step(eta, 25.0, 1e-5), b.step(eta, 25.0, 1e-5)
    assert not np.array_equal(ya, yb)
    assert np.allclose(ya, yb, rtol=1e-6, atol=0)


def test_bad_input_raises_with_reason():
    stepper = PlantStepper(MEMS())
    eta = np.array([2e-5, 0.0, 0.0])
    for bad in (math.nan, math.inf):
        with pytest.raises(ValueError, match="input u"):
            stepper.step(eta, bad, 1e-6)
    for h in (0.0, -1e-6, math.nan):
        with pytest.raises(ValueError, match="step size"):
            stepper.step(eta, 25.0, h)
    with pytest.raises(DomainError, match="q \\+ c0 > 0"):
        stepper.step(np.array([-2e-5, 0.0, 0.0]), 25.0, 1e-6)
    with pytest.raises(ValueError, match="rtol"):
        PlantStepper(MEMS(), rtol=0.1)
    h_next = stepper.h_next
    with pytest.raises(DomainError, match="gap has closed"):
        state = np.array([1e-6, -5e-9, 0.0])                  # moving fast towards the closed gap
        for _ in range(20):
            state = stepper.step(state, 0.0, 1e-6)
    assert stepper.h_next != 0 or h_next == 0


def test_maglev_reaching_the_magnet():
    plant = Maglev()
    stepper = PlantStepper(plant)
    eta = plant.equilibrium([0.0025])
    with pytest.raises(DomainError, match="reached the magnet"):
        for _ in range(100):
            eta = stepper.step(eta, 2.0, 1e-2)


def test_dense_path_for_plants_without_constant_mass():
    """The EMPlant.f / EMPlant.jacobian path (used when M depends on q) gives the same steps."""
    from components.plant_step import _ArrayModel

    plant = MEMS()
    fast, dense = PlantStepper(plant), PlantStepper(plant)
    dense.model, dense.dense = _ArrayModel(plant), True
    eta = np.array([2e-5, 1e-10, 3e-11])
    for u, h in [(25.0, 1e-6), (10.0, 1e-5), (30.0, 1e-8)]:
        assert np.allclose(fast.step(eta, u, h), dense.step(eta, u, h), rtol=1e-9, atol=0)
