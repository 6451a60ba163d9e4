"""Adapter: a static controller of components/ as an FMI 2.0 co-simulation slave.

Variables: the plant's physical parameters (the controller's model of the plant, same names as in the
plant FMU) and the gains of components.catalog.GAINS (parameters); the plant outputs q, p, x_e and,
for tracking, the reference jet q_star, q_star_dot, q_star_ddot, q_star_dddot (inputs); u (output).
The controller is built by components.catalog.controller. u depends on the inputs only
(direct feedthrough, no state): it is computed when read, so a master reads it right after setting the
inputs, without a one-step delay. doStep only checks that u could be computed.
"""
from __future__ import annotations

import math
from types import ModuleType
from typing import ClassVar

import numpy as np

from components import catalog
from components.controller import Controller
from components.ph_plant import Jet
from em_fmu_framework import REFERENCE_JET as JET, EMSlave

STATE_NAMES = ("q", "p", "x_e")



class ControllerSlave(EMSlave):
    plant_module: ClassVar[ModuleType]                          # components.mems or components.maglev
    input_start: ClassVar[tuple[float, ...]]                    # q, p, x_e (and the jet, if tracking)

    def declare(self) -> None:
        module = self.plant_module
        self.tracking = catalog.TRACKING[self.model_identifier]
        self.gains = catalog.GAINS[self.model_identifier]
        for p in module.PARAMETERS.values():
            self.parameter(p.name, p.default, p.unit, f"controller's model of the plant: {p.description}")
        for p in self.gains.values():
            self.parameter(p.name, p.default, p.unit, p.description)
        inputs = [(n,) + module.STATES[n] for n in STATE_NAMES] + (list(JET) if self.tracking else [])
        for (name, unit, description), start in zip(inputs, self.input_start):
            self.input(name, start, unit, description)
        self.input_names = [i[0] for i in inputs]
        self.output("u", module.INPUT[1], module.INPUT[2], self.u_value, self.input_names,
                    self.input_names + list(module.PARAMETERS) + list(self.gains))
        self.controller: Controller | None = None
        self._u: float | None = None
        self._u_error = ""

    def initialize(self) -> None:
        names = list(self.plant_module.PARAMETERS) + list(self.gains)
        self.controller = catalog.controller(self.model_identifier, {n: self.values[n] for n in names})
        self._u = None                                               # (a ValueError names the parameter)

    # ---- the output -----------------------------------------------------------------------------
    def inputs_changed(self) -> None:
        self._u = None

    def u_value(self) -> float:
        if self._u is None:
            self._u, self._u_error = self.compute_u()
            if self._u_error:
                self.log_error(self._u_error)
        return self._u

    def compute_u(self) -> tuple[float, str]:
        """(u, "") or (nan, reason)."""
        v = self.values
        for name in self.input_names:
            if not math.isfinite(v[name]):
                return math.nan, f"{self.model_identifier}: input {name} = {v[name]} is not finite"
        try:
            controller = self.controller
            if controller is None:                       # before initialization: from the current values
                self.initialize()
                controller, self.controller = self.controller, None
            if controller.scalars is not None:                # one-DOF plant: the law in scalars
                jet = tuple(v[name] for name, _, _ in JET) if self.tracking else None
                u = float(controller.u_scalar(v["q"], v["p"], v["x_e"], jet))
            else:
                jet = Jet(*(np.array([v[name]]) for name, _, _ in JET)) if self.tracking else None
                u = float(controller.u(np.array([v["q"], v["p"], v["x_e"]]), jet)[0])
        except Exception as exc:                                      # noqa: BLE001 - reported, never raised
            return math.nan, f"{self.model_identifier}: u cannot be computed for the inputs {self.input_values()}: {exc}"
        if not math.isfinite(u):
            return math.nan, f"{self.model_identifier}: u = {u} for the inputs {self.input_values()}"
        return u, ""

    def input_values(self) -> dict:
        return {name: self.values[name] for name in self.input_names}

    def step(self, t: float, h: float) -> bool:
        u = self.u_value()
        if math.isfinite(u):
            return True
        self.log_error(f"{self._u_error} (doStep at t = {t:.9g} s)")
        return False
