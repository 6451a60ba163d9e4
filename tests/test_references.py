"""Reference jets and feasible trajectories (Definition 1)."""
import numpy as np
import pytest

from components.maglev import Maglev
from components.mems import MEMS
from components.ph_plant import Jet
from components.references import Constant, Sinusoid, SmoothStep


def numeric_derivative(f, t, h):
    """Fourth-order central difference."""
    return (-f(t + 2 * h) + 8 * f(t + h) - 8 * f(t - h) + f(t - 2 * h)) / (12 * h)


@pytest.mark.parametrize("ref,times", [
    (Sinusoid(), [0.0, 0.013, 0.1]),
    (SmoothStep(q_from=1e-5, q_to=3e-5, t_start=1e-3, duration=2e-3), [1.2e-3, 2e-3, 2.9e-3]),
])
def test_jet_derivatives_are_consistent(ref, times):
    for t in times:
        jet = ref.jet(t)
        scale = ref.params.get("duration", 0.05)
        h = 1e-4 * scale
        for lower, higher in [("q", "qd"), ("qd", "qdd"), ("qdd", "qddd")]:
            num = numeric_derivative(lambda s: getattr(ref.jet(s), lower)[0], t, h)
            exact = getattr(jet, higher)[0]
            assert num == pytest.approx(exact, rel=1e-6, abs=1e-9 * abs(getattr(ref.jet(t), "qddd")[0]) * scale**3 + 1e-20)


def test_smooth_step_is_c3_at_its_ends():
    ref = SmoothStep(q_from=1.0, q_to=2.0, t_start=1.0, duration=2.0)
    for t_edge, q_edge in [(1.0, 1.0), (3.0, 2.0)]:
        for t in (t_edge - 1e-9, t_edge + 1e-9):
            j = ref.jet(t)
            assert j.q[0] == pytest.approx(q_edge, abs=1e-8)
            assert abs(j.qd[0]) < 1e-6 and abs(j.qdd[0]) < 1e-4 and abs(j.qddd[0]) < 1e-2
    assert ref.jet(2.0).q[0] == pytest.approx(1.5)


def test_mems_feasible_state_is_the_papers_formula():
    """Section 7.1: p* = m q*', x_e* = (c0 + q*) sqrt(2 c1 (m q*'' + b q*' + a1 q* + a2 q*^3)), b = R_m."""
    P, ref = MEMS(), Sinusoid()
    for t in np.linspace(0, 0.2, 7):
        j = ref.jet(t)
        eta, _ = P.feasible_state(j)
        q, qd, qdd = j.q[0], j.qd[0], j.qdd[0]
        b = P.params["R_m"]
        x = (P.c0 + q) * np.sqrt(2 * P.c1 * (P.m * qdd + b * qd + P.a1 * q + P.a2 * q**3))
        np.testing.assert_allclose(eta, [q, P.m * qd, x], rtol=1e-13)


def test_maglev_feasible_state_is_the_papers_formula():
    """Section 7.2: p* = m q*', x_e* = sqrt(2 k (m q*'' + b))."""
    P, ref = Maglev(), Sinusoid(offset=0.0025, amplitude=0.001, omega=5.0)
    for t in np.linspace(0, 2, 7):
        j = ref.jet(t)
        eta, _ = P.feasible_state(j)
        np.testing.assert_allclose(eta, [j.q[0], P.m * j.qd[0], np.sqrt(2 * P.k * (P.m * j.qdd[0] + P.b))], rtol=1e-13)


@pytest.mark.parametrize("plant,ref", [
    (MEMS(), Sinusoid()),
    (Maglev(), Sinusoid(offset=0.0025, amplitude=0.001, omega=5.0)),
    (MEMS(), SmoothStep(q_from=1e-5, q_to=3e-5, t_start=0.0, duration=1e-3)),
])
def test_feasible_state_satisfies_definition_1(plant, ref):
    """eta*(t) solves the open-loop mechanical equations for any u (the p-row does not see u),
    and x_e*' is the time derivative of x_e*(t)."""
    T = ref.params.get("duration", 0.2)
    h = 1e-4 * T
    star = lambda s: plant.feasible_state(ref.jet(s))[0]                      # noqa: E731
    rows = []
    for t in np.linspace(0.1 * T, 0.9 * T, 5):
        eta, xe_dot = plant.feasible_state(ref.jet(t))
        d = plant.f(eta, np.zeros(1))
        rows.append((d[0], d[1], xe_dot[0], numeric_derivative(star, t, h)))
    model = np.array([r[:3] for r in rows])
    numeric = np.array([r[3] for r in rows])
    for col in range(3):                                     # q', p', x_e' each against its own scale
        np.testing.assert_allclose(model[:, col], numeric[:, col], rtol=1e-6, atol=1e-7 * np.max(np.abs(numeric[:, col])))


def test_infeasible_references_are_refused():
    with pytest.raises(ValueError, match="infeasible reference.*x_e\\*"):
        MEMS().feasible_state(Constant(q_d=-1e-6).jet(0))        # spring pushes away: no attraction can hold it
    with pytest.raises(ValueError, match="infeasible reference"):   # faster than free fall: the magnet cannot push
        Maglev().feasible_state(Sinusoid(offset=0.0025, amplitude=0.001, omega=200.0).jet(np.pi / 400))
    with pytest.raises(ValueError, match="q < c"):
        Maglev().feasible_state(Constant(q_d=0.006).jet(0))
    with pytest.raises(ValueError, match="q \\+ c0 > 0"):
        MEMS().feasible_state(Jet(np.array([-2e-5]), np.zeros(1), np.array([-1e6]), np.zeros(1)))


@pytest.mark.parametrize("cls", [Constant, Sinusoid, SmoothStep])
def test_invalid_reference_parameters_are_refused_by_name(cls):
    for spec in cls.PARAMETERS.values():
        with pytest.raises(ValueError, match=rf"\b{spec.name}\b"):
            cls(**{spec.name: float("nan")})
        if spec.condition != "any":
            with pytest.raises(ValueError, match=rf"\b{spec.name}\b"):
                cls(**{spec.name: -1.0})
