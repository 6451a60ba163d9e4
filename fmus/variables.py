"""The variables of an emcosim FMU: what each is (causality, unit, description, dependencies) and the units
they use. Nothing here knows physics: the adapters declare their variables with the names, units and
descriptions of components/."""
from __future__ import annotations

from dataclasses import dataclass, field
from typing import Callable

# SI base-unit exponents (kg, m, s, A, rad) of every unit the FMUs use (FMI 2.0 UnitDefinitions / BaseUnit)
UNITS: dict[str, dict[str, int]] = {
    "1": {},
    "s": {"s": 1},
    "m": {"m": 1},
    "m/s": {"m": 1, "s": -1},
    "m/s2": {"m": 1, "s": -2},
    "m/s3": {"m": 1, "s": -3},
    "kg": {"kg": 1},
    "kg.m/s": {"kg": 1, "m": 1, "s": -1},
    "N": {"kg": 1, "m": 1, "s": -2},
    "N/m": {"kg": 1, "s": -2},
    "N/m3": {"kg": 1, "m": -2, "s": -2},
    "N.s/m": {"kg": 1, "s": -1},
    "J": {"kg": 1, "m": 2, "s": -2},
    "C": {"s": 1, "A": 1},
    "C/m": {"m": -1, "s": 1, "A": 1},
    "C/s": {"A": 1},
    "V": {"kg": 1, "m": 2, "s": -3, "A": -1},
    "Ohm": {"kg": 1, "m": 2, "s": -3, "A": -2},
    "F/m": {"kg": -1, "m": -3, "s": 4, "A": 2},
    "Wb": {"kg": 1, "m": 2, "s": -2, "A": -1},
    "Wb/s": {"kg": 1, "m": 2, "s": -3, "A": -1},
    "Wb/m": {"kg": 1, "m": 1, "s": -2, "A": -1},
    "H.m": {"kg": 1, "m": 3, "s": -2, "A": -2},
    "rad": {"rad": 1},
    "rad/s": {"rad": 1, "s": -1},
}

# the unit of the time derivative of a quantity in `unit` (der(q) of a state q)
RATE_UNITS = {"m": "m/s", "kg.m/s": "N", "C": "C/s", "Wb": "Wb/s", "J": "J/s"}


@dataclass
class Variable:
    """One FMI variable of an emcosim FMU.

    causality      "parameter" (fixed), "input", "output" (continuous, calculated), "local" (a state
                   derivative der(x): its `derivative_of` names the state x) or "independent" (time)
    dependencies   outputs and derivatives: names of the knowns it depends on at a communication point /
                   in Continuous-Time Mode (FMI 2.0: inputs, continuous states, the independent variable)
    initial_deps   outputs and derivatives: names of the knowns (inputs, parameters) it depends on at
                   initialization (None: all of them)
    """

    name: str
    causality: str
    unit: str | None
    description: str
    start: float | int | None = None
    integer: bool = False
    getter: Callable[[], float] | None = None
    dependencies: list[str] = field(default_factory=list)
    initial_deps: list[str] | None = None
    derivative_of: str | None = None
    nominal: float | None = None

    def check(self, model: str) -> None:
        """A ValueError for a declaration the modelDescription cannot express."""
        if self.unit is not None and self.unit not in UNITS:
            raise ValueError(f"{model}: unit {self.unit!r} of {self.name} has no UnitDefinition")
        if self.integer and self.causality != "parameter":
            raise ValueError(f"{model}: {self.name}: only parameters may be Integer")
