"""The four controllers: matching identity (closed loop = target pH system), set-points, the paper's
explicit Section 7 formulas, the errata, and refusal of invalid parameters."""
import numpy as np
import pytest

from components import closed_loop, differentiation
from components.maglev import D_d_from_paper, Maglev
from components.mems import MEMS, R_e_bar_from_rbar_e
from components.proposition1 import Proposition1
from components.proposition2 import Proposition2
from components.references import Constant, Sinusoid
from components.theorem2 import Theorem2
from components.theorem3 import Theorem3
from tests.helpers import CASES, MAGLEV_REF, RBAR, random_state_near


@pytest.mark.parametrize("name", list(CASES))
def test_matching_identity(name):
    """f(eta, u(eta, t)) = F_d grad H_d(eta, t) (eqs. closedloop, Eq:R-J) at 1000 random states and times,
    grad H_d by the complex step of H_d, which is written independently of the control law."""
    ctrl, ref, horizon = CASES[name]
    rng = np.random.default_rng(abs(hash(name)) % 2**32)
    F_d = ctrl.F_d()
    worst = 0.0
    for _ in range(1000):
        jet = None if ref is None else ref.jet(rng.uniform(0, horizon))
        eta = random_state_near(ctrl.target(jet), rng, ctrl.plant)
        lhs = ctrl.plant.f(eta, ctrl.u(eta, jet))
        gH = differentiation.gradient(lambda e: ctrl.H_d(e, jet), eta, scale=np.abs(eta) + 1e-30)
        rhs = F_d @ gH
        # relative to the size of the terms that make up each row of F_d grad H_d
        size = np.abs(F_d) @ np.abs(gH)
        assert np.all(size > 0) and np.all(np.isfinite(lhs))
        worst = max(worst, float(np.max(np.abs(lhs - rhs) / size)))
    assert worst < 1e-10, worst


@pytest.mark.parametrize("name", [n for n in CASES if not n.startswith("2-axis")])
def test_scalar_law_is_the_matrix_law(name):
    """For the one-DOF plants the controllers evaluate the law in scalars (what the FMUs and the
    monolithic reference run); the matrix form of the paper gives the same u at random states and
    times. (The matching identity above checks the scalar law itself for these plants, and the
    matrix law for the two-axis plant.)"""
    ctrl, ref, horizon = CASES[name]
    assert ctrl.scalars is not None
    rng = np.random.default_rng(7)
    for _ in range(300):
        jet = None if ref is None else ref.jet(rng.uniform(0, horizon))
        eta = random_state_near(ctrl.target(jet), rng, ctrl.plant)
        u_matrix = ctrl.u_matrix(eta, jet)[0]
        assert ctrl.u(eta, jet)[0] == pytest.approx(u_matrix, rel=1e-12, abs=1e-15 * abs(u_matrix))


@pytest.mark.parametrize("name", ["MEMS Prop1", "maglev Prop2", "2-axis Prop1", "2-axis Prop2"])
def test_regulation_set_point_is_a_strict_minimum_of_H_d(name):
    """grad H_d(eta_d) = 0 (eq. gradHd), H_d(eta_d) = 0 (eq. Hd) and hess H_d(eta_d) > 0 (phi12 / Phic22)."""
    ctrl = CASES[name][0]
    eta_d = ctrl.target()
    scale = np.abs(eta_d) + 1e-3 * np.max(np.abs(eta_d))
    g = differentiation.gradient(ctrl.H_d, eta_d, scale)
    g_typical = differentiation.gradient(ctrl.H_d, eta_d * 1.01 + 0.01 * scale, scale)
    assert np.all(np.abs(g) <= 1e-12 * np.max(np.abs(g_typical)))
    assert ctrl.H_d(eta_d) == pytest.approx(0.0, abs=1e-14 * abs(ctrl.plant.H(eta_d)) + 1e-300)
    H = _hessian(ctrl.H_d, eta_d, scale)
    assert np.min(np.linalg.eigvalsh(0.5 * (H + H.T))) > 0


def _hessian(f, x, scale):
    """Hessian by central differences of the complex-step gradient."""
    n = x.size
    H = np.empty((n, n))
    for k in range(n):
        h = 1e-5 * scale[k]
        e = np.zeros(n)
        e[k] = h
        H[:, k] = (differentiation.gradient(f, x + e, scale) - differentiation.gradient(f, x - e, scale)) / (2 * h)
    return H


def test_theorem2_regulation_equals_proposition1_without_coupled_damping():
    """With a constant jet the Theorem 2 law and Proposition 1 law coincide (both are eq. c1 with L_1)."""
    P = MEMS()
    p1, t2 = Proposition1(P, 3e-5, RBAR, D_d=0.0), Theorem2(P, RBAR, D_d=0.0)
    jet = Constant(q_d=3e-5).jet(0)
    for eta in ([15e-6, 0, 0], [2e-5, 1e-10, 3e-11], [4e-5, -2e-10, 6e-11]):
        assert t2.u(np.array(eta), jet)[0] == pytest.approx(p1.u(np.array(eta))[0], rel=1e-12)


def test_mems_controller_is_the_papers_eq_C1():
    """Section 7.1, eq. (C1): u = -(r_e/rbar_e)(x_e - x_e* + L_2) - K_e r_e x_e / (c1 (q + c0)) + r_e D_d p / m,
    L_2 = -rbar_e x_e*' - x_e* / (c1 (q* + c0)) + rbar_e D_d p* / m, K_e = 1/rbar_e - 1/r_e."""
    P, ref, rbar, D = MEMS(), Sinusoid(), 100.0, -0.4
    ctrl = Theorem2(P, R_e_bar_from_rbar_e(rbar), D_d=D)
    rng = np.random.default_rng(3)
    K_e = 1 / rbar - 1 / P.r_e
    for t in rng.uniform(0, 0.2, 50):
        jet = ref.jet(t)
        (qs, ps, xs), (xs_dot,) = P.feasible_state(jet)[0], P.feasible_state(jet)[1]
        L2 = -rbar * xs_dot - xs / (P.c1 * (qs + P.c0)) + rbar * D * ps / P.m
        q, p, x = qs * (1 + 0.3 * rng.normal()), ps * (1 + 0.3 * rng.normal()), xs * (1 + 0.3 * rng.normal())
        u_paper = -(P.r_e / rbar) * (x - xs + L2) - K_e * P.r_e * x / (P.c1 * (q + P.c0)) + P.r_e * D * p / P.m
        assert ctrl.u(np.array([q, p, x]), jet)[0] == pytest.approx(u_paper, rel=1e-10)


def maglev_paper_u(P, eta, jet, D_paper, R_bar, k_c, L3_sign):
    """eq. (controlmaglv) with the paper's D_d; L3_sign = +1 is the printed L_3, -1 the corrected one."""
    q, p, x = eta
    (qs, ps, xs), (xs_dot,) = P.feasible_state(jet)
    z, zs = (q / (2 * P.k) + x) / R_bar, (qs / (2 * P.k) + xs) / R_bar
    L3 = (xs_dot + R_bar * xs**2 + k_c * zs + (1 + L3_sign * D_paper) / (2 * P.k * P.m) * ps) / k_c
    return (-1 + D_paper) / (2 * P.k * P.m) * p - R_bar * x**2 - k_c * (z - L3) + P.R_e / P.k * (P.c - q) * x


@pytest.mark.parametrize("D_paper,R_bar", [(0.0, 0.82), (0.0, 2.82), (-1.0, 0.82), (-1.0, 2.82)])
def test_maglev_controller_is_eq_controlmaglv_with_corrected_L3(D_paper, R_bar):
    """Erratum 1: the printed maglev law with the paper's D_d is eq. (tracker2) with D_d = D_paper / (2k).
    Erratum 2: it matches only with (1 - D_d) in L_3."""
    P = Maglev()
    ctrl = Theorem3(P, R_bar, k_c=20.0, D_d=D_d_from_paper(D_paper))
    rng = np.random.default_rng(4)
    for t in rng.uniform(0, 2, 50):
        jet = MAGLEV_REF.jet(t)
        eta = ctrl.target(jet) * (1 + 0.2 * rng.normal(size=3)) + np.array([0, 0.01 * rng.normal(), 0])
        u = ctrl.u(eta, jet)[0]
        assert u == pytest.approx(maglev_paper_u(P, eta, jet, D_paper, R_bar, 20.0, -1), rel=1e-10, abs=1e-12)


def test_erratum2_printed_L3_loses_the_reference():
    """With the printed L_3 (1 + D_d) the reference is a closed-loop trajectory only for D_d = 0:
    started on eta*(t), x_e' differs from x_e*'."""
    P = Maglev()
    for D_paper, should_hold in [(0.0, True), (-1.0, False)]:
        jet = MAGLEV_REF.jet(0.3)
        eta_s, xs_dot = P.feasible_state(jet)
        for sign, corrected in [(-1, True), (+1, False)]:
            u = maglev_paper_u(P, eta_s, jet, D_paper, 0.82, 20.0, sign)
            residual = P.f(eta_s, u)[2] - xs_dot[0]
            on_reference = abs(residual) < 1e-10 * abs(xs_dot[0]) + 1e-12
            assert on_reference == (corrected or should_hold), (D_paper, sign, residual)


def test_erratum3_printed_set_point_condition_has_no_equilibrium():
    """The printed first row of eq. (Phic21), grad_q Phi_2(z_d) = 0, puts Phi_2's minimum at z_d; then
    grad_xe H_d(eta_d) = grad phi(x_e_d) = x_e_d^2 != 0: eta_d is not an equilibrium. Our L does it."""
    P = Maglev()
    ctrl = Proposition2(P, 0.0025, 2.82, k_c=20.0)
    eta_d = ctrl.target()
    printed = Proposition2(P, 0.0025, 2.82, k_c=20.0)
    printed.L = printed.z(eta_d)                                   # grad_z Phi_2(z_d) = 0
    scale = np.abs(eta_d) + 1e-6
    assert np.abs(differentiation.gradient(printed.H_d, eta_d, scale)[2]) == pytest.approx(eta_d[2] ** 2, rel=1e-12)
    assert np.linalg.norm(P.f(eta_d, printed.u_matrix(eta_d))) > 1e-3        # u_matrix reads the L set here
    assert np.linalg.norm(P.f(eta_d, ctrl.u(eta_d))) < 1e-14


def test_ph_condition_is_enforced_by_the_propositions_with_the_bound():
    P = MEMS()
    bound = np.sqrt(4 * P.params["R_m"] / 100.0)                 # |D_d| < sqrt(4 R_m R_e_bar), eq. (pHcondition)
    Proposition1(P, 3e-5, RBAR, D_d=0.99 * bound)
    with pytest.raises(ValueError, match=r"D_d.*pHcondition.*\|D_d\| < 0\.000148"):
        Proposition1(P, 3e-5, RBAR, D_d=-1.0)                     # the paper's Fig. 1 value (erratum 5)
    with pytest.raises(ValueError, match=r"D_d.*pHcondition"):
        Proposition1(P, 3e-5, RBAR, D_d=bound)                   # strict inequality in Proposition 1
    with pytest.raises(ValueError, match=r"D_d.*pHcondition.*\|D_d\| <= 0\b"):
        Proposition2(Maglev(), 0.0025, 2.82, D_d=-0.1)           # R_m = 0: no coupled damping keeps pH
    Theorem2(P, RBAR, D_d=-1.0)                                  # Theorems 2, 3 need no pH condition
    Theorem3(Maglev(), 0.82, D_d=-1.0)
    assert closed_loop.ph_margin(P.R_m, RBAR, np.array([[-1.0]])) < 0


@pytest.mark.parametrize("make,param", [
    (lambda: Theorem2(MEMS(), -0.01), "R_e_bar"),
    (lambda: Theorem2(MEMS(), RBAR, D_d=float("nan")), "D_d"),
    (lambda: Theorem2(MEMS(), RBAR, D_d=[1.0, 2.0]), "D_d"),
    (lambda: Theorem3(Maglev(), 0.82, k_c=0.0), "k_c"),
    (lambda: Theorem3(Maglev(), 0.82, k_c=-3.0), "k_c"),
    (lambda: Theorem3(Maglev(), 0.0), "R_e_bar"),
    (lambda: Proposition2(Maglev(), 0.0025, "x"), "R_e_bar"),
    (lambda: Proposition1(MEMS(), 3e-5, RBAR, W=-1.0), "W"),
    (lambda: Proposition2(Maglev(), 0.006, 2.82), "q < c"),
    (lambda: Proposition1(MEMS(), -1e-6, RBAR), "infeasible"),
])
def test_invalid_controller_parameters_are_refused_by_name(make, param):
    with pytest.raises(ValueError, match=param):
        make()


@pytest.mark.parametrize("name", ["MEMS Thm2 sinusoid", "MEMS Thm2 smooth step", "maglev Thm3", "2-axis Thm2", "2-axis Thm3"])
def test_reference_is_a_closed_loop_trajectory(name):
    """Feasibility (eqs. feasibleT2, L2): on eta*(t) the closed-loop vector field is d eta*/dt =
    (q*', M q*'', x_e*')."""
    ctrl, ref, horizon = CASES[name]
    plant = ctrl.plant
    for t in np.linspace(0.05, 0.95, 7) * horizon:
        jet = ref.jet(t)
        eta_s, xe_dot = plant.feasible_state(jet)
        M = np.linalg.inv(plant.M_inv(jet.q))
        expected = np.concatenate([jet.qd, M @ jet.qdd, xe_dot])
        got = plant.f(eta_s, ctrl.u(eta_s, jet))
        scale = np.abs(plant.F()) @ np.abs(plant.grad_H(eta_s)) + np.abs(expected)
        assert np.all(np.abs(got - expected) <= 1e-10 * scale), (got, expected)


def test_erratum8_printed_L2_without_G_e_loses_the_reference():
    """eq. (L2) as printed (grad_z Theta_2 without G_e) is right only for G_e = I: on the two-axis plant
    (G_e != I) the offset it gives does not keep eta* a closed-loop trajectory."""
    ctrl, ref, _ = CASES["2-axis Thm3"]
    plant, jet = ctrl.plant, ref.jet(0.7)
    eta_s, xe_dot = plant.feasible_state(jet)
    q_s, p_s, x_s = plant.split(eta_s)
    printed_rhs = ((ctrl.D_d - ctrl.Gamma.T) @ plant.M_inv(q_s) @ p_s + ctrl.JR_bar @ plant.grad_phi(x_s) - xe_dot)
    L3_printed = ctrl.z(eta_s) - np.linalg.solve(ctrl.K_c, printed_rhs)
    from components.proposition2 import law_u2
    u_printed = law_u2(ctrl, eta_s, ctrl.K_c @ (ctrl.z(eta_s) - L3_printed))
    assert np.linalg.norm(plant.f(eta_s, u_printed)[4:] - xe_dot) > 1e-3 * np.linalg.norm(xe_dot)
    assert np.linalg.norm(plant.f(eta_s, ctrl.u(eta_s, jet))[4:] - xe_dot) < 1e-10 * np.linalg.norm(xe_dot) + 1e-12


@pytest.mark.parametrize("name", list(CASES))
def test_hess_H_d_matches_the_derivative_of_grad_H_d(name):
    ctrl, ref, horizon = CASES[name]
    rng = np.random.default_rng(7)
    for _ in range(10):
        jet = None if ref is None else ref.jet(rng.uniform(0, horizon))
        eta = random_state_near(ctrl.target(jet), rng, ctrl.plant)
        scale = np.abs(eta) + 1e-3 * np.max(np.abs(eta))
        H_num = _hessian(lambda e: ctrl.H_d(e, jet), eta, scale)
        H = ctrl.hess_H_d(eta, jet)
        entry_scale = np.sqrt(np.outer(np.abs(np.diag(H)), np.abs(np.diag(H))))    # sqrt(|H_ii H_jj|)
        assert np.all(np.abs(H - H_num) <= 1e-6 * entry_scale + 1e-6 * np.abs(H)), (H, H_num)
