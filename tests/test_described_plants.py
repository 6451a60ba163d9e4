"""Plants generated from descriptions agree with independent truths.

- The paper's MEMS and maglev (components/plants/*.toml -> *_model.py) against their hand-written
  formulas (tests/hand_written_plants.py): model functions, f, jacobian, H, feasible states and the
  four controllers' u, to 1e-12 relative at random states.
- A 2 x 2 description (a bar levitated by two electromagnets) against its hand-written model, and the
  matching identity of every design: plant.f(eta, u(eta)) = F_d grad H_d(eta), eq. (closedloop), with
  grad H_d by the complex step of the controller's H_d.
- A description with a q-dependent mass: derivatives of M^-1 and Psi by complex step, and the feasible
  reference (Definition 1) satisfies the p-row of eq. (open-loop elecmech) with p*' by complex step.
"""
import numpy as np
import pytest

from components import codegen, maglev, mems
from components.codegen import device
from components.description import parse
from components.ph_plant import DomainError, Jet
from components.proposition1 import Proposition1
from components.proposition2 import Proposition2
from components.references import Sinusoid
from components.theorem2 import Theorem2
from components.theorem3 import Theorem3
from tests.hand_written_plants import BAR_TOML, HandBar, HandMaglev, HandMEMS
from tests.plants_for_tests import VectorSinusoid

RTOL = 1e-12
H = 1e-30            # complex step


def close(a, b, rtol=RTOL):
    a, b = np.asarray(a), np.asarray(b)
    scale = max(float(np.max(np.abs(b))), 1e-300)
    return bool(np.all(np.abs(a - b) <= rtol * scale))


def test_committed_model_modules_are_current():
    assert codegen.stale() == [], "run: python -m components.codegen"


def test_public_api_kept():
    assert list(mems.PARAMETERS) == ["c0", "c1", "m", "a1", "a2", "R_m", "r_e"]
    assert list(maglev.PARAMETERS) == ["k", "R_e", "c", "b", "m", "R_m"]
    assert mems.STATES["x_e"] == ("C", "charge of the actuator capacitor") and mems.INPUT[0] == "u"
    assert maglev.INPUT == ("u", "V", "coil voltage")
    assert mems.MEMS().q_min == -15e-6 and maglev.Maglev().q_max == 0.005
    assert mems.MEMS(a1=0.5).a1 == 0.5 and maglev.Maglev().Gamma[0, 0] == 1 / (2 * 0.64042)


def _states(kind, rng, n=25):
    if kind == "MEMS":
        return [np.array([rng.uniform(-0.9e-5, 0.1), rng.normal(0, 1e-9), rng.normal(0, 1e-6)]) for _ in range(n)]
    return [np.array([rng.uniform(-0.01, 0.0049), rng.normal(0, 0.01), rng.normal(0, 0.5)]) for _ in range(n)]


PAIRS = [("MEMS", mems.MEMS, HandMEMS, {"a1": 0.5, "r_e": 50.0}),
         ("Maglev", maglev.Maglev, HandMaglev, {"k": 0.6, "R_m": 0.01})]


@pytest.mark.parametrize("kind,gen,hand,values", PAIRS, ids=[p[0] for p in PAIRS])
def test_generated_paper_plants_equal_hand_written(kind, gen, hand, values):
    rng = np.random.default_rng(7)
    for params in ({}, values):
        G, Hw = gen(**params), hand(**params)
        for key in ("R_m", "J_e", "R_e", "G_e"):
            assert close(getattr(G, key), getattr(Hw, key))
        assert G.m == Hw.m and (G.q_min, G.q_max) == (Hw.q_min, Hw.q_max)
        for eta in _states(kind, rng):
            q = eta[0]
            for fn in ("V_s", "dV", "d2V", "psi", "dpsi", "d2psi"):
                assert close(getattr(G, fn)(q), getattr(Hw, fn)(q)), fn
                qc = complex(q, 1e-3 * abs(q))
                assert close(getattr(G, fn)(qc), getattr(Hw, fn)(qc)), fn      # complex arguments too
            u = np.array([rng.normal()])
            assert close(G.f(eta, u), Hw.f(eta, u))
            assert close(G.jacobian(eta), Hw.jacobian(eta))
            assert close(G.H(eta), Hw.H(eta))
            assert G.domain_margin(eta) == Hw.domain_margin(eta)
        if kind == "Maglev":
            for x in (0.3, -0.2, complex(0.1, 1e-3)):
                for fn in ("phi_s", "dphi", "d2phi"):
                    assert close(getattr(G, fn)(x), getattr(Hw, fn)(x))
            assert close(G.Gamma, Hw.Gamma)


def test_feasible_states_and_controllers_equal_hand_written():
    rng = np.random.default_rng(11)
    mems_jet = Sinusoid(offset=0.05, amplitude=0.05, omega=30.0)
    maglev_jet = Sinusoid(offset=0.0025, amplitude=0.001, omega=5.0)
    laws = [
        (mems.MEMS, HandMEMS, "MEMS", lambda P: Proposition1(P, 3e-5, mems.R_e_bar_from_rbar_e(100.0), D_d=0.0), None),
        (mems.MEMS, HandMEMS, "MEMS", lambda P: Theorem2(P, mems.R_e_bar_from_rbar_e(50.0), D_d=-0.4), mems_jet),
        (maglev.Maglev, HandMaglev, "Maglev", lambda P: Proposition2(P, 0.0025, 2.82, k_c=20.0, D_d=0.0), None),
        (maglev.Maglev, HandMaglev, "Maglev", lambda P: Theorem3(P, 2.82, k_c=10.0, D_d=-0.5), maglev_jet),
    ]
    for gen, hand, kind, law, ref in laws:
        a, b = law(gen()), law(hand())
        for eta in _states(kind, rng, 10):
            jet = ref.jet(rng.uniform(0, 1)) if ref is not None else None
            assert close(a.u(eta, jet), b.u(eta, jet)), a.name
            if jet is not None:
                (ea, xa), (eb, xb) = gen().feasible_state(jet), hand().feasible_state(jet)
                assert close(ea, eb) and close(xa, xb)
        assert close(a.target(jet), b.target(jet))


def test_domain_errors_as_before():
    with pytest.raises(DomainError, match=r"^MEMS optical switch: q = -2e-05 m violates q \+ c0 > 0 \(c0 = 1.5e-05 m\): "
                                          "the capacitor gap has closed$"):
        mems.MEMS().check_state(np.array([-2e-5, 0.0, 0.0]))
    with pytest.raises(DomainError, match=r"^magnetic levitation system: q = 0.006 m violates q < c \(c = 0.005 m\): "
                                          "the ball has reached the magnet$"):
        maglev.Maglev().check_state(np.array([0.006, 0.0, 0.0]))
    for P, eta in ((mems.MEMS(), [-2e-5, 0, 0]), (HandMEMS(), [-2e-5, 0, 0]), (maglev.Maglev(), [0.006, 0, 0]),
                   (HandMaglev(), [0.006, 0, 0])):
        with pytest.raises(DomainError):
            P.check_state(np.array(eta, dtype=float))
    with pytest.raises(ValueError, match="parameter c0"):
        mems.MEMS(c0=-1.0)


# ---- general n: the levitated bar ---------------------------------------------------------------------
BAR = parse(BAR_TOML, "bar.toml")


def _bar_states(rng, n=10):
    out = []
    while len(out) < n:
        q = np.array([rng.uniform(-0.01, 0.009), rng.uniform(-0.05, 0.05)])
        if 0.01 - q[0] - 0.1 * abs(q[1]) > 1e-4:
            out.append(np.concatenate([q, rng.normal(0, 0.01, 2), rng.uniform(0.2, 0.8, 2)]))
    return out


def test_bar_equals_hand_written():
    G, Hw = codegen.plant_class(BAR)(), HandBar()
    rng = np.random.default_rng(3)
    for eta in _bar_states(rng):
        q = eta[:2]
        for fn in ("M_inv", "V", "grad_V", "hess_V", "Psi", "dPsi", "d2Psi"):
            assert close(getattr(G, fn)(q), getattr(Hw, fn)(q)), fn
        # the derived factorization is the hand-written one rescaled per port (Gamma_0 S, phi_0 / S): the product
        # of eq. (assHereg) is the same, and S is diagonal and positive
        assert close(G.Gamma @ G.grad_phi(eta[4:]), Hw.Gamma @ Hw.grad_phi(eta[4:]))
        S = G.Gamma / Hw.Gamma
        assert close(S, S[:1].repeat(2, axis=0)) and np.all(S > 0)
        assert close(G.f(eta, np.ones(2)), Hw.f(eta, np.ones(2))) and close(G.jacobian(eta), Hw.jacobian(eta))
    ref = VectorSinusoid([0.004, 0.01], [0.001, 0.005], [3.0, 2.0], [0.0, 0.5])
    for t in (0.0, 0.3, 1.1):
        (ea, xa), (eb, xb) = G.feasible_state(ref.jet(t)), Hw.feasible_state(ref.jet(t))
        assert close(ea, eb, 1e-10) and close(xa, xb, 1e-10)


def test_bar_domain_and_infeasible():
    G = codegen.plant_class(BAR)()
    with pytest.raises(DomainError, match=r"z = 0.0095 m, theta = 0.01 rad violates z \+ l\*theta < c \(c = 0.01 m, l = 0.1 m\)"):
        G.check_state(np.array([0.0095, 0.01, 0, 0, 1, 1]))
    assert G.domain_margin(np.array([0.0, 0.0, 0, 0, 1, 1])) == pytest.approx(0.01)
    z = np.zeros(2)
    with pytest.raises(ValueError, match="infeasible reference"):      # pulling down needs negative force
        G.feasible_state(Jet(np.array([0.0, 0.0]), z, np.array([-100.0, 0.0]), z))


def _grad_complex_step(fn, eta):
    g = np.zeros(len(eta))
    for i in range(len(eta)):
        e = eta.astype(complex)
        e[i] += 1j * H
        g[i] = np.imag(fn(e)) / H
    return g


@pytest.mark.parametrize("design", ["Proposition1", "Proposition2", "Theorem2", "Theorem3"])
def test_bar_closed_loop_matches_target(design):
    dev = device(BAR)
    assert set(dev.designs) == {"Proposition1", "Proposition2", "Theorem2", "Theorem3"}
    d = dev.designs[design]
    if design.startswith("Proposition"):
        assert {"q_d_1", "q_d_2"} <= set(d.gains)
    assert "R_e_bar_1_2" in d.gains and "D_d_2_1" in d.gains and d.gains["R_e_bar_1_1"].unit == "Ohm"
    assert d.gains["D_d_1_2"].unit == "Wb/rad"
    values = {"D_d_1_1": 0.1, "D_d_2_2": 0.01} if design == "Proposition1" else {"D_d_1_2": -0.2, "D_d_2_1": 0.3}
    if design in ("Proposition2", "Theorem3"):
        values = {"D_d_1_1": 0.0}                  # R_m = diag(d_z, d_theta): keep the pH condition
    C = dev.controller(design, values)
    P = C.plant
    rng = np.random.default_rng(5)
    ref = VectorSinusoid([0.004, 0.01], [0.001, 0.005], [3.0, 2.0], [0.0, 0.5])
    for eta in _bar_states(rng, 6):
        jet = ref.jet(rng.uniform(0, 2)) if C.tracking else None
        lhs = P.f(eta, C.u(eta, jet))                                             # plant under the law
        rhs = C.F_d() @ _grad_complex_step(lambda e: C.H_d(e, jet), eta)          # eq. (closedloop)
        assert close(lhs, rhs, 1e-9), (design, lhs, rhs)


def test_device_gains_of_the_paper_plants():
    dev = device(parse(open("components/plants/mems.toml").read(), "mems.toml"), ["Proposition1", "Theorem2"])
    assert list(dev.designs["Proposition1"].gains) == ["q_d", "rbar_e", "D_d"]
    assert dev.designs["Proposition1"].gains["D_d"].unit == "C/m"
    C = dev.controller("Theorem2", {"rbar_e": 50.0, "D_d": -0.4})
    B = Theorem2(HandMEMS(), mems.R_e_bar_from_rbar_e(50.0), D_d=-0.4)
    eta, jet = np.array([0.06, 2.8e-9, 2.9e-6]), Sinusoid().jet(0.2)
    assert close(C.u(eta, jet), B.u(eta, jet))
    dev = device(parse(open("components/plants/maglev.toml").read(), "maglev.toml"))
    g = dev.designs["Proposition2"].gains
    assert [(n, g[n].default, g[n].unit) for n in g] == [("q_d", 0.0025, "m"), ("R_e_bar", 2.82, "Ohm"),
                                                        ("k_c", 20.0, "1"), ("D_d", 0.0, "Wb/m")]


# ---- a q-dependent mass ----------------------------------------------------------------------------------
VARIABLE_MASS = BAR_TOML.replace('M   = [["m", "0"], ["0", "J"]]', 'M   = [["m + mu*theta^2", "0.01*m"], ["0.01*m", "J"]]') \
    .replace('d_theta = [0.001', 'mu      = [0.5, "kg/rad2", "mass growing with tilt", "> 0"]\nd_theta = [0.001') \
    .replace('V   = "b*z"', 'V   = "b*z + kt*theta^2/2"') \
    .replace('R       = [2.0', 'kt      = [0.3, "N.m/rad", "torsion spring", "> 0"]\nR       = [2.0')


def test_variable_mass_derivatives_and_feasible_reference():
    desc = parse(VARIABLE_MASS, "vm.toml")
    assert not desc.constant_mass
    P = codegen.plant_class(desc)()
    q = np.array([0.002, 0.03])
    for k in range(2):
        dq = np.zeros(2, dtype=complex)
        dq[k] = 1j * H
        assert close(P.dM_inv(q)[k], np.imag(P.M_inv(q + dq)) / H)
        assert close(P.d2M_inv(q)[k], np.imag(P.dM_inv(q + dq)) / H)
        assert close(P.dPsi(q)[k], np.imag(P.Psi(q + dq)) / H)
    eta = np.array([0.002, 0.03, 0.01, -0.02, 0.5, 0.6])
    assert close(P.hess_H(eta), np.array([_grad_complex_step(lambda e: P.grad_H(e)[i], eta) for i in range(6)]), 1e-10)
    ref = VectorSinusoid([0.004, 0.01], [0.001, 0.005], [3.0, 2.0], [0.0, 0.5])
    for t in (0.1, 0.7):
        eta_s, x_dot = P.feasible_state(ref.jet(t))
        # complex step in time through the whole construction: d eta* / dt
        d_eta = np.imag(P.feasible_state(ref.jet(complex(t, H)))[0]) / H
        assert close(d_eta[4:], x_dot, 1e-9)                                 # x_e*' of Definition 1
        f = P.f(eta_s, np.zeros(2))                                         # u enters the x_e rows only
        assert close(f[:4], d_eta[:4], 1e-9)                                # q' and p' rows hold on eta*


def test_unequal_dimensions_refuse_feasible_state():
    text = BAR_TOML.replace('x_e = [["x_1", "Wb", "flux linkage of coil 1"], ["x_2", "Wb", "flux linkage of coil 2"]]',
                            'x_e = [["x_1", "Wb", "flux linkage"]]').replace(
        'u   = [["u_1", "V", "voltage of coil 1"], ["u_2", "V", "voltage of coil 2"]]', 'u   = [["u_1", "V", "voltage"]]') \
        .replace('Psi = [["(c - z - l*theta)/k", "0"], ["0", "(c - z + l*theta)/k"]]', 'Psi = "(c - z)/k"') \
        .replace('J_e = [["0", "0"], ["0", "0"]]', 'J_e = "0"').replace('R_e = [["R", "0"], ["0", "R"]]', 'R_e = "R"') \
        .replace('G_e = [["1", "0"], ["0", "1"]]', 'G_e = "1"').replace("k_c = [[20.0, 0.0], [0.0, 20.0]]", "k_c = 20.0")
    P = codegen.plant_class(parse(text))()
    z = np.zeros(2)
    with pytest.raises(NotImplementedError, match="n_e >= n_m"):
        P.feasible_state(Jet(z, z, z, z))


def test_issue_file_builds_the_maglev():
    from tests.test_description import ISSUE_MAGLEV
    P, M = codegen.plant_class(parse(ISSUE_MAGLEV, "issue25.toml"))(), maglev.Maglev()
    rng = np.random.default_rng(2)
    for eta in _states("Maglev", rng, 10):
        assert close(P.f(eta, np.array([1.0])), M.f(eta, np.array([1.0]))) and P.H(eta) == M.H(eta)
    assert P.q_max == M.q_max and close(P.Gamma, M.Gamma)
    dev = device(parse(ISSUE_MAGLEV))
    C = dev.controller("Theorem3", {"R_e_bar": 2.82, "k_c": 10.0, "D_d": -0.5})
    B = Theorem3(HandMaglev(), 2.82, k_c=10.0, D_d=-0.5)
    eta, jet = np.array([0.002, 0.01, 1.0]), Sinusoid(offset=0.0025, amplitude=0.001, omega=5.0).jet(0.3)
    assert close(C.u(eta, jet), B.u(eta, jet))


def test_x_e_sign_picks_the_negative_root():
    text = BAR_TOML.replace('domain = [', 'x_e_sign = -1\ndomain = [')
    P, Q = codegen.plant_class(parse(text))(), codegen.plant_class(BAR)()
    jet = VectorSinusoid([0.004, 0.01], [0.001, 0.005], [3.0, 2.0], [0.0, 0.5]).jet(0.4)
    (a, xa), (b, xb) = P.feasible_state(jet), Q.feasible_state(jet)
    assert np.all(a[4:] < 0) and close(a[4:], -b[4:]) and close(xa, -xb)


def test_one_dof_nonlinear_domain_and_variable_mass():
    from tests.test_description import ISSUE_MAGLEV
    text = ISSUE_MAGLEV.replace('domain = ["q < c"]', 'domain = ["q^2 < c^2"]')
    P = codegen.plant_class(parse(text))()
    assert not P.linear_domain and P.domain_margin(np.array([0.001, 0, 0])) == pytest.approx(0.005 ** 2 - 0.001 ** 2)
    with pytest.raises(DomainError, match=r"q = -0.006 m violates q\^2 < c\^2 \(c = 0.005 m\)"):
        P.check_state(np.array([-0.006, 0.0, 0.0]))
    # M(q): the general path with n_m = n_e = 1 agrees with the scalar formulas of Definition 1
    text = ISSUE_MAGLEV.replace('M   = "m"', 'M   = "m*(1 + q^2)"')
    P = codegen.plant_class(parse(text))()
    assert not P.constant_mass
    q, qd, qdd, qddd = 0.002, 0.01, 0.3, -2.0
    eta, x_dot = P.feasible_state(Jet(*(np.array([v]) for v in (q, qd, qdd, qddd))))
    m, b, k = 0.0844, 0.828, 0.64042
    M, dM = m * (1 + q * q), 2 * m * q
    p = M * qd
    F = M * qdd + dM * qd * qd + b - 0.5 * p * p * dM / M ** 2     # p' + grad V + 1/2 p^2 d(1/M)/dq
    assert close(eta, [q, p, np.sqrt(2 * k * F)])
    jet_c = Jet(*(np.array([v]) for v in (complex(q, qd * H), complex(qd, qdd * H), complex(qdd, qddd * H),
                                          complex(qddd, 0.0))))
    assert close(x_dot, np.imag(P.feasible_state(jet_c)[0][2:]) / H, 1e-9)


def test_catalog_gains_equal_the_descriptions_gains():
    """The catalog's hand-written designs and the descriptions' devices name the same gains, with the same
    defaults, units and conditions (only the descriptive texts differ)."""
    from components import catalog
    from components.description import load
    for name, file in (("MEMS", "mems"), ("Maglev", "maglev")):
        old = catalog.DEVICES[name]
        new = device(load(f"components/plants/{file}.toml"), list(old.designs))
        assert old.parameters == new.parameters and (old.q, old.p, old.x_e, old.u) == (new.q, new.p, new.x_e, new.u)
        for design, d in old.designs.items():
            g = new.designs[design].gains
            assert [(p.name, p.default, p.unit, p.condition) for p in d.gains.values()] == \
                [(p.name, p.default, p.unit, p.condition) for p in g.values()], design


def test_functions_take_floats_and_complex_numbers():
    from tests.test_description import ISSUE_MAGLEV
    text = ISSUE_MAGLEV.replace('V   = "b*q"', 'V   = "b*q + b*c*exp(q/c) + b*c*cos(q/c)^2"') \
        .replace('Psi = "(c - q)/k"', 'Psi = "sqrt(c - q)/k + 1/(k*(1 + tanh(q/c)^2))"')
    desc = parse(text)
    source = codegen.module_source(desc)
    assert "import sympy" not in source and "_sqrt(" in source and "_exp(" in source
    P = codegen.plant_class(desc)()
    for q in (-0.01, 0.001, 0.0049):
        for f, df in (("V_s", "dV"), ("dV", "d2V"), ("psi", "dpsi"), ("dpsi", "d2psi")):
            assert close(getattr(P, df)(q), np.imag(getattr(P, f)(complex(q, H))) / H), (f, q)
    with pytest.raises(DomainError, match="violates q < c"):
        P.check_state(np.array([0.006, 0.0, 0.0]))


@pytest.mark.parametrize("values, message", [
    ({"R_e": -1.0}, "R_e = [[-1.0]] violates R_e = R_e^T >= 0"),
    ({"R_m": -0.5}, "R_m = [[-0.5]] violates R_m = R_m^T >= 0"),
    ({"m": -0.1}, "violates M = M^T > 0"),
])
def test_a_plant_of_the_issues_file_refuses_parameters_that_break_the_structure(values, message):
    """The issue's file gives no parameter conditions, so the parameters are any finite numbers; the plant
    still refuses values that break eq. (open-loop elecmech) (checked at these values, not only at the
    defaults as the description was), naming the matrix and the parameters."""
    from components.codegen import plant_class
    from tests.test_description import ISSUE_MAGLEV

    cls = plant_class(parse(ISSUE_MAGLEV, "issue25.toml"))
    with pytest.raises(ValueError) as err:
        cls(**values)
    assert message in str(err.value) and "with k = 0.64042" in str(err.value)


def test_a_state_where_psi_is_not_positive_is_refused():
    """k < 0 makes Psi = (c - q)/k negative inside q < c: the plant's check_state (which a plant FMU runs on
    its initial state) says so instead of integrating a negative stored energy."""
    from components.codegen import plant_class
    from components.ph_plant import DomainError
    from tests.test_description import ISSUE_MAGLEV

    plant = plant_class(parse(ISSUE_MAGLEV, "issue25.toml"))(k=-0.64042)
    with pytest.raises(DomainError, match=r"Psi\(q\) = .* is not positive at q = 0.0025"):
        plant.check_state(np.array([0.0025, 0.0, 1.0]))
    plant_class(parse(ISSUE_MAGLEV, "issue25.toml"))().check_state(np.array([0.0025, 0.0, 1.0]))
