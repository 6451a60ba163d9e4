"""Plant models, eq. (open-loop elecmech): derivatives against the complex step, passivity, parameters."""
import numpy as np
import pytest

from components import differentiation, maglev, mems
from components.maglev import Maglev
from components.mems import MEMS
from components.ph_plant import DomainError
from tests.plants_for_tests import TwoAxisLevitator

rng = np.random.default_rng(1)


def random_states(plant, n):
    """Admissible random states around physically relevant magnitudes."""
    if isinstance(plant, MEMS):
        q = rng.uniform(-0.9 * plant.c0, 0.1, n)
        return np.column_stack([q, rng.normal(0, 1e-9, n), rng.normal(0, 1e-6, n)])
    if isinstance(plant, Maglev):
        q = rng.uniform(-0.01, 0.99 * plant.c, n)
        return np.column_stack([q, rng.normal(0, 0.01, n), rng.uniform(0.1, 2.0, n)])
    return np.column_stack([rng.uniform(-0.5, 0.5, (n, 2)), rng.normal(0, 1, (n, 2)), rng.uniform(0.2, 2, (n, 2))])


PLANTS = [MEMS(), Maglev(), TwoAxisLevitator(), TwoAxisLevitator(variable_mass=True)]


@pytest.mark.parametrize("plant", PLANTS, ids=lambda p: f"{p.name}{'/M(q)' if getattr(p, 'variable_mass', False) else ''}")
def test_gradient_and_jacobian_match_complex_step(plant):
    for eta in random_states(plant, 50):
        scale = np.abs(eta) + 1e-30
        g = differentiation.gradient(plant.H, eta, scale)
        np.testing.assert_allclose(plant.grad_H(eta), g, rtol=1e-10, atol=1e-14 * np.max(np.abs(g)))
        u = rng.normal(size=plant.n_e)
        J = differentiation.jacobian(lambda e: plant.f(e, u), eta, scale)
        Ja = plant.jacobian(eta)
        np.testing.assert_allclose(Ja, J, rtol=1e-9, atol=1e-12 * np.max(np.abs(J)))


@pytest.mark.parametrize("plant", PLANTS[:3], ids=lambda p: p.name)
def test_power_balance(plant):
    """dH/dt = -grad_p H^T R_m grad_p H - grad_xe H^T R_e grad_xe H + y^T u, y = G_e^T grad_xe H
    (the pH passivity identity, independent of how f is assembled)."""
    m = plant.n_m
    for eta in random_states(plant, 50):
        u = rng.normal(size=plant.n_e)
        gH = plant.grad_H(eta)
        gp, gx = gH[m:2 * m], gH[2 * m:]
        dH = gH @ plant.f(eta, u)
        expected = -gp @ plant.R_m @ gp - gx @ plant.R_e @ gx + (plant.G_e.T @ gx) @ u
        assert dH == pytest.approx(expected, rel=1e-9, abs=1e-12 * np.abs(gH) @ np.abs(plant.f(eta, u)))


def test_mems_matches_the_papers_model():
    """Section 7.1: m q'' = -a1 q - a2 q^3 - R_m q' + x_e^2 / (2 c1 (q + c0)^2), r_e x_e' = u - x_e / (c1 (q + c0))."""
    P = MEMS()
    q, p, x = 2e-5, 3e-10, 4e-11
    d = P.f(np.array([q, p, x]), 7.0)
    assert d[0] == pytest.approx(p / P.m, rel=1e-14)
    assert d[1] == pytest.approx(-P.a1 * q - P.a2 * q**3 - P.R_m * p / P.m + x**2 / (2 * P.c1 * (q + P.c0) ** 2), rel=1e-12)
    assert d[2] == pytest.approx((7.0 - x / (P.c1 * (q + P.c0))) / P.r_e, rel=1e-12)


def test_maglev_matches_the_papers_model():
    """Section 7.2: m q'' = -b + x_e^2/(2k), x_e' = -R_e (c - q) x_e / k + u."""
    P = Maglev()
    q, p, x = 0.002, 0.01, 1.1
    d = P.f(np.array([q, p, x]), 0.3)
    assert d[1] == pytest.approx(-P.b + x**2 / (2 * P.k), rel=1e-13)
    assert d[2] == pytest.approx(-P.R_e * (P.c - q) * x / P.k + 0.3, rel=1e-13)


@pytest.mark.parametrize("module,cls", [(mems, MEMS), (maglev, Maglev)])
def test_invalid_parameters_are_refused_by_name(module, cls):
    for spec in module.PARAMETERS.values():
        bad = [float("nan"), float("inf"), "abc", 1e-300, 1e300] + ([0.0, -1.0] if spec.condition == "> 0" else [-1.0])
        for value in bad:
            with pytest.raises(ValueError, match=rf"\b{spec.name}\b"):
                cls(**{spec.name: value})
    with pytest.raises(ValueError, match="unknown parameter"):
        cls(not_a_parameter=1.0)


def test_parameters_have_units_and_descriptions():
    for module in (mems, maglev):
        for spec in module.PARAMETERS.values():
            assert spec.unit and spec.description
        for unit, description in module.STATES.values():
            assert unit and description


def test_domains():
    P = MEMS()
    P.check_state(np.array([-0.99 * P.c0, 0, 0]))
    with pytest.raises(DomainError, match="q \\+ c0 > 0"):
        P.check_state(np.array([-P.c0, 0, 0]))
    B = Maglev()
    B.check_state(np.array([0.999 * B.c, 0, 1]))
    with pytest.raises(DomainError, match="q < c"):
        B.check_state(np.array([B.c, 0, 1]))
    with pytest.raises(DomainError, match="not finite"):
        B.check_state(np.array([0.0, np.nan, 1]))
