"""Adapter: a static controller of components/ as an FMI 2.0 slave (Co-Simulation and Model Exchange: no states).

Variables (from the class's components.device.Device and its design): the plant's physical parameters
(the controller's model of the plant, same names as in the plant FMU) and the design's gains
(parameters); the plant outputs q, p, x_e (n_m + n_m + n_e inputs under the device's names) and, for
tracking, the reference jet (Device.jet_names: q_star, q_star_dot, q_star_ddot, q_star_dddot for the
paper's plants); u (n_e outputs). The controller is built by Device.controller. u depends on the inputs only
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
from typing import ClassVar

import numpy as np

from components import certificates
from components.controller import Controller
from components.device import Device
from components.ph_plant import Jet
from components.references import JET_VARIABLES as JET

from .pythonfmu_workarounds import Fmi2Status
from .slave import EMSlave


class ControllerSlave(EMSlave):
    device: ClassVar[Device]                                    # the plant kind (components.device)
    design: ClassVar[str]                                       # one of device.designs: "Theorem2", ...
    input_start: ClassVar[tuple[float, ...]]                    # q, p, x_e (and the jet, if tracking)
    # FMI 2.0 derivatives (hooks at the end of the class)
    can_interpolate_inputs = True                               # accepts input derivatives (for du/dt)
    input_derivative_orders_used = 1                            # any order accepted, orders >= 2 dropped
    max_output_derivative_order = 1
    provides_directional_derivative = True

    def declare(self) -> None:
        device = self.device
        design = device.designs[self.design]
        self.tracking = design.tracking
        self.gains = design.gains
        self.scalar = device.n_m == 1 and device.n_e == 1       # one input u: the law in scalars where it can
        for p in device.parameters.values():
            self.parameter(p.name, p.default, p.unit, f"controller's model of the plant: {p.description}")
        for p in self.gains.values():
            self.parameter(p.name, p.default, p.unit, p.description)
        self.parameter("strict", 0, None, "1: refuse to initialize when the parameters violate a condition of the "
                       "controller's proposition or theorem (components.certificates.design_checks); "
                       "0: log a warning and run", integer=True)
        inputs = [(v.name, v.unit, v.description) for v in device.states]
        if self.tracking:
            jet = device.jet_names()
            # the paper's plants keep the Reference FMU's descriptions (components.references)
            same = [(n, u) for n, u, _ in jet] == [(n, u) for n, u, _ in JET]
            inputs += list(JET) if same else jet
        for (name, unit, description), start in zip(inputs, self.input_start, strict=True):
            self.input(name, start, unit, description)
        self.input_names = [i[0] for i in inputs]
        self.n = len(device.states)
        self.output_names = [v.name for v in device.u]
        self.output_index = {n: i for i, n in enumerate(self.output_names)}
        initial = self.input_names + list(device.parameters) + list(self.gains)
        if self.scalar:
            v = device.u[0]
            self.output(v.name, v.unit, v.description, self.u_value, self.input_names, initial)
        else:
            for i, v in enumerate(device.u):
                self.output(v.name, v.unit, v.description, (lambda i=i: self.u_vector()[i]), self.input_names, initial)
        self.controller: Controller | None = None
        self._u: float | None = None
        self._u_vector: tuple[float, ...] | None = None
        self._u_error = ""

    def make_controller(self) -> Controller:
        """The components controller of the current parameter values (a ValueError names the parameter)."""
        names = list(self.device.parameters) + list(self.gains)
        return self.device.controller(self.design, {n: self.values[n] for n in names})

    def initialize(self) -> None:
        controller = self.make_controller()
        strict = self.values["strict"]                               # (a ValueError names the parameter)
        if strict not in (0, 1):
            raise ValueError(f"parameter strict = {strict} violates strict in {{0, 1}}")
        failed = certificates.violated(controller, self.input_jet(controller))
        if failed:
            message = certificates.violation_text(self.model_identifier, controller, failed, int(strict))
            if strict:
                raise ValueError(message)
            self.log(message, Fmi2Status.warning)
        self.controller, self._u, self._u_vector = controller, None, None

    def input_jet(self, controller: Controller) -> Jet | None:
        """The reference jet at the inputs (tracking controllers), or None if it is not feasible."""
        if not self.tracking:
            return None
        m = self.device.n_m
        values = np.array([self.values[name] for name in self.input_names[self.n:]])
        jet = Jet(*values.reshape(4, m))
        try:
            controller.target(jet)
        except ValueError:
            return None
        return jet

    # ---- the output -----------------------------------------------------------------------------
    def inputs_changed(self) -> None:
        self._u = None
        self._u_vector = None

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
            if controller.scalars is not None:                # one-DOF plant: the generated law in scalars
                u = float(controller.scalars(*x))
            else:
                u = float(self.law(controller, x)[0])
        except Exception as exc:                                      # noqa: BLE001 - reported, never raised
            return math.nan, f"{self.model_identifier}: u cannot be computed for the inputs {self.input_values()}: {exc}"
        if not math.isfinite(u):
            return math.nan, f"{self.model_identifier}: u = {u} for the inputs {self.input_values()}"
        return u, ""

    def law(self, controller: Controller, x: list[float]) -> np.ndarray:
        """u (n_e,) of the matrix law at the inputs x (the states, then the jet if tracking)."""
        n, m = self.n, self.device.n_m
        jet = Jet(*np.array(x[n:]).reshape(4, m)) if self.tracking else None
        return np.asarray(controller.u(np.array(x[:n]), jet), dtype=float)

    def u_vector(self) -> tuple[float, ...]:
        """u (n_e entries) at the current inputs, computed once per input change (before initialization, at
        every call); any entry nan when it cannot be computed (the reason is logged)."""
        if self._u_vector is None or self.controller is None:
            self._u_vector, self._u_error = self.compute_u_vector()
            if self._u_error:
                self.log_error(self._u_error)
        return self._u_vector

    def compute_u_vector(self) -> tuple[tuple[float, ...], str]:
        """(u, "") or (nan..., reason): any n_e."""
        n_e = len(self.output_names)
        x = [self.values[name] for name in self.input_names]
        for name, value in zip(self.input_names, x):
            if not math.isfinite(value):
                return (math.nan,) * n_e, f"{self.model_identifier}: input {name} = {value} is not finite"
        try:
            controller = self.controller if self.controller is not None else self.make_controller()
            u = self.law(controller, x)
        except Exception as exc:                                      # noqa: BLE001 - reported, never raised
            return (math.nan,) * n_e, (f"{self.model_identifier}: u cannot be computed for the inputs "
                                       f"{self.input_values()}: {exc}")
        if not np.all(np.isfinite(u)):
            return (math.nan,) * n_e, f"{self.model_identifier}: u = {u.tolist()} for the inputs {self.input_values()}"
        return tuple(float(v) for v in u), ""

    def input_values(self) -> dict:
        return {name: self.values[name] for name in self.input_names}

    def step(self, t: float, h: float) -> bool:
        u = self.u_value() if self.scalar else sum(self.u_vector())
        if math.isfinite(u):
            return True
        self.log_error(f"{self._u_error} (doStep at t = {t:.9g} s)")
        return False

    # ---- FMI 2.0 derivatives (contract: derivatives.DerivativeFunctions) --------------------------------
    def u_derivative(self, directions: list[float]):
        """sum_j du/d(input_j) directions_j at the current inputs (ValueError with the reason): a number for
        a one-DOF plant, else an array of shape (n_e,) (components.controller.Controller.u_derivative)."""
        values = self.values
        x = [values[name] for name in self.input_names]
        if not math.isfinite(sum(x)):                          # some input is nan or inf (or the sum overflows)
            for name, value in zip(self.input_names, x):
                if not math.isfinite(value):
                    raise ValueError(f"input {name} = {value} is not finite")
        controller = self.controller if self.controller is not None else self.make_controller()
        d = controller.u_derivative(x, directions)
        return float(d) if self.scalar and controller.scalars is not None else np.asarray(d, dtype=float).reshape(-1)

    def output_derivative(self, name: str, order: int) -> float:
        """du/dt = (du/d inputs) (d inputs/dt), the input rates as set by the master (0 where none)."""
        rates = self.input_derivatives
        d = self.u_derivative([rates[n].get(1, 0.0) if n in rates else 0.0 for n in self.input_names])
        return d if isinstance(d, float) else float(d[self.output_index[name]])

    def directional_derivative(self, unknowns: list[str], knowns: list[str], seeds: list[float]) -> list[float]:
        """sum_j du_i/d(knowns_j) seeds_j for each unknown u_i."""
        index = {n: i for i, n in enumerate(self.input_names)}
        v = [0.0] * len(self.input_names)
        for name, seed in zip(knowns, seeds):
            v[index[name]] += seed
        d = self.u_derivative(v)
        if isinstance(d, float):
            return [d] * len(unknowns)
        return [float(d[self.output_index[name]]) for name in unknowns]
