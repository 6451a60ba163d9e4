"""components.plant_step: the plant over one communication step with a held or polynomial input."""
from __future__ import annotations

import math

import numpy as np
import pytest

import components.plant_step as plant_step
from components import catalog
from components.maglev import Maglev
from components.mems import MEMS
from components.ph_plant import DomainError
from components.plant_step import (
    _A,
    _C,
    _GAMMA,
    _STAGE_GAMMA,
    _STAGE_TIME,
    LAYER_MIN_DECAY,
    PlantStepper,
    _ArrayModel,
    _rodas4_structured,
    _ScalarModel,
    _solve_structured,
    nominal_scale,
    simulate_polynomial,
    simulate_zoh,
)

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
        y, _ = rodas4(_ArrayModel(plant) if dense else stepper.model, (eta[0] / sq, eta[1] / sp, eta[2] / sx), 0.5, 0.0, 0.0, h,
                      1 / sq, 1 / sp, 1 / sx, sq, sp, sx)
        ref = simulate_zoh(plant, eta, h, [0.5], rtol=1e-13)[-1]
        errors.append(np.max(np.abs(np.array(y) - ref / stepper.scale)))
    assert 2 ** 4.5 < errors[0] / errors[1] < 2 ** 5.5


def test_electrical_layer_is_applied_only_when_fast():
    mems = PlantStepper(MEMS())
    eta = np.array([2e-5, 1e-10, 0.0])
    mems.step(eta, 25.0, 1e-6)
    assert mems.layer_applied and mems.n_substeps == 1
    alpha = (1 / 100.0) / (35.6e-9 * (2e-5 + 15e-6))
    mems.step(eta, 25.0, 0.5 * LAYER_MIN_DECAY / alpha)      # the layer hardly decays inside the step
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


# ---- polynomial input over the step ---------------------------------------------------------------

def test_stage_times_and_gammas_follow_from_the_coefficient_table():
    """RODAS4's stage times alpha_i and f_t coefficients gamma_i (rodas.f C2..C4, D1..D4) are the row sums
    of alpha = a Gamma and Gamma = (I/gamma - c)^-1 of the transformed coefficients a, c the step uses."""
    a, c = np.zeros((6, 6)), np.zeros((6, 6))
    for i in range(6):
        a[i, :i], c[i, :i] = _A[i], _C[i]
    Gamma = np.linalg.inv(np.eye(6) / _GAMMA - c)
    assert np.allclose((a @ Gamma).sum(axis=1), _STAGE_TIME, rtol=0, atol=1e-13)
    assert np.allclose(Gamma.sum(axis=1), _STAGE_GAMMA, rtol=0, atol=1e-13)


def _one_step_errors(dense: bool, hs, u=(0.5, 40.0, -3000.0)):
    """Errors of one RODAS4 step of the maglev (no electrical layer) with input u0 + u1 t + u2 t^2/2."""
    plant = Maglev()
    stepper = PlantStepper(plant)
    sq, sp, sx = stepper.scale
    eta = plant.equilibrium([0.0025]) + np.array([0.0, 0.002, 0.01])
    errors = []
    for h in hs:
        rodas4 = stepper._rodas4_dense if dense else _rodas4_structured
        y, _ = rodas4(_ArrayModel(plant) if dense else stepper.model, tuple(eta / stepper.scale), *u, h,
                      1 / sq, 1 / sp, 1 / sx, sq, sp, sx)
        ref = simulate_polynomial(plant, eta, h, [u], rtol=1e-13)[-1]
        errors.append(np.max(np.abs(np.array(y) - ref / stepper.scale)))
    return errors


@pytest.mark.parametrize("dense", [False, True], ids=["written-out stages", "coefficient loop"])
def test_fourth_order_with_a_time_varying_input(dense):
    """The local error of one step with a quadratic input shrinks like h^5 (order 4): ratio ~2^5 for h, h/2."""
    e = _one_step_errors(dense, (0.01, 0.005))
    assert 2 ** 4.5 < e[0] / e[1] < 2 ** 5.5, e


def test_without_the_f_t_term_the_order_drops(monkeypatch):
    """The test above can fail: dropping the gamma_i h f_t terms (the stage input times kept) leaves a
    local error of order h^2 (ratio ~4 for h, h/2), and a much larger one."""
    for name in ("_d1", "_d2", "_d3", "_d4"):
        monkeypatch.setattr(plant_step, name, 0.0)
    e = _one_step_errors(False, (0.01, 0.005))
    assert e[0] / e[1] < 2 ** 3, e
    monkeypatch.undo()
    assert e[1] > 100 * _one_step_errors(False, (0.005,))[0]


@pytest.mark.parametrize("name", list(PLANTS))
def test_polynomial_input_steps_match_radau(name):
    """Communication steps with polynomial inputs (orders 0, 1, 2) from random states equal scipy's Radau
    with the same input to the stepper's tolerance: |error_i| <= rtol (s_i + |eta_i|)."""
    plant = PLANTS[name]()
    rng = np.random.default_rng(5)
    stepper = PlantStepper(plant, rtol=1e-9)
    s = np.array(stepper.scale)
    h = 2e-6 if name == "MEMS" else 2e-3
    for eta in _states(name, 3):
        u0 = 20.0 if name == "MEMS" else 0.5
        u = (u0 * rng.uniform(0.5, 1.5), u0 * rng.normal() / (50 * h), u0 * rng.normal() / (50 * h) ** 2)
        for order in (1, 2, 3):
            poly = u[:order]
            y = stepper.step(eta, poly[0], h, *poly[1:])
            ref = simulate_polynomial(plant, eta, h, [poly], rtol=1e-11)[-1]
            assert np.all(np.abs(y - ref) <= stepper.rtol * (s + np.abs(ref))), (order, y, ref)


def _tracking_loop(h: float, first_order: bool, n: int):
    """n communication steps of the MEMS tracking loop (Theorem 2, D_d = -0.4) from the reference state at
    t = 10 ms, the input held or with its derivative along the loop; each step against Radau."""
    plant, ref = MEMS(), catalog.reference("sinusoid", {})
    ctrl = catalog.controller("MEMS_Theorem2", {"D_d": -0.4})
    stepper = PlantStepper(plant, rtol=1e-9)
    s = np.array(stepper.scale)
    eta = plant.feasible_state(ref.jet(0.01))[0]
    worst, substeps, layers = 0.0, [], 0
    for k in range(n):
        t = 0.01 + k * h
        x = list(eta) + list(ref.values(t))
        u = ctrl.u_scalar(*eta, ref.values(t))
        du = ctrl.u_derivative(x, list(plant.f(eta, u)) + list(ref.derivatives(t, 4)[1:])) if first_order else 0.0
        y = stepper.step(eta, u, h, du)
        reference = simulate_polynomial(plant, eta, h, [(u, du)], rtol=1e-12)[-1]
        worst = max(worst, float(np.max(np.abs(y - reference) / (stepper.rtol * (s + np.abs(reference))))))
        substeps.append(stepper.n_substeps + stepper.n_rejected)
        layers += stepper.layer_applied
        eta = y
    return worst, substeps, layers


@pytest.mark.parametrize("first_order", [False, True], ids=["held input", "first-order hold"])
def test_partial_layer_keeps_tracking_steps_accurate_in_one_substep(first_order):
    """At the tracking scenario's q ~ 0.06 m the layer lasts ~2e-7 s, a fifth of a 1 us step: each input
    jump used to cost 10-12 substeps. Taken in closed form (with what is left of it added at the end),
    every step is one substep and within the tolerance of the Radau solution."""
    worst, substeps, layers = _tracking_loop(1e-6, first_order, 8)
    assert worst <= 1.0 and layers == 8 and max(substeps) == 1, (worst, substeps, layers)


def test_layer_is_refused_when_what_it_neglects_is_too_large():
    """A large input jump with a layer that lasts a fifth of the step: its kick on p is ~1e2 of the
    tolerance and the terms it neglects (relative ~1/(alpha T)) would show, so the step resolves the layer
    with the error control instead (many substeps) and still matches Radau."""
    plant = MEMS()
    stepper = PlantStepper(plant, rtol=1e-9)
    eta = np.array([0.06, 2.8e-9, 0.0])                          # no charge, 1300 V applied
    alpha = (1 / 100.0) / (35.6e-9 * (0.06 + 15e-6))
    h = 5.0 / alpha
    y = stepper.step(eta, 1300.0, h)
    assert not stepper.layer_applied and stepper.n_substeps > 5
    ref = simulate_zoh(plant, eta, h, [1300.0], rtol=1e-12)[-1]
    assert np.all(np.abs(y - ref) <= stepper.rtol * (np.array(stepper.scale) + np.abs(ref)))


def test_non_finite_input_derivatives_are_refused_by_name():
    stepper = PlantStepper(MEMS())
    eta = np.array([2e-5, 0.0, 0.0])
    with pytest.raises(ValueError, match="du/dt = nan"):
        stepper.step(eta, 25.0, 1e-6, math.nan)
    with pytest.raises(ValueError, match="d2u/dt2 = inf"):
        stepper.step(eta, 25.0, 1e-6, 0.0, math.inf)
