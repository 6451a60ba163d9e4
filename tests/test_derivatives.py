"""Exact time derivatives and Jacobians that the FMUs' derivative functions answer with, against
independent truths: complex-step and finite differences of components/, and differences of trajectories
integrated by scipy's Radau.

- plants: (q, p, x_e)' and '' and H', H'' from eq. (open-loop elecmech) (`EMPlant.time_derivatives` and its
  scalar fast path `PlantStepper.time_derivatives`);
- references: q*^(k) of any order (`Reference.derivatives`);
- controllers: the derivative of u along any direction of its inputs (`Controller.u_derivative`).
"""
from __future__ import annotations

import math

import numpy as np
import pytest

from components import catalog
from components.maglev import Maglev
from components.mems import MEMS
from components.ph_plant import Jet
from components.plant_step import PlantStepper, mechanical_time, nominal_scale, simulate_polynomial
from components.references import Constant, Sinusoid, SmoothStep
from tests.helpers import CASES, random_state_near, richardson_derivative
from tests.plants_for_tests import TwoAxisLevitator

# ---- plants --------------------------------------------------------------------------------------

PLANTS = {"MEMS": MEMS, "Maglev": Maglev}


def _plant_cases(name, n=10):
    """(eta, u, u_dot) samples: random states around the plant's nominal scale."""
    plant = PLANTS[name]()
    rng = np.random.default_rng(11)
    s = nominal_scale(plant)
    for _ in range(n):
        eta = rng.uniform(-1, 1, 3) * s
        eta[0] = rng.uniform(0.1, 2.0) * s[0] if name == "MEMS" else rng.uniform(-0.5, 0.9) * s[0]
        u = rng.uniform(5.0, 40.0) if name == "MEMS" else rng.uniform(-1.0, 3.0)
        yield plant, eta, u, u * rng.normal() * 1e4


@pytest.mark.parametrize("name", list(PLANTS))
def test_scalar_time_derivatives_are_the_plants(name):
    for plant, eta, u, u_dot in _plant_cases(name):
        fast = PlantStepper(plant).time_derivatives(*eta, u, u_dot)
        d1, d2, H1, H2 = plant.time_derivatives(eta, u, u_dot)
        assert np.allclose(fast[0], d1, rtol=1e-12, atol=0) and np.allclose(fast[1], d2, rtol=1e-12, atol=0)
        assert fast[2] == pytest.approx(H1, rel=1e-12) and fast[3] == pytest.approx(H2, rel=1e-12)


def _complex_step_cases():
    for name in PLANTS:
        yield from ((name,) + c for c in _plant_cases(name, 5))
    plant = TwoAxisLevitator(variable_mass=True, damped=True)         # q-dependent mass, n_m = n_e = 2
    rng = np.random.default_rng(12)
    for _ in range(5):
        yield "two-axis", plant, rng.uniform(-0.3, 0.3, 6), rng.normal(size=2), rng.normal(size=2)


@pytest.mark.parametrize("case", list(_complex_step_cases()), ids=lambda c: c[0])
def test_time_derivatives_are_the_complex_step_along_the_motion(case):
    """eta'' = d/de f(eta + e eta', u + e u') and H' = d/de H(eta + e eta') (complex step, exact to rounding);
    H' is also the power balance -grad_p H^T R_m grad_p H - grad_xe H^T R_e grad_xe H + y^T u, y = G_e^T
    grad_xe H; H'' = d2/de2 H(eta + e eta' + e^2/2 eta'') (Richardson differences)."""
    _, plant, eta, u, u_dot = case
    u, u_dot = np.atleast_1d(u), np.atleast_1d(u_dot)
    d1, d2, H1, H2 = plant.time_derivatives(eta, u, u_dot)
    assert np.array_equal(d1, plant.f(eta, u))
    e = 1e-30
    cs = np.imag(plant.f(eta + 1j * e * d1, u + 1j * e * u_dot)) / e
    size = np.abs(plant.F()) @ np.abs(plant.hess_H(eta) @ d1) + np.abs(plant.g() @ u_dot)
    assert np.all(np.abs(d2 - cs) <= 1e-12 * size), (d2, cs)
    assert H1 == pytest.approx(np.imag(plant.H(eta + 1j * e * d1)) / e, rel=1e-12)
    m = plant.n_m
    gH = plant.grad_H(eta)
    balance = -gH[m:2 * m] @ plant.R_m @ gH[m:2 * m] - gH[2 * m:] @ plant.R_e @ gH[2 * m:] + (plant.G_e.T @ gH[2 * m:]) @ u
    assert H1 == pytest.approx(balance, rel=1e-10, abs=1e-12 * np.abs(gH) @ np.abs(d1))
    curve = lambda t: np.atleast_1d(plant.H(eta + t * d1 + 0.5 * t * t * d2))       # noqa: E731
    second = richardson_derivative(lambda t: richardson_derivative(curve, t, np.ones(1), 1e-3 * _time(plant, eta, d1)),
                                   np.zeros(1), np.ones(1), 1e-2 * _time(plant, eta, d1))
    assert H2 == pytest.approx(second[0], rel=1e-6)


def _time(plant, eta, d1):
    """A time over which eta changes little: min_i |eta_i| / |eta_i'| over the states that move."""
    moving = np.abs(d1) > 0
    return float(np.min((np.abs(eta[moving]) + 1e-3 * np.max(np.abs(eta))) / np.abs(d1[moving])))


@pytest.mark.parametrize("name", list(PLANTS))
def test_time_derivatives_are_those_of_the_trajectory(name):
    """eta' and eta'' at t equal one-sided differences (fourth / third order) of the trajectory that
    scipy's Radau integrates from eta with the polynomial input u + u' t + u'' t^2 / 2. The MEMS starts
    on its electrical slow manifold (x_e' = 0), so its trajectory is smooth over the differences' span."""
    plant = PLANTS[name]()
    if name == "MEMS":
        ref = Sinusoid()
        eta = plant.feasible_state(ref.jet(0.01))[0]
        u = -plant.F()[2, 2] * plant.psi(eta[0]) * eta[2] / plant.G_e[0, 0]
        poly, dt = (u, 1e3, -1e7), 2e-9
    else:
        eta = plant.equilibrium([0.0025]) + np.array([5e-4, 0.003, 0.01])
        poly, dt = (0.7, 0.4, -2.0), 2e-3
    samples = [eta]
    for k in range(4):
        t = k * dt
        row = (poly[0] + t * (poly[1] + 0.5 * t * poly[2]), poly[1] + t * poly[2], poly[2])
        samples.append(simulate_polynomial(plant, samples[-1], dt, [row], rtol=1e-13)[-1])
    y = np.array(samples)
    first = (-25 * y[0] + 48 * y[1] - 36 * y[2] + 16 * y[3] - 3 * y[4]) / (12 * dt)
    second = (35 * y[0] - 104 * y[1] + 114 * y[2] - 56 * y[3] + 11 * y[4]) / (12 * dt * dt)
    d1, d2, _, _ = plant.time_derivatives(eta, poly[0], poly[1])
    T = mechanical_time(plant)
    rate = np.abs(d1) + (np.abs(eta) + nominal_scale(plant)) / T          # what moves over a mechanical time
    assert np.all(np.abs(d1 - first) <= 1e-6 * rate), (d1, first)
    assert np.all(np.abs(d2 - second) <= 1e-3 * (np.abs(d2) + rate / T)), (d2, second)


# ---- references ----------------------------------------------------------------------------------

# reference, times, its time scale
REFERENCES = {"constant": (Constant(), (0.0, 0.3), 1.0),
              "sinusoid": (Sinusoid(phase=0.4), (0.0, 0.013, 0.2, 7.0), 1 / 30.0),
              "smooth step": (SmoothStep(t_start=1e-4), (1.5e-4, 3e-4, 6e-4, 1.05e-3), 1e-3)}


@pytest.mark.parametrize("name", list(REFERENCES))
def test_reference_derivatives_continue_the_jet(name):
    """Orders 0-3 are the jet of `values`; order k + 1 is the derivative of order k (Richardson central
    differences in t, 1e-8 relative) up to order 7."""
    ref, times, T = REFERENCES[name]
    for t in times:
        d = ref.derivatives(t, 7)
        assert len(d) == 8
        assert np.allclose(d[:4], ref.values(t), rtol=1e-14, atol=0)
        for k in range(7):
            fd = richardson_derivative(lambda tt: np.atleast_1d(ref.derivatives(float(tt[0]), k)[k]), np.array([t]),
                                       np.ones(1), T, decades=(-2, -8))[0]
            # relative, or against the size of the order-k derivative over the time scale where it crosses 0
            assert d[k + 1] == pytest.approx(fd, rel=1e-8, abs=1e-8 * abs(d[k]) / T), (t, k)


def test_smooth_step_high_derivatives_are_taken_from_the_right():
    """q*'''' jumps at the start of the transition (s''''(0) = 840) and at its end (s''''(1) = -840):
    at those instants the value of the step that starts there is returned; orders 0-3 are continuous."""
    ref = SmoothStep(q_from=1e-5, q_to=3e-5, t_start=1e-4, duration=1e-3)
    d, T = 2e-5, 1e-3
    assert ref.derivatives(1e-4, 4)[4] == pytest.approx(840 * d / T ** 4, rel=1e-12)
    assert ref.derivatives(1e-4 - 1e-12, 4)[4] == 0.0
    assert ref.derivatives(1.1e-3, 5) == (3e-5, 0.0, 0.0, 0.0, 0.0, 0.0)
    assert ref.derivatives(1.1e-3 - 1e-12, 4)[4] == pytest.approx(-840 * d / T ** 4, rel=1e-6)


@pytest.mark.parametrize("order", [-1, 1.5, True, "2"])
def test_bad_derivative_order_is_refused(order):
    with pytest.raises(ValueError, match="order"):
        Sinusoid().derivatives(0.0, order)


# ---- controllers ---------------------------------------------------------------------------------

def _inputs(ctrl, eta, jet):
    return np.array(list(eta) + ([] if jet is None else list(np.concatenate([jet.q, jet.qd, jet.qdd, jet.qddd]))))


def _u(ctrl, x):
    n, m = ctrl.plant.n, ctrl.plant.n_m
    jet = Jet(*np.reshape(np.array(x[n:]), (4, m))) if ctrl.tracking else None
    return np.atleast_1d(ctrl.u(np.array(x[:n]), jet))


@pytest.mark.parametrize("name", list(CASES))
def test_controller_jacobian_is_the_finite_difference_of_u(name):
    """Every column of du/d(inputs) (q, p, x_e and, tracking, the jet) and the derivative along random
    directions equal Richardson central differences of the real u to 1e-8 relative, at random states near
    the target (MEMS: q ~ 1e-5..1e-1 m, x_e ~ 1e-11..1e-6 C: the inputs span 17 orders of magnitude)."""
    ctrl, ref, horizon = CASES[name]
    rng = np.random.default_rng(13)
    for _ in range(4):
        jet = None if ref is None else ref.jet(rng.uniform(0, horizon))
        x = _inputs(ctrl, random_state_near(ctrl.target(jet), rng, ctrl.plant), jet)
        scale = np.where(x != 0, np.abs(x), 1.0)
        directions = list(np.eye(x.size)) + [rng.normal(size=x.size) for _ in range(2)]
        for v in directions:
            exact = np.atleast_1d(ctrl.u_derivative(x, v * scale))
            fd = richardson_derivative(lambda z: _u(ctrl, z), x, v * scale, 1.0)
            assert np.all(np.abs(exact - fd) <= 1e-8 * np.max(np.abs(exact))), (v, exact, fd)


def test_controller_derivative_along_zero_is_zero_and_bad_input_is_refused():
    ctrl = catalog.controller("Maglev_Theorem3")
    x = [0.0025, 0.0, 0.2, 0.0025, 0.0, 0.0, 0.0]
    assert ctrl.u_derivative(x, [0.0] * 7) == 0.0
    with pytest.raises(ValueError, match="not finite"):
        ctrl.u_derivative(x, [math.nan] + [0.0] * 6)
    with pytest.raises(ValueError, match="7 inputs but 3 directions"):
        ctrl.u_derivative(x, [1.0, 0.0, 0.0])


def test_du_dt_is_the_derivative_of_u_along_the_closed_loop():
    """du/dt = u_derivative(inputs, d inputs/dt) with the plant's eta' = f(eta, u) and the reference's jet
    derivatives equals the time derivative of u(eta(t), jet(t)) along the monolithic closed loop (MEMS
    tracking, Theorem 2 with D_d = -0.4): Richardson differences of u on Radau's trajectory."""
    from scipy.integrate import solve_ivp

    from components.monolithic import ClosedLoop

    ctrl = catalog.controller("MEMS_Theorem2", {"D_d": -0.4})
    plant, ref = ctrl.plant, Sinusoid()
    loop = ClosedLoop(ctrl, ref)
    t0 = 0.01
    eta0 = plant.feasible_state(ref.jet(t0))[0] * np.array([1.0001, 1.001, 1.0])
    s = np.abs(eta0)
    sol = solve_ivp(lambda t, xi: loop.rhs(t, xi * s) / s, (t0, t0 + 2e-6), eta0 / s, method="Radau", rtol=1e-13,
                    atol=1e-13, dense_output=True, jac=lambda t, xi: loop.jacobian(t, xi * s) * s[None, :] / s[:, None])
    t1 = t0 + 1e-6
    eta1 = sol.sol(t1) * s
    u_of_t = lambda t: np.atleast_1d(loop.u(sol.sol(t[0]) * s, t[0]))                   # noqa: E731
    fd = richardson_derivative(u_of_t, np.array([t1]), np.ones(1), 1e-7)[0]
    u1 = loop.u(eta1, t1)[0]
    x = list(eta1) + list(ref.values(t1))
    rates = list(plant.f(eta1, u1)) + list(ref.derivatives(t1, 4)[1:])
    assert ctrl.u_derivative(x, rates) == pytest.approx(fd, rel=1e-6)
