"""`emcosim run --plot` for the suite's own scenarios: a run in the paper's quantities.

Panels, each on its own axis and in SI units with prefixes: q against its target q* (or q_d), the
tracking error q - q*, the input u, x_e against x_e*, and the stored energy H (the plant's output;
H_d is left out: its terms mix units, e.g. k_c/2 (z - L)^2). The target eta*(t) is the design's own
(components/), with the run's --set values applied. Scenarios whose FMUs are not this suite's get
the engine's figure of the recorded variables instead (emcosim.engine.plotting.variables_figure).
"""
from __future__ import annotations

from pathlib import Path

import numpy as np

from ..engine.errors import ScenarioError
from ..engine.plotting import OKABE_ITO, FigureSpec, Panel, Series, label, scale_unit
from ..engine.ssd import Scenario
from . import report


def run_figure(scenario: Scenario, result, start_values: dict | None = None) -> FigureSpec | None:
    """The figure of a run of a suite scenario, or None if the scenario is not one (no plant and
    controller FMU of this suite) or the result lacks the plant state or the input."""
    from components import catalog

    from ..devices.registry import register_fmu
    from ..engine.ssd import with_values
    from . import design_facts
    from .reproduce import plant_and_controller, run_from_result

    for comp in scenario.components:             # a device's FMUs (emcosim plant build) carry their description
        if Path(comp.source).stem not in catalog.GAINS and Path(comp.source).is_file():
            try:
                register_fmu(comp.source)
            except ValueError:                   # a description that does not register: the generic figure
                return None
    try:
        plant, controller = plant_and_controller(scenario)
    except ValueError:
        return None
    needed = [f"{plant}.q", f"{plant}.p", f"{plant}.x_e", f"{controller}.u"]
    if any(n not in result.columns for n in needed):
        return None
    values = {k: float(v) for k, v in (start_values or {}).items() if _is_number(v)}
    designed = with_values(scenario, values) if values else scenario
    try:
        run = run_from_result(scenario.name, scenario.name, designed, result)
        run.notes = [text for _, text in design_facts.violated_conditions(design_facts.design(designed))]
    except ValueError as exc:                  # a --set value the design refuses
        raise ScenarioError(f"--plot: {exc}") from None
    return figure(run, scenario.description or scenario.name)


def _is_number(v) -> bool:
    try:
        float(v)
        return True
    except (TypeError, ValueError):
        return False


def figure(run: report.Run, title: str) -> FigureSpec:
    """Panels q & q*, q - q*, u, x_e & x_e*, H (if recorded) of one run."""
    u = report.units(run.plant)
    tf, tu = scale_unit(run.t, "s")
    t = run.t * tf
    target = dict(color="black", style=(0, (1.5, 2.5)), width=1.0, zorder=3.0)
    main = dict(color=OKABE_ITO[0], width=1.4)
    panels = []
    f, unit = scale_unit(np.concatenate([run.q, run.eta_star[:, 0]]), u["q"])
    panels.append(Panel(label("position q", unit), [Series("q", t, run.q * f, **main),
                                                     Series("q* (target)", t, run.eta_star[:, 0] * f, **target)]))
    f, unit = scale_unit(run.e, u["q"])
    panels.append(Panel(label("error q - q*", unit), [Series("q - q*", t, run.e * f, color=OKABE_ITO[5], width=1.2)]))
    f, unit = scale_unit(run.u, u["u"])
    panels.append(Panel(label("input u", unit), [Series("u", t, run.u * f, color=OKABE_ITO[2], width=1.2)]))
    f, unit = scale_unit(np.concatenate([run.x_e, run.eta_star[:, 2]]), u["x_e"])
    panels.append(Panel(label("electrical state x_e", unit), [Series("x_e", t, run.x_e * f, **main),
                                                               Series("x_e* (target)", t, run.eta_star[:, 2] * f, **target)]))
    if run.H is not None:
        f, unit = scale_unit(run.H, u["H"])
        panels.append(Panel(label("stored energy H", unit), [Series("H", t, run.H * f, color=OKABE_ITO[3], width=1.2)]))
    note = "; ".join(run.notes)
    return FigureSpec(title, panels, label("time t", tu), legend="right", note=note)
