"""Adapter: a plant of components/ (MEMS, maglev) as an FMI 2.0 co-simulation slave.

Variables: every entry of the plant module's PARAMETERS, the initial state q_0, p_0, x_e_0, the
integration tolerance rtol (parameters); the input u; the outputs q, p, x_e (states: no direct
feedthrough) and the stored energy H. doStep holds u over the step and calls
components.plant_step.PlantStepper; the FMU state includes the stepper's proposed substep.
"""
from __future__ import annotations

from types import ModuleType
from typing import ClassVar

import numpy as np

from .components import catalog
from .components.ph_plant import DomainError, EMPlant
from .components.plant_step import DEFAULT_RTOL, PlantStepper, StepFailure
from .em_fmu_framework import EMSlave

STATE_NAMES = ("q", "p", "x_e")


class PlantSlave(EMSlave):
    plant_module: ClassVar[ModuleType]                          # components.mems or components.maglev
    initial_state: ClassVar[tuple[float, float, float]]
    input_start: ClassVar[float] = 0.0

    def declare(self) -> None:
        module = self.plant_module
        for p in module.PARAMETERS.values():
            self.parameter(p.name, p.default, p.unit, p.description)
        for name, start in zip(STATE_NAMES, self.initial_state):
            unit, description = module.STATES[name]
            self.parameter(f"{name}_0", start, unit, f"initial value of {name}: {description}")
        self.parameter("rtol", DEFAULT_RTOL, "1",
                       "relative tolerance of the integration inside doStep (absolute tolerance: rtol times "
                       "the nominal state scale)")
        name, unit, description = module.INPUT
        self.input(name, self.input_start, unit, description)
        initial = [f"{n}_0" for n in STATE_NAMES]
        for i, name in enumerate(STATE_NAMES):
            unit, description = module.STATES[name]
            self.output(name, unit, description, (lambda i=i: self.state()[i]), [], [f"{name}_0"])
        self.output("H", "J", "stored energy H(q, p, x_e) = p^2/(2 m) + V(q) + H_e(q, x_e), eq. (open-loop elecmech)",
                    self.energy, [], initial + list(module.PARAMETERS))
        self.plant: EMPlant | None = None
        self.stepper: PlantStepper | None = None
        self.eta: tuple[float, float, float] | None = None
        self._H: float | None = None

    # ---- outputs ------------------------------------------------------------------------------
    def initial(self) -> tuple[float, float, float]:
        return tuple(float(self.values[f"{n}_0"]) for n in STATE_NAMES)

    def state(self) -> tuple[float, float, float]:
        return self.eta if self.eta is not None else self.initial()

    def energy(self) -> float:
        if self._H is None:
            plant = self.plant if self.plant is not None else self.make_plant()
            self._H = float(plant.H(self.state()))
        return self._H

    # ---- life cycle -----------------------------------------------------------------------------
    def make_plant(self) -> EMPlant:
        return catalog.plant(self.model_identifier, {n: self.values[n] for n in self.plant_module.PARAMETERS})

    def initialize(self) -> None:
        plant = self.make_plant()                                   # ValueError names parameter and condition
        stepper = PlantStepper(plant, rtol=self.values["rtol"])
        eta = self.initial()
        try:
            plant.check_state(np.array(eta))
        except DomainError as exc:
            raise ValueError(f"initial state (q_0, p_0, x_e_0) = {eta} is not admissible: {exc}") from None
        self.plant, self.stepper, self.eta, self._H = plant, stepper, eta, None

    def step(self, t: float, h: float) -> bool:
        u = self.values["u"]
        try:
            self.eta = self.stepper.advance(*self.eta, u, h)
        except (ValueError, ArithmeticError, DomainError, StepFailure) as exc:
            self.log_error(f"{self.model_identifier}: doStep from t = {t:.9g} s over h = {h:.6g} s with u = {u!r} "
                           f"failed: {exc}. The state is left at t = {t:.9g} s.")
            return False
        self._H = None
        return True

    # ---- FMU state ----------------------------------------------------------------------------
    def save_internal(self) -> dict:
        if self.stepper is None:
            return {}
        return {"eta": list(self.eta), "h_next": self.stepper.h_next}

    def restore_internal(self, internal: dict) -> None:
        if internal:
            self.eta = tuple(internal["eta"])
            self.stepper.h_next = internal["h_next"]
        self._H = None
