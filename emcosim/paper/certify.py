"""`emcosim certify SCENARIO`: the paper's guarantees for a scenario's controller design.

Reads the scenario's controller, plant and reference parameters, builds the same components objects
the FMUs use (components.catalog) and evaluates components.certificates over a tube around the
scenario's reference (physics-aware: not part of the master's core).
"""
from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from components import catalog, certificates
from components.controller import Controller
from components.references import Constant, Reference

from ..engine.ssd import Scenario, read_scenario


@dataclass
class Design:
    controller: Controller
    controller_name: str
    reference: Reference | None
    eta0: np.ndarray | None
    horizon: float


def _values(component) -> dict:
    return {name: p.value for name, p in component.parameters.items()}


def design_from_scenario(scenario: Scenario) -> Design:
    """The controller (with its plant model), reference, initial plant state and horizon of a scenario."""
    ctrl = ref = eta0 = None
    name = ""
    for comp in scenario.components:
        model = Path(comp.source).stem
        values = _values(comp)
        if model in catalog.GAINS:
            ctrl, name = catalog.controller(model, values), model
        elif model == "Reference":
            kind = values.pop("kind", 1)
            ref = catalog.reference(int(kind), values)
        elif model in catalog.PLANTS:
            eta0 = np.array([values.get(k, np.nan) for k in ("q_0", "p_0", "x_e_0")], dtype=float)
    if ctrl is None:
        raise ValueError(f"{scenario.path}: no controller FMU of this suite ({', '.join(catalog.GAINS)}) in the scenario")
    if not ctrl.tracking:
        ref = None
    horizon = 0.0 if (ref is None or isinstance(ref, Constant)) else float(scenario.stop_time or 0.0)
    if ctrl.tracking and ref is None:
        raise ValueError(f"{scenario.path}: {name} tracks a reference, but the scenario has no Reference FMU")
    return Design(ctrl, name, ref, None if eta0 is None or np.any(np.isnan(eta0)) else eta0, horizon)


def certify_scenario(path: str | Path, radius: float = 0.1, include_start: bool = False,
                     scenario_dirs: list[Path] | None = None) -> certificates.Certificate:
    """Certificate of a scenario's design over a tube of relative half-width `radius` around its
    reference (over the scenario's horizon); with include_start the tube also contains eta(0)."""
    scenario = read_scenario(path, scenario_dirs)
    d = design_from_scenario(scenario)
    cert = certificates.certify(d.controller, d.reference, d.horizon, radius=radius,
                                eta0=d.eta0 if include_start else None)
    cert.controller = f"{d.controller_name} ({d.controller.name}) in scenario {scenario.name}"
    if d.eta0 is not None:
        target0 = d.controller.target(None if d.reference is None else d.reference.jet(0.0))
        inside = bool(np.all(np.abs(d.eta0 - target0) <= np.asarray(cert.neighbourhood["half_widths"])))
        cert.neighbourhood["initial state inside"] = inside
        cert.neighbourhood["description"] += ("; the scenario's initial state is inside it" if inside else
                                              "; the scenario's initial state is OUTSIDE it (use --include-start)")
    return cert
