"""The operating point a paper scenario's loop is linearized at (`emcosim linearize`, `emcosim.linearize`).

`reference_state(scenario, t)`: the state where the loop sits on its reference at time t, eta*(t) of
Definition 1 (eq. desired trajectory) for a tracking design, eta_d (eq. desired eq) for a regulation one:
`Controller.target` of the scenario's controller (certify.design_from_scenario reads it, its plant model and
its reference from the scenario's parameters), mapped onto the plant component's continuous states. The
engine's linearization (engine/linearization.py) knows no physics; this is where the paper says which state
that is.
"""
from __future__ import annotations

from pathlib import Path

from components import catalog

from ..engine.errors import ScenarioError
from ..engine.ssd import Scenario
from .certify import design_from_scenario


def reference_state(scenario: Scenario, t: float) -> dict[str, float]:
    """{"plant.q": q*(t), "plant.p": p*(t), "plant.x_e": x_e*(t), ...}: the controller's target at time t
    [the plant's units], named by the plant component (the one its output u feeds) and the plant's states
    (eta = (q, p, x_e), the order of the plant FMU's states). ScenarioError if the scenario has no
    controller of this suite or a reference that is not feasible at t."""
    try:
        design = design_from_scenario(scenario)
        jet = None if design.reference is None else design.reference.jet(float(t))
        eta = design.controller.target(jet)
    except ValueError as exc:
        raise ScenarioError(f"{scenario.path}: no reference state at t = {t:g} s: {exc}") from None
    controller = next(c.name for c in scenario.components if Path(c.source).stem == design.controller_name)
    fed = sorted({c.end_element for c in scenario.connections if c.start_element == controller})
    if len(fed) != 1:
        raise ScenarioError(f"{scenario.path}: the controller '{controller}' feeds {len(fed)} components "
                            f"({', '.join(fed) or 'none'}), not one plant: no reference state")
    device = catalog.DEVICES[catalog.CONTROLLER_PLANT[design.controller_name]]
    names = [f"{fed[0]}.{v.name}" for v in device.states]
    if len(names) != len(eta):
        raise ScenarioError(f"{scenario.path}: the plant model has {len(names)} state names for {len(eta)} states")
    return {name: float(value) for name, value in zip(names, eta)}

