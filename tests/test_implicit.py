"""Implicit coupling (emcosim/engine/implicit.py): every communication step iterated until the inputs of
the FMUs with states agree with their sources at its end.

Independent truths: the closed form of the toy loop x' = k x (the C toy FMUs integrate a polynomial
input exactly, so one step multiplies x by the stability function of the coupling: two-stage Radau IIA
for the Hermite polynomial, the trapezoidal rule for chords), and the monolithic Radau solution of
the MEMS loops (components.monolithic)."""
from __future__ import annotations

import numpy as np
import pytest

from emcosim.engine.errors import ScenarioError, SimulationError
from emcosim.engine.master import Simulation, simulate
from emcosim.engine.ssd import read_scenario
from emcosim.engine.ssd_writer import system_structure_xml
from tests.helpers import DYNAMIC, ROOT, STATIC, TIGHT, loop


def radau(z: float) -> float:
    """Stability function of the two-stage Radau IIA method (order 3, L-stable)."""
    return (1 + z / 3) / (1 - 2 * z / 3 + z * z / 6)


def trapezoidal(z: float) -> float:
    return (1 + z / 2) / (1 - z / 2)


@pytest.mark.parametrize("k", [-1.0, -1000.0])
def test_a_step_is_a_radau_step_of_the_loop(make, k):
    """x' = k x with k h = -0.01 and -10: x_n = R(k h)^n, R of Radau IIA; at k h = -10 the stiff mode
    is damped by 0.096 per step (explicit coupling multiplies it by about -9: it diverges)."""
    h = 0.01
    s = loop(make, k=k, step_size=h)
    r = simulate(s, record=["plant.x"], coupling="implicit")
    expected = radau(k * h) ** np.arange(len(r))
    # the iteration stops where the inputs agree to ITERATION_TOL of their largest magnitude (|k| x0)
    np.testing.assert_allclose(r["plant.x"], expected, rtol=1e-5, atol=1e-6)
    assert r.implicit.steps == 100 and r.implicit.trials >= 100
    if k == -1000.0:
        assert np.max(np.abs(r["plant.x"][10:])) < 1e-5                          # damped, not ringing
        try:                                                                      # explicit: diverges
            x = simulate(s, record=["plant.x"])["plant.x"]
        except SimulationError:
            return
        assert np.max(np.abs(x)) > 1e6


def test_a_target_taking_first_derivatives_only_gets_chords(make):
    """The plant refuses input derivatives of order 2 (fmi2Error; FMI 2.0 declares no order): the
    master restores it and couples with chords from then on, the trapezoidal rule on the loop."""
    h, k = 0.01, -1000.0
    s = make([("plant", "dynamic", DYNAMIC, True, 3), ("ctrl", "static", STATIC, True, 3)],
             [("plant.x", "ctrl.u1"), ("ctrl.y", "plant.u")],
             {"ctrl": {"k1": k}, "plant": {"x0": 1.0, "input_order": 1.0}}, 0.2, h)
    r = simulate(s, record=["plant.x"], coupling="implicit")
    np.testing.assert_allclose(r["plant.x"], trapezoidal(k * h) ** np.arange(len(r)), rtol=1e-5, atol=1e-6)


def test_sources_without_derivatives_give_chords(make):
    """The controller declares no output derivatives: chords (trapezoidal rule) on the loop."""
    h, k = 0.01, -3.0
    s = make([("plant", "dynamic", DYNAMIC, True, 0), ("ctrl", "static", STATIC, True, 0)],
             [("plant.x", "ctrl.u1"), ("ctrl.y", "plant.u")], {"ctrl": {"k1": k}, "plant": {"x0": 1.0}}, 0.2, h)
    r = simulate(s, record=["plant.x"], coupling="implicit")
    np.testing.assert_allclose(r["plant.x"], trapezoidal(k * h) ** np.arange(len(r)), rtol=1e-6)


def test_global_error_falls_at_order_3(make):
    errors = []
    for h in (0.1, 0.05, 0.025):
        r = simulate(loop(make, step_size=h), record=["plant.x"], coupling="implicit")
        errors.append(np.max(np.abs(r["plant.x"] - np.exp(-r.time))))
    orders = np.log2(np.array(errors[:-1]) / np.array(errors[1:]))
    assert np.all(np.abs(orders - 3.0) < 0.2), (errors, orders)


def test_implicit_takes_no_coupling_order(make):
    with pytest.raises(ScenarioError, match="coupling_order 2 sets the derivatives of explicit coupling; coupling "
                                            "implicit passes none"):
        simulate(loop(make), coupling="implicit", coupling_order=2)


def test_mems_converges_at_third_order_where_explicit_coupling_is_unstable(fmu_dir, references):
    """mems_regulation_Dd-1 (a stiff loop: the voltage law feeds back the momentum through D_d = -1)
    over its full 20 ms against the monolithic reference: implicit coupling converges at order >= 2.6
    at steps of 40, 20, 10 us; explicit coupling at 20 us errs more than ten times as much (its guard
    holds the input: first order, at the edge of stability)."""
    from emcosim.paper.reference_check import position_error, samples_for
    s = read_scenario(ROOT / "scenarios" / "mems_regulation_Dd-1", fmu_dir=fmu_dir)
    assert s.coupling == "implicit"
    ref = references(s, s.stop_time, samples_for(s.stop_time, 4e-5, 1001))
    errors = []
    with Simulation(s) as sim:
        for h in (4e-5, 2e-5, 1e-5):
            r = sim.run(step_size=h, record=["plant.q"], start_values=TIGHT)
            assert r.implicit is not None
            errors.append(position_error(r.time, r["plant.q"], ref, 1.0))
        explicit = sim.run(step_size=2e-5, record=["plant.q"], coupling="explicit")
    orders = np.log2(np.array(errors[:-1]) / np.array(errors[1:]))
    assert np.all(orders >= 2.6), (errors, orders)
    assert position_error(explicit.time, explicit["plant.q"], ref, 1.0) > 10 * errors[1]


def test_a_step_that_does_not_converge_is_halved(fmu_dir, references):
    """mems_tracking_Dd-0.4 at 20 us: the first step (the electrical layer of the charging capacitor)
    does not converge and is retried as halves (every FMU rolled back, the reference and the static
    controller included); the rows stay on the 20 us grid and follow the monolithic closed loop."""
    from emcosim.paper.reference_check import position_error, position_scale, samples_for
    s = read_scenario(ROOT / "scenarios" / "mems_tracking_Dd-0.4", fmu_dir=fmu_dir)
    r = simulate(s, stop_time=2e-4, step_size=2e-5, record=["plant.q"])
    assert r.implicit.halved >= 1
    assert r.implicit.steps > 10                              # the halves are steps of the iteration
    np.testing.assert_allclose(r.time, np.arange(11) * 2e-5, rtol=0, atol=1e-15)
    ref = references(s, 2e-4, samples_for(2e-4, 2e-5, 2001))
    assert position_error(r.time, r["plant.q"], ref, position_scale(s)) < 1e-3
    assert "did not converge and were taken as two halves" in r.implicit.summary()


def test_a_step_that_does_not_converge_after_its_halvings_ends_the_run_clearly(fmu_dir, monkeypatch):
    """Without halvings (or past the last) the run ends with what to do, and keeps its first row."""
    from emcosim.engine import implicit
    monkeypatch.setattr(implicit, "MAX_HALVINGS", 0)
    s = read_scenario(ROOT / "scenarios" / "mems_tracking_Dd-0.4", fmu_dir=fmu_dir)
    with pytest.raises(SimulationError, match="did not agree within .* take a shorter step") as info:
        simulate(s, stop_time=1e-4, step_size=2e-5, record=["plant.q"])
    assert len(info.value.result) >= 1


def test_the_scenario_annotation_sets_the_default(make, tmp_path):
    s = loop(make, k=-1000.0, stop_time=0.05)
    s.coupling = "implicit"
    folder = s.path.parent
    (folder / "SystemStructure.ssd").write_text(
        system_structure_xml(s, {c.name: str(c.source) for c in s.components}, 0.01))
    again = read_scenario(folder)
    assert again.coupling == "implicit"
    r = simulate(again, record=["plant.x"])
    np.testing.assert_allclose(r["plant.x"], radau(-10.0) ** np.arange(len(r)), rtol=1e-5, atol=1e-6)
    assert getattr(simulate(again, record=["plant.x"], coupling_order=1), "implicit", None) is None   # explicit
    text = (folder / "SystemStructure.ssd").read_text()
    (folder / "SystemStructure.ssd").write_text(text.replace('method="implicit"', 'method="iterative"'))
    with pytest.raises(ScenarioError, match='method="iterative" must be one of explicit, implicit'):
        read_scenario(folder)


def test_error_controlled_steps_recur_and_keep_their_jacobians(fmu_dir):
    """maglev_tracking_D-1_R0.82 with --tolerance 1e-3, coupled implicitly: the steps lie on the rungs
    h_max / 2^(k/4) (but the last macro step, stretched to the stop time), so sizes recur, and a size
    met before takes its kept Jacobian: fewer finite-difference Jacobians than twice the number of
    sizes (measured: 29 for 21 sizes; 81 when none is kept)."""
    from emcosim.engine import stepcontrol
    s = read_scenario(ROOT / "scenarios" / "maglev_tracking_D-1_R0.82", fmu_dir=fmu_dir)
    r = simulate(s, record=["plant.q"], tolerance=1e-3, coupling="implicit")
    h_max = (s.stop_time - s.start_time) / 50
    rungs = np.log(h_max / np.diff(r.time)) / np.log(stepcontrol.RUNG)
    off = np.flatnonzero(np.abs(rungs - np.round(rungs)) > 1e-6)
    assert len(off) <= 2 and np.all(off >= len(rungs) - 2), (off, rungs[off])
    sizes = len(np.unique(np.round(rungs[:-2])))
    assert r.implicit.jacobians < 2 * sizes, (r.implicit, sizes)
