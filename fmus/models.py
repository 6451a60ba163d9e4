"""The seven emcosim FMUs, one row each: which adapter, which components/ model, what the FMU shows on its
own (its start values and DefaultExperiment). build.py builds one FMU per row; `slave_class` makes the
row's slave class, which the FMU's generated script binds to the model identifier.

Default experiments (docs/fmus.md, "Run with fmpy"):
- MEMS: the open-loop response to a constant 25 V from the paper's initial state (q, p, x_e) = (15e-6 m,
  0, 0): the electrode is pulled to its static equilibrium and rings (damping ratio ~0.01); <= 1000 steps,
  so that fmpy keeps the step as its output interval.
- Maglev: the paper gives no maglev initial state (erratum 7): the equilibrium at q = 0.0025 m (half way to
  the magnet at c = 0.005 m), eta = (0.0025, 0, sqrt(2 k b)); with the coil voltage held at 0 V the flux
  decays and the ball falls (the open loop is unstable).
- the controllers: u for constant start inputs (the MEMS initial state, the maglev equilibrium);
- Reference: the paper's MEMS tracking reference q* = 0.05 + 0.05 sin(30 t) (eq. csim), kind 1.
"""
from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

from components import maglev
from components.catalog import DEVICES

from .controller import ControllerSlave
from .plant import PlantSlave
from .reference import ReferenceSlave

MAGLEV_EQUILIBRIUM = tuple(float(v) for v in maglev.Maglev().equilibrium([0.0025]))


@dataclass(frozen=True)
class Model:
    """One FMU: its adapter class and the class attributes the adapter reads."""

    adapter: type
    summary: str
    experiment: tuple[float, float, float]                   # start, stop, step of the DefaultExperiment
    attributes: dict[str, Any] = field(default_factory=dict)


MODELS: dict[str, Model] = {
    "MEMS": Model(PlantSlave, "MEMS optical switch (paper Section 7.1): input voltage u, outputs q, p, x_e and "
                  "the energy H", (0.0, 9e-4, 1e-6),
                  {"device": DEVICES["MEMS"], "initial_state": (15e-6, 0.0, 0.0), "input_start": 25.0}),
    "Maglev": Model(PlantSlave, "magnetic levitation system (paper Section 7.2): input voltage u, outputs q, p, "
                    "x_e and the energy H", (0.0, 0.5, 1e-3),
                    {"device": DEVICES["Maglev"], "initial_state": MAGLEV_EQUILIBRIUM, "input_start": 0.0}),
    "MEMS_Proposition1": Model(ControllerSlave, "Proposition 1 (eq. c1) for the MEMS optical switch: u from "
                               "(q, p, x_e)", (0.0, 1e-3, 1e-4),
                               {"device": DEVICES["MEMS"], "design": "Proposition1", "input_start": (15e-6, 0.0, 0.0)}),
    "MEMS_Theorem2": Model(ControllerSlave, "Theorem 2 (eq. u1-track) for the MEMS optical switch: u from "
                           "(q, p, x_e) and the reference jet", (0.0, 1e-3, 1e-4),
                           {"device": DEVICES["MEMS"], "design": "Theorem2",
                             "input_start": (15e-6, 0.0, 0.0, 3e-5, 0.0, 0.0, 0.0)}),
    "Maglev_Proposition2": Model(ControllerSlave, "Proposition 2 (eq. u2) for the magnetic levitation system: u "
                                 "from (q, p, x_e)", (0.0, 0.1, 1e-2),
                                 {"device": DEVICES["Maglev"], "design": "Proposition2", "input_start": MAGLEV_EQUILIBRIUM}),
    "Maglev_Theorem3": Model(ControllerSlave, "Theorem 3 (eq. tracker2) for the magnetic levitation system: u "
                             "from (q, p, x_e) and the reference jet", (0.0, 0.1, 1e-2),
                             {"device": DEVICES["Maglev"], "design": "Theorem3",
                               "input_start": MAGLEV_EQUILIBRIUM + (0.0025, 0.0, 0.0, 0.0)}),
    "Reference": Model(ReferenceSlave, "reference generator: constant, sinusoid or smooth transition; outputs the "
                       "jet q*, q*', q*'', q*'''", (0.0, 0.5, 1e-3)),
}


def slave_class(identifier: str) -> type:
    """The slave class of the FMU `identifier`: its adapter with the row's attributes."""
    model = MODELS[identifier]
    return type(identifier, (model.adapter,), {"model_identifier": identifier, "summary": model.summary,
                                               "experiment": model.experiment, **model.attributes,
                                               "__module__": __name__})
