"""components.plant_step with an input polynomial of any degree (issue 26, item 9: a master may send input
derivatives of any order, and the plant FMUs integrate the whole polynomial): the polynomial's values
(`input_value`), RODAS4's order with a quartic input through the stage inputs, and clear errors for a
polynomial that cannot be evaluated. tests/test_fmu_derivatives.py checks the plant FMUs against Radau."""
from __future__ import annotations

import math

import numpy as np
import pytest

from components.maglev import Maglev
from components.mems import MEMS
from components.plant_step import (
    _STAGE_POINTS,
    PlantStepper,
    _ArrayModel,
    _rodas4_structured,
    input_terms,
    input_value,
    simulate_polynomial,
)

QUARTIC = (0.5, 40.0, -3000.0, 2e5, -1e7)          # (u, u', u'', u''', u'''') of the maglev's input


def test_input_value_is_the_taylor_polynomial_and_its_derivatives():
    terms = input_terms(*QUARTIC[:3], {3: QUARTIC[3], 4: QUARTIC[4]})
    for tau in (0.0, 1e-3, 0.02):
        value = sum(c * tau**k / math.factorial(k) for k, c in enumerate(QUARTIC))
        rate = sum(c * tau**(k - 1) / math.factorial(k - 1) for k, c in enumerate(QUARTIC) if k)
        assert input_value(terms, tau) == pytest.approx(value, rel=1e-15)
        assert input_value(terms, tau, 1) == pytest.approx(rate, rel=1e-15)
    far = ((0, 1.0), (2**31 - 1, 1e300))           # tau^k / k! underflows, k! is never formed
    assert input_value(far, 0.5) == 1.0 and input_value(far, 0.0) == 1.0


def test_polynomials_that_cannot_be_integrated_are_refused_by_name():
    stepper = PlantStepper(MEMS())
    eta = (15e-6, 0.0, 0.0)
    with pytest.raises(ValueError, match=r"d\^3u/dt\^3 = nan is not finite"):
        stepper.advance(*eta, 25.0, 1e-6, 0.0, 0.0, {3: math.nan})
    with pytest.raises(ValueError, match="order 0 is not an integer >= 3"):
        stepper.advance(*eta, 25.0, 1e-6, 0.0, 0.0, {0: 1.0})
    with pytest.raises(ValueError, match="overflows over the step"):
        stepper.advance(*eta, 25.0, 1e110, 0.0, 0.0, {3: 1.0})
    assert stepper.h_next == 0.0                     # unchanged: no step was taken


def test_orders_above_two_that_are_zero_take_the_quadratic_path():
    """A master that sends orders >= 3 of value 0 gets the quadratic's step bit for bit."""
    a, b = PlantStepper(MEMS()), PlantStepper(MEMS())
    eta = (15e-6, 0.0, 0.0)
    assert a.advance(*eta, 25.0, 1e-6, 2e5, -3e10, {3: 0.0, 9: 0.0}) == b.advance(*eta, 25.0, 1e-6, 2e5, -3e10)


@pytest.mark.parametrize("dense", [False, True], ids=["written-out stages", "coefficient loop"])
def test_fourth_order_with_a_quartic_input(dense):
    """One RODAS4 step of the maglev (no electrical layer) with the quartic given by its values at the
    stage times: the local error shrinks like h^5 (ratio ~2^5 for h, h/2), both implementations."""
    plant = Maglev()
    stepper = PlantStepper(plant)
    sq, sp, sx = stepper.scale
    eta = plant.equilibrium([0.0025]) + np.array([0.0, 0.002, 0.01])
    terms = tuple(enumerate(QUARTIC))
    errors = []
    for h in (0.01, 0.005):
        rodas4 = stepper._rodas4_dense if dense else _rodas4_structured
        stages = tuple(input_value(terms, a * h) for a in _STAGE_POINTS)
        y, _ = rodas4(_ArrayModel(plant) if dense else stepper.model, tuple(eta / stepper.scale), QUARTIC[0],
                      QUARTIC[1], 0.0, h, 1 / sq, 1 / sp, 1 / sx, sq, sp, sx, stages)
        ref = simulate_polynomial(plant, eta, h, [QUARTIC], rtol=1e-13)[-1]
        errors.append(np.max(np.abs(np.array(y) - ref / stepper.scale)))
    assert 2 ** 4.5 < errors[0] / errors[1] < 2 ** 5.5, errors


@pytest.mark.parametrize("plant, eta, h", [(Maglev(), (0.0025, 0.002, 0.9), 1e-3), (MEMS(), (15e-6, 0.0, 0.0), 1e-6)],
                         ids=["maglev", "MEMS (electrical layer)"])
def test_steps_with_a_quartic_input_match_radau(plant, eta, h):
    """Ten communication steps with a quartic input re-expanded at each point, at rtol 1e-9, against Radau
    (1e-12); the MEMS steps go through the electrical layer, whose slow manifold takes the orders >= 3."""
    coefficients = QUARTIC if isinstance(plant, Maglev) else (25.0, 2e5, -3e10, 1e17, 1e23)
    terms = tuple(enumerate(coefficients))
    rows = [tuple(input_value(terms, k * h, j) for j in range(5)) for k in range(10)]
    stepper = PlantStepper(plant, rtol=1e-9)
    state = eta
    for u, du, d2u, d3u, d4u in rows:
        state = stepper.advance(*state, u, h, du, d2u, {3: d3u, 4: d4u})
    ref = simulate_polynomial(plant, eta, h, rows, rtol=1e-12)[-1]
    assert np.all(np.abs(np.array(state) - ref) <= 1e-8 * (np.array(stepper.scale) + np.abs(ref)))


def test_the_electrical_layer_starts_on_the_slow_manifold_of_any_polynomial():
    """For n_e = 1 and a frozen alpha (p = 0: alpha' = 0) the slow manifold of x_e' = -alpha x_e + G_e u(t)
    with a polynomial u is x_s = (G_e/alpha) sum_k (-1/alpha)^k u^(k) (docs/derivations.md, section 9):
    the x_s(0) the layer returns has every order (orders >= 3 enter through the u'' slot), to rounding.
    The orders are scaled by alpha^k so that each term counts."""
    stepper = PlantStepper(MEMS())
    q, p = 15e-6, 0.0
    model = stepper.model
    alpha = -model.F_xx * model.psi(q)[0]
    c = [25.0, 3.0 * alpha, -2.0 * alpha**2, 4.0 * alpha**3, -1.5 * alpha**4]
    series = model.g_x / alpha * sum(ck * (-1.0 / alpha) ** k for k, ck in enumerate(c))
    quadratic = model.g_x / alpha * sum(ck * (-1.0 / alpha) ** k for k, ck in enumerate(c[:3]))
    assert abs(quadratic - series) > 0.1 * abs(series)             # the orders 3 and 4 change it
    _, _, x_s, _, applied = stepper.layer(q, p, series, c[0], 1e-6, c[1], c[2], ((3, c[3]), (4, c[4])))
    assert applied and x_s == pytest.approx(series, rel=1e-12)
