"""Adapter: a static controller of components/ as an FMI 2.0 slave (Co-Simulation and Model Exchange: no states).

Variables: the plant's physical parameters (the controller's model of the plant, same names as in the
plant FMU) and the gains of components.catalog.GAINS (parameters); the plant outputs q, p, x_e and,
for tracking, the reference jet q_star, q_star_dot, q_star_ddot, q_star_dddot (inputs); u (output).
The controller is built by components.catalog.controller. u depends on the inputs only
(direct feedthrough, no state): it is computed when read, so a master reads it right after setting the
inputs, without a one-step delay. doStep only checks that u could be computed.
FMI 2.0 derivatives: the exact Jacobian of u with respect to the inputs (fmi2GetDirectionalDerivative)
and du/dt by the chain rule from the input derivatives the master set (fmi2GetRealOutputDerivatives,
order 1; an input without a derivative counts as constant; derivatives of order 2 and above, which a
master may send, are accepted and dropped: du/dt needs the first ones only), both from
components.controller.Controller.u_derivative (complex step of the law).
"""
from __future__ import annotations

import math
from types import ModuleType
from typing import ClassVar

import numpy as np

from components import catalog, certificates
from components.controller import Controller
from components.ph_plant import Jet
from components.references import JET_VARIABLES as JET

from .pythonfmu_workarounds import Fmi2Status
from .slave import EMSlave

STATE_NAMES = ("q", "p", "x_e")


class ControllerSlave(EMSlave):
    plant_module: ClassVar[ModuleType]                          # components.mems or components.maglev
    input_start: ClassVar[tuple[float, ...]]                    # q, p, x_e (and the jet, if tracking)
    # FMI 2.0 derivatives (hooks at the end of the class)
    can_interpolate_inputs = True                               # accepts input derivatives (for du/dt)
    input_derivative_orders_used = 1                            # any order accepted, orders >= 2 dropped
    max_output_derivative_order = 1
    provides_directional_derivative = True

    def declare(self) -> None:
        module = self.plant_module
        self.tracking = catalog.TRACKING[self.model_identifier]
        self.gains = catalog.GAINS[self.model_identifier]
        for p in module.PARAMETERS.values():
            self.parameter(p.name, p.default, p.unit, f"controller's model of the plant: {p.description}")
        for p in self.gains.values():
            self.parameter(p.name, p.default, p.unit, p.description)
        self.parameter("strict", 0, None, "1: refuse to initialize when the parameters violate a condition of the "
                       "controller's proposition or theorem (components.certificates.design_checks); "
                       "0: log a warning and run", integer=True)
        inputs = [(n,) + module.STATES[n] for n in STATE_NAMES] + (list(JET) if self.tracking else [])
        for (name, unit, description), start in zip(inputs, self.input_start):
            self.input(name, start, unit, description)
        self.input_names = [i[0] for i in inputs]
        self.output("u", module.INPUT[1], module.INPUT[2], self.u_value, self.input_names,
                    self.input_names + list(module.PARAMETERS) + list(self.gains))
        self.controller: Controller | None = None
        self._u: float | None = None
        self._u_error = ""

    def make_controller(self) -> Controller:
        """The components controller of the current parameter values (a ValueError names the parameter)."""
        names = list(self.plant_module.PARAMETERS) + list(self.gains)
        return catalog.controller(self.model_identifier, {n: self.values[n] for n in names})

    def initialize(self) -> None:
        controller = self.make_controller()
        strict = self.values["strict"]                               # (a ValueError names the parameter)
        if strict not in (0, 1):
            raise ValueError(f"parameter strict = {strict} violates strict in {{0, 1}}")
        failed = [c for c in certificates.design_checks(controller, self.input_jet(controller))
                  if c.verdict == certificates.FAILS]
        if failed:
            message = (f"{self.model_identifier}: the parameters violate {controller.name}'s conditions: "
                       + "; ".join(f"{c.name} ({', '.join(f'{k} = {v:.4g}' for k, v in c.numbers.items())})"
                                   + (f" [{c.note}]" if c.note else "") for c in failed))
            if strict:
                raise ValueError(message + " (strict = 1)")
            self.log(message + "; running anyway (strict = 0)", Fmi2Status.warning)
        self.controller, self._u = controller, None

    def input_jet(self, controller: Controller) -> Jet | None:
        """The reference jet at the inputs (tracking controllers), or None if it is not feasible."""
        if not self.tracking:
            return None
        jet = Jet(*(np.array([self.values[name]]) for name, _, _ in JET))
        try:
            controller.target(jet)
        except ValueError:
            return None
        return jet

    # ---- the output -----------------------------------------------------------------------------
    def inputs_changed(self) -> None:
        self._u = None

    def u_value(self) -> float:
        """u at the current inputs, computed once per input change (before initialization, when parameters
        may still change, at every call)."""
        if self._u is None or self.controller is None:
            self._u, self._u_error = self.compute_u()
            if self._u_error:
                self.log_error(self._u_error)
        return self._u

    def compute_u(self) -> tuple[float, str]:
        """(u, "") or (nan, reason)."""
        v = self.values
        x = [v[name] for name in self.input_names]             # q, p, x_e (and the jet)
        if not math.isfinite(sum(x)):                          # some input is nan or inf (or the sum overflows)
            for name, value in zip(self.input_names, x):
                if not math.isfinite(value):
                    return math.nan, f"{self.model_identifier}: input {name} = {value} is not finite"
        try:
            controller = self.controller
            if controller is None:                       # before initialization: from the current values
                controller = self.make_controller()
            if controller.scalars is not None:                # one-DOF plant: the law in scalars
                u = float(controller.u_scalar(x[0], x[1], x[2], x[3:] if self.tracking else None))
            else:
                jet = Jet(*(np.array([xi]) for xi in x[3:])) if self.tracking else None
                u = float(controller.u(np.array(x[:3]), jet)[0])
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

    # ---- FMI 2.0 derivatives (contract: derivatives.DerivativeFunctions) --------------------------------
    def u_derivative(self, directions: list[float]) -> float:
        """sum_j du/d(input_j) directions_j at the current inputs (ValueError with the reason)."""
        values = self.values
        x = [values[name] for name in self.input_names]
        if not math.isfinite(sum(x)):                          # some input is nan or inf (or the sum overflows)
            for name, value in zip(self.input_names, x):
                if not math.isfinite(value):
                    raise ValueError(f"input {name} = {value} is not finite")
        controller = self.controller if self.controller is not None else self.make_controller()
        return float(controller.u_derivative(x, directions))

    def output_derivative(self, name: str, order: int) -> float:
        """du/dt = (du/d inputs) (d inputs/dt), the input rates as set by the master (0 where none)."""
        rates = self.input_derivatives
        return self.u_derivative([rates[n].get(1, 0.0) if n in rates else 0.0 for n in self.input_names])

    def directional_derivative(self, unknowns: list[str], knowns: list[str], seeds: list[float]) -> list[float]:
        """sum_j du/d(knowns_j) seeds_j for each unknown (u is the only output)."""
        index = {n: i for i, n in enumerate(self.input_names)}
        v = [0.0] * len(self.input_names)
        for name, seed in zip(knowns, seeds):
            v[index[name]] += seed
        return [self.u_derivative(v)] * len(unknowns)
