"""components.plant_step.GeneralStepper (any n_m, n_e): one communication step of eq. (open-loop elecmech)
against scipy's Radau at tight tolerance, for the two-axis test plant (n_m = n_e = 2) with held and
polynomial inputs; its error control, h_next, domain checks and failures."""
from __future__ import annotations

import numpy as np
import pytest
from scipy.integrate import solve_ivp

from components.maglev import Maglev
from components.ph_plant import DomainError
from components.plant_step import (
    GeneralStepper,
    PlantStepper,
    StepFailure,
    make_stepper,
    nominal_scale,
    vector_input,
    vector_terms,
)
from tests.plants_for_tests import TwoAxisLevitator

ETA0 = np.array([0.1, -0.2, 0.3, 0.1, 1.0, 0.8])


def radau(plant, eta0, h, rows):
    """The states after each step k of size h with the input polynomial rows[k] = (u, {order: rates}),
    scipy's Radau with the exact Jacobian at rtol = atol = 1e-13 (an independent integrator)."""
    eta, out = np.array(eta0, dtype=float), []
    for u, derivatives in rows:
        terms = vector_terms(u, derivatives, plant.n_e)
        sol = solve_ivp(lambda t, x: plant.f(x, vector_input(terms, t)), (0.0, h), eta, method="Radau",
                        rtol=1e-13, atol=1e-13, jac=lambda t, x: plant.jacobian(x))
        assert sol.success
        eta = sol.y[:, -1]
        out.append(eta)
    return np.array(out)


HELD = [(np.array([0.5, -0.3]), {})] * 6
POLYNOMIAL = [(np.array([0.5, -0.3]), {1: [2.0, 1.0], 2: [-3.0, 0.5]}),
              (np.array([0.6, -0.2]), {1: [1.0, -1.0], 3: [10.0, 0.0]}),
              (np.array([0.4, 0.1]), {2: [0.0, 4.0], 5: [100.0, -50.0]})] * 2


@pytest.mark.parametrize("rows", [HELD, POLYNOMIAL], ids=["held", "polynomial"])
@pytest.mark.parametrize("variable_mass", [False, True], ids=["M", "M(q)"])
def test_general_stepper_agrees_with_radau(rows, variable_mass):
    plant = TwoAxisLevitator(variable_mass=variable_mass, damped=True)
    rtol = 1e-10
    stepper = GeneralStepper(plant, rtol=rtol)
    eta, got = ETA0, []
    for u, derivatives in rows:
        eta = stepper.step(eta, u, 0.05, derivatives)
        got.append(eta)
        assert stepper.h_next > 0
    truth = radau(plant, ETA0, 0.05, rows)
    scale = nominal_scale(plant)
    # error control per step at rtol on the scaled states, accumulated over 6 steps (factor 20 margin)
    assert np.max(np.abs(np.array(got) - truth) / (scale + np.abs(truth))) <= 20 * rtol


def test_the_polynomial_is_used():
    """The same step with and without the derivatives differs by about u' h^2 / 2 in x_e: the input
    polynomial reaches the integration (the held test alone would not show it)."""
    plant = TwoAxisLevitator(damped=True)
    u = np.array([0.5, -0.3])
    held = GeneralStepper(plant, rtol=1e-10).step(ETA0, u, 0.05)
    ramp = GeneralStepper(plant, rtol=1e-10).step(ETA0, u, 0.05, {1: [2.0, 0.0]})
    assert abs(ramp[4] - held[4]) == pytest.approx(2.0 * 0.05 ** 2 / 2, rel=0.1)


def test_h_next_is_carried_over_and_only_a_successful_step_changes_it():
    plant = TwoAxisLevitator(damped=True)
    stepper = GeneralStepper(plant, rtol=1e-8)
    stepper.step(ETA0, [0.5, -0.3], 1.0)
    first = stepper.n_substeps
    h_next = stepper.h_next
    assert 0 < h_next < 1.0 and first > 1
    with pytest.raises(ValueError, match="not finite"):
        stepper.step(ETA0, [np.nan, 0.0], 1.0)
    assert stepper.h_next == h_next
    stepper.step(ETA0, [0.5, -0.3], 1.0)
    assert stepper.n_substeps <= first                          # starts from the proposed substep


def test_failures_are_named():
    plant = TwoAxisLevitator(damped=True)
    stepper = GeneralStepper(plant, rtol=1e-8)
    with pytest.raises(ValueError, match="expected n_e = 2"):
        stepper.step(ETA0, [0.5], 0.01)
    with pytest.raises(ValueError, match="expected 6"):
        stepper.step(ETA0[:5], [0.5, 0.0], 0.01)
    with pytest.raises(ValueError, match="must be finite and > 0"):
        stepper.step(ETA0, [0.5, 0.0], 0.0)
    with pytest.raises(DomainError, match="positive definite"):
        stepper.step(np.array([6.0, 0.0, 0, 0, 0, 0]), [0.5, 0.0], 0.01)   # Psi_11 = 5 - 6 < 0
    with pytest.raises(ValueError, match="violates"):
        GeneralStepper(plant, rtol=1.0)
    few = GeneralStepper(plant, rtol=1e-12, max_substeps=3)
    with pytest.raises(StepFailure, match="more than 3 substeps"):
        few.step(ETA0, [0.5, -0.3], 1.0)


def test_leaving_the_domain_is_a_domain_error():
    """A large voltage drives the fluxes up and q into Psi <= 0: the step stops there with DomainError."""
    plant = TwoAxisLevitator(damped=True)
    with pytest.raises(DomainError):
        GeneralStepper(plant, rtol=1e-6).step(ETA0, [400.0, 400.0], 20.0)


def test_make_stepper_keeps_the_one_dof_path():
    assert type(make_stepper(Maglev())) is PlantStepper
    assert type(make_stepper(TwoAxisLevitator())) is GeneralStepper


def test_nominal_scale_per_axis():
    """n > 1: L_i is the distance along +-e_i to the domain's boundary (Psi_11 = 5 - q_1 at q_1 = 5,
    Psi_22 = 4 - 0.2 q_1 - 0.8 q_2 at q_2 = 5), momenta m_i L_i / T_i, all finite and > 0."""
    s = nominal_scale(TwoAxisLevitator())
    assert s[:2] == pytest.approx([5.0, 5.0], rel=2e-3)
    assert np.all(np.isfinite(s)) and np.all(s > 0) and s.shape == (6,)
