"""Higher-order coupling (emcosim/engine/coupling.py) on the C toy FMUs of tests/fixtures/toy_derivatives.c.

Independent truths: the loop of ToyDynamic (x' = u, exact for a polynomial input) and ToyStatic
(u = k x) is x' = k x; a master that hands over u and its first K derivatives makes the exact
recursion x_{n+1} = x_n sum_{j<=K+1} (k h)^j / j! (the Taylor polynomial of e^{kh}), whose global
error against e^{kt} is O(h^(K+1)). A wrong order of the calls (e.g. the plant's x' read before u
is set at the same instant) or a derivative not scaled by a connection's factor gives another
recursion."""
from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest
from fmpy import extract, read_model_description
from fmpy.fmi2 import FMU2Slave

from emcosim.engine import coupling, vendor
from emcosim.engine.errors import ScenarioError
from emcosim.engine.master import Simulation, declared_orders, simulate
from emcosim.engine.plan import make_plan
from emcosim.engine.ssd import read_scenario
from tests.helpers import DYNAMIC, SINE, STATIC, loop


def taylor(kh: float, K: int) -> float:
    return sum(kh ** j / math.factorial(j) for j in range(K + 2))


@pytest.mark.parametrize("K", [0, 1, 2, 3])
def test_derivatives_give_the_taylor_recursion(make, K):
    r = simulate(loop(make), coupling_order=K, record=["plant.x", "plant.u"])
    n = np.arange(len(r))
    np.testing.assert_allclose(r["plant.x"], taylor(-0.01, K) ** n, rtol=1e-13)
    np.testing.assert_allclose(r["plant.u"], -r["plant.x"], rtol=1e-15)


def test_default_order_is_what_both_ends_declare(make):
    full = simulate(loop(make, order=3), record=["plant.x"])            # both ends: order 3
    np.testing.assert_allclose(full["plant.x"], taylor(-0.01, 3) ** np.arange(len(full)), rtol=1e-13)
    none = simulate(loop(make, interpolate=False), record=["plant.x"])  # no input interpolation: hold
    np.testing.assert_array_equal(none["plant.x"], _zoh(-1.0, 0.01, 100))


def _zoh(k: float, h: float, n: int) -> np.ndarray:
    """x_{i+1} = x_i + (k x_i) h_i over the master's steps h_i = (i + 1) h - i h, in the same
    floating-point operations as the toy FMUs."""
    x = [1.0]
    for i in range(n):
        x.append(x[-1] + (k * x[-1]) * ((i + 1) * h - i * h))
    return np.array(x)


def test_one_order_more_by_extrapolation(make):
    """The controller gives du/dt only, the plant takes u'' too: the master passes the backward
    difference u''_n = (u'_n - u'_{n-1}) / h (0 at the first point) while it predicts u' better than
    holding it, and the global error falls at order 3 instead of 2."""
    k, h, n = -1.0, 0.01, 100
    r = simulate(loop(make, order=1), record=["plant.x"])
    assert r.coupling_orders["plant.u"] == 2
    x, du_prev = [1.0], None
    for i in range(n):
        u = k * x[-1]
        du = k * u                                       # y' = k x', x' = u (set at the same instant)
        d2u = 0.0 if i < 1 else (du - du_prev) / h
        x.append(x[-1] + h * u + h * h / 2 * du + h ** 3 / 6 * d2u)
        du_prev = du
    np.testing.assert_allclose(r["plant.x"], x, rtol=1e-12)
    errors = []
    for step in (0.04, 0.02, 0.01):
        r = simulate(loop(make, order=1, step_size=step), record=["plant.x"])
        errors.append(np.max(np.abs(r["plant.x"] - np.exp(-r.time))))
    orders = np.log2(np.array(errors[:-1]) / np.array(errors[1:]))
    assert np.all(orders > 2.7), (errors, orders)
    r = simulate(loop(make, order=1), coupling_order=1, record=["plant.x"])   # asked: no more than 1
    np.testing.assert_allclose(r["plant.x"], taylor(-0.01, 1) ** np.arange(len(r)), rtol=1e-13)


def test_zero_order_is_bit_identical_to_the_hold(make):
    r = simulate(loop(make), coupling_order=0, record=["plant.x"])
    np.testing.assert_array_equal(r["plant.x"], _zoh(-1.0, 0.01, 100))


def test_connection_factor_scales_the_derivatives(make):
    """u = -1 * y with y = +x: the derivatives must be scaled by the factor as the values are."""
    r = simulate(loop(make, k=1.0, factor=-1.0), coupling_order=2, record=["plant.x"])
    np.testing.assert_allclose(r["plant.x"], taylor(-0.01, 2) ** np.arange(len(r)), rtol=1e-13)


def test_feedthrough_chain_gets_derivatives_in_dependency_order(make):
    """Tracking: ref (ToySine r = sin t) and plant x feed ctrl (y = k (r - x)), which feeds the plant.
    The controller's y' = k (r' - x') needs the plant's x' = y (of the same instant: u set first)
    and the source's r' set on its inputs before it is read."""
    k, h, n = 5.0, 0.01, 100
    s = make([("ref", "sine", SINE, True, 3), ("plant", "dynamic", DYNAMIC, True, 3), ("ctrl", "static", STATIC, True, 3)],
             [("ref.y", "ctrl.u1"), ("plant.x", "ctrl.u2"), ("ctrl.y", "plant.u")],
             {"ctrl": {"k1": k, "k2": -k}, "plant": {"x0": 0.0}}, stop_time=n * h, step_size=h)
    r = simulate(s, coupling_order=1, record=["plant.x"])
    x = [0.0]
    for i in range(n):
        t = i * h
        y = k * (math.sin(t) - x[-1])
        dy = k * (math.cos(t) - y)                       # x' = y: the input value set at t
        x.append(x[-1] + h * y + h * h / 2 * dy)
    np.testing.assert_allclose(r["plant.x"], x, rtol=1e-12, atol=1e-15)


@pytest.mark.parametrize("K", [0, 1, 2])
def test_global_error_falls_at_order_K_plus_1(make, K):
    errors = []
    for h in (0.04, 0.02, 0.01):
        r = simulate(loop(make, step_size=h), coupling_order=K, record=["plant.x"])
        errors.append(np.max(np.abs(r["plant.x"] - np.exp(-r.time))))
    orders = np.log2(np.array(errors[:-1]) / np.array(errors[1:]))
    assert np.all(np.abs(orders - (K + 1)) < 0.15), (errors, orders)


def test_a_target_refusing_an_order_is_coupled_one_order_lower(make):
    """FMI 2.0 does not declare the highest input derivative order: the plant accepts only order 1
    (fmi2Error for order 2), so the master restores it and couples at order 1 (and says so)."""
    s = make([("plant", "dynamic", DYNAMIC, True, 3), ("ctrl", "static", STATIC, True, 3)],
             [("plant.x", "ctrl.u1"), ("ctrl.y", "plant.u")],
             {"ctrl": {"k1": -1.0}, "plant": {"x0": 1.0, "input_order": 1.0}})
    r = simulate(s, record=["plant.x"])
    np.testing.assert_allclose(r["plant.x"], taylor(-0.01, 1) ** np.arange(len(r)), rtol=1e-13)
    assert r.coupling_orders == {"ctrl.u1": 3, "plant.u": 1} and r.warnings == []
    assert simulate(s, coupling_order=2, record=["plant.x"]).coupling_orders["plant.u"] == 1


def _annotated(order_used: str) -> str:
    """emcosim's vendor annotation (emcosim/engine/vendor.py) with orderUsed as given (no quoting)."""
    return f'<Tool name="org.emcosim"><InputDerivatives orderUsed="{order_used}"/></Tool>'


def _loop_declaring(make, vendor: str | None, input_order: float = 3.0):
    """plant (order 3 accepted unless input_order says less; carrying `vendor`) and ctrl in the x' = -x loop."""
    return make([("plant", "dynamic", DYNAMIC, True, 3, vendor), ("ctrl", "static", STATIC, True, 3)],
                [("plant.x", "ctrl.u1"), ("ctrl.y", "plant.u")],
                {"ctrl": {"k1": -1.0}, "plant": {"x0": 1.0, "input_order": input_order}})


def test_a_target_declaring_the_order_it_uses_gets_no_order_above_it(make):
    """FMI 2.0 cannot say which input derivative order an FMU uses; emcosim's vendor annotation can. The
    plant takes every order but declares orderUsed="1": the master couples it at order 1 from the start
    (no probe needed): the same numbers, bit for bit, as the plant that refuses order 2 and is probed."""
    declared = _loop_declaring(make, _annotated("1"))
    with Simulation(declared) as sim:
        assert declared_orders(sim.instances) == {"plant": 1}
        r = sim.run(record=["plant.x"])
    assert r.coupling_orders == {"ctrl.u1": 3, "plant.u": 1} and r.warnings == []
    probed = simulate(_loop_declaring(make, None, input_order=1.0), record=["plant.x"])
    assert probed.coupling_orders == r.coupling_orders
    np.testing.assert_array_equal(r["plant.x"], probed["plant.x"])
    np.testing.assert_allclose(r["plant.x"], taylor(-0.01, 1) ** np.arange(len(r)), rtol=1e-13)
    # the plant refuses order 2 too: it never sees it (its refusal would end the run or be probed)
    strict = simulate(_loop_declaring(make, _annotated("1"), input_order=1.0), record=["plant.x"])
    np.testing.assert_array_equal(strict["plant.x"], r["plant.x"])
    assert simulate(_loop_declaring(make, _annotated("0")), record=["plant.x"]).coupling_orders["plant.u"] == 0


@pytest.mark.parametrize("order_used, problem", [
    ("x", "orderUsed='x' is not an integer >= 0"), ("-1", "orderUsed='-1' is not an integer >= 0"),
    ("1.5", "orderUsed='1.5' is not an integer >= 0"), ("", "orderUsed='' is not an integer >= 0"),
    ("\u00b2", "is not an integer >= 0"), ("1" * 5000, None), ("0" * 5000 + "2", None)])
def test_a_malformed_order_used_is_ignored_with_a_warning(make, order_used, problem):
    """An orderUsed that is not an integer >= 0 is ignored (the master probes as without it) and said
    in the result's warnings; a huge one limits nothing; none of them stops the run."""
    s = _loop_declaring(make, _annotated(order_used), input_order=2.0)
    r = simulate(s, record=["plant.x"])
    assert r.coupling_orders == {"ctrl.u1": 3, "plant.u": 2}     # the plant refuses 3: probed (or declared) 2
    np.testing.assert_allclose(r["plant.x"], taylor(-0.01, 2) ** np.arange(len(r)), rtol=1e-13)
    if problem is None:
        assert r.warnings == []
    else:
        assert len(r.warnings) == 1 and r.warnings[0].startswith("plant: ") and problem in r.warnings[0], r.warnings
        assert "ignored" in r.warnings[0]


def test_other_vendor_annotations_and_a_tool_without_order_are_no_declaration(make):
    """Another tool's annotation, or emcosim's without <InputDerivatives>, declares nothing (no warning);
    <InputDerivatives> without orderUsed is a malformed declaration: a warning."""
    others = '<Tool name="com.example"><InputDerivatives orderUsed="0"/></Tool><Tool name="org.emcosim"><Other/></Tool>'
    r = simulate(_loop_declaring(make, others), record=["plant.x"])
    assert r.coupling_orders == {"ctrl.u1": 3, "plant.u": 3} and r.warnings == []
    r = simulate(_loop_declaring(make, '<Tool name="org.emcosim"><InputDerivatives/></Tool>'), record=["plant.x"])
    assert r.coupling_orders["plant.u"] == 3 and len(r.warnings) == 1 and "has no orderUsed" in r.warnings[0]


def test_an_unreadable_annotation_source_is_a_warning_not_a_crash(tmp_path):
    """vendor.input_order_used never raises: a missing file, a file that is not a zip archive, an archive
    without modelDescription.xml, broken XML are each (None, a warning naming the file)."""
    import zipfile
    cases = {"missing.fmu": None, "text.fmu": b"not a zip", "empty.fmu": {}, "broken.fmu": {"modelDescription.xml": b"<fmi"}}
    for name, content in cases.items():
        path = tmp_path / name
        if isinstance(content, bytes):
            path.write_bytes(content)
        elif isinstance(content, dict):
            with zipfile.ZipFile(path, "w") as z:
                for entry, data in content.items():
                    z.writestr(entry, data)
        order, warning = vendor.input_order_used(path)
        assert order is None and warning.startswith(f"{name}: ") and warning.endswith("ignored"), warning


def test_connection_orders_follow_the_declarations(make):
    """Order of a connection: the source's maxOutputDerivativeOrder, capped by the orders of the
    inputs a feedthrough output depends on, 0 unless the target interpolates, at most the order asked."""
    s = make([("ref", "sine", SINE, True, 3), ("plant", "dynamic", DYNAMIC, True, 1), ("ctrl", "static", STATIC, False, 2)],
             [("ref.y", "ctrl.u1"), ("plant.x", "ctrl.u2"), ("ctrl.y", "plant.u")])
    with Simulation(s) as sim:
        plan = make_plan(sim.scenario, sim.instances, sim.connections, None)
        orders = coupling.connection_orders(sim.instances, sim.connections, plan.level, plan.depends)
        assert orders == {"ctrl.u1": 0, "ctrl.u2": 0, "plant.u": 0}      # ctrl does not interpolate
    s = make([("ref", "sine", SINE, True, 3), ("plant", "dynamic", DYNAMIC, True, 1), ("ctrl", "static", STATIC, True, 2)],
             [("ref.y", "ctrl.u1"), ("plant.x", "ctrl.u2"), ("ctrl.y", "plant.u")])
    with Simulation(s) as sim:
        plan = make_plan(sim.scenario, sim.instances, sim.connections, None)
        orders = coupling.connection_orders(sim.instances, sim.connections, plan.level, plan.depends)
        assert orders == {"ctrl.u1": 3, "ctrl.u2": 1, "plant.u": 1}      # y' only: x gives order 1
        assert coupling.connection_orders(sim.instances, sim.connections, plan.level, plan.depends, 0) == \
            {"ctrl.u1": 0, "ctrl.u2": 0, "plant.u": 0}
    with pytest.raises(ScenarioError, match="coupling_order 7: must be an integer from 0 to 3"):
        simulate(s, coupling_order=7)                     # refused before any FMU is loaded (options.check)


@pytest.mark.parametrize("name", ["maglev_tracking_D-1_R2.82", "maglev_regulation_prop2"])
def test_controllers_get_the_input_derivative_order_they_use(fmu_dir, monkeypatch, name):
    """The controllers declare orderUsed="1" (they drop higher orders): the master couples their inputs at
    order 1 from the start instead of passing the plant's and the reference's higher orders, for the same
    numbers, bit for bit, as with the annotation ignored (the behaviour before it). (The MEMS tracking
    scenarios couple implicitly: their controllers get order 1 either way.)"""
    s = read_scenario(Path(__file__).resolve().parents[1] / "scenarios" / name, fmu_dir=fmu_dir)
    stop = 200 * s.step_size
    declared = simulate(s, stop_time=stop)
    monkeypatch.setattr(vendor, "input_order_used", lambda fmu: (None, ""))
    ignored = simulate(s, stop_time=stop)
    controller = {k: v for k, v in declared.coupling_orders.items() if k.startswith("controller.")}
    assert controller and set(controller.values()) == {1}
    assert max(v for k, v in ignored.coupling_orders.items() if k.startswith("controller.")) > 1
    assert declared.coupling_orders["plant.u"] == ignored.coupling_orders["plant.u"] >= 1
    assert declared.columns == ignored.columns and declared.warnings == ignored.warnings == []
    np.testing.assert_array_equal(np.array(declared.rows), np.array(ignored.rows))


def test_fmus_without_derivatives_run_as_a_plain_hold_master(fmu_dir, tmp_path):
    """A paper scenario with a zero-order hold equals, bit for bit, an independent fixed-step
    master written here with fmpy's FMU2Slave (levels: plant and reference outputs, then the
    controller's u at the same instant; inputs held over the step)."""
    name, h, n = "maglev_tracking_D-1_R2.82", 5e-4, 200
    s = read_scenario(Path(__file__).resolve().parents[1] / "scenarios" / name, fmu_dir=fmu_dir)
    ours = simulate(s, stop_time=n * h, step_size=h, coupling_order=0, record=["plant.q", "plant.p", "plant.x_e", "controller.u"])
    theirs = _plain_master(s, n, h, tmp_path)
    for column in ("plant.q", "plant.p", "plant.x_e", "controller.u"):
        np.testing.assert_array_equal(ours[column], theirs[column], err_msg=column)


def _plain_master(s, n: int, h: float, tmp_path: Path) -> dict[str, list[float]]:
    slaves, vr = {}, {}
    for comp in s.components:
        md = read_model_description(str(comp.source))
        folder = extract(str(comp.source), str(tmp_path / comp.name))
        slave = FMU2Slave(guid=md.guid, unzipDirectory=folder, modelIdentifier=md.coSimulation.modelIdentifier,
                          instanceName=comp.name)
        slave.instantiate()
        slave.setupExperiment(startTime=0.0)
        vr[comp.name] = {v.name: v.valueReference for v in md.modelVariables}
        for p in comp.parameters.values():
            (slave.setInteger if p.type == "Integer" else slave.setReal)([vr[comp.name][p.name]], [p.value])
        slave.enterInitializationMode()
        slaves[comp.name] = slave
    by_level = [[c for c in s.connections if c.start_element != "controller"],
                [c for c in s.connections if c.start_element == "controller"]]

    def resolve():
        for conns in by_level:
            for c in conns:
                value = slaves[c.start_element].getReal([vr[c.start_element][c.start_connector]])[0]
                slaves[c.end_element].setReal([vr[c.end_element][c.end_connector]], [value])

    resolve()
    for slave in slaves.values():
        slave.exitInitializationMode()
    out = {k: [] for k in ("plant.q", "plant.p", "plant.x_e", "controller.u")}
    for i in range(n + 1):
        resolve()
        for full in out:
            comp, _, var = full.partition(".")
            out[full].append(slaves[comp].getReal([vr[comp][var]])[0])
        if i < n:
            t, t_next = i * h, (i + 1) * h
            for slave in slaves.values():
                slave.doStep(t, t_next - t)
    for slave in slaves.values():
        slave.terminate()
        slave.freeInstance()
    return out


def test_a_loop_stiffer_than_the_step_is_held_not_extrapolated(fmu_dir):
    """MEMS regulation with rbar_e = 100.5 Ohm (K_e != 0: du/dx_e ~ 3e9 V/Wb, a loop far stiffer than
    the 4 us step): passing the controller's du/dt drove the plant out of its domain within a few
    steps at any step down to 0.1 us (the gap closed), where the zero-order hold ran. The guard
    (coupling._Guard) holds u there, and the run follows the monolithic closed loop."""
    from emcosim.engine.ssd import read_scenario
    from emcosim.paper.reference_check import monolithic, position_error, position_scale, samples_for
    s = read_scenario(Path(__file__).parents[1] / "scenarios" / "mems_regulation_Dd0", fmu_dir=fmu_dir)
    s.component("controller").parameters["rbar_e"].value = 100.5     # for the run and the reference
    t_end, h = 1e-3, 4e-6
    r = simulate(s, stop_time=t_end, step_size=h, record=["plant.q"])
    assert r.time[-1] == pytest.approx(t_end)
    ref = monolithic(s, stop_time=t_end, n_samples=samples_for(t_end, h, 1001))
    assert position_error(r.time, r["plant.q"], ref, position_scale(s)) < 1e-3
