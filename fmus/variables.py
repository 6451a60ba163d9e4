"""The variables of an emcosim FMU: what each is (causality, unit, description, dependencies) and the units
they use. Nothing here knows physics: the adapters declare their variables with the names, units and
descriptions of components/."""
from __future__ import annotations

import re
from dataclasses import dataclass, field
from typing import Callable

# SI base-unit exponents (kg, m, s, A, rad) of the units the paper's FMUs use (FMI 2.0 UnitDefinitions /
# BaseUnit). Any other unit string is parsed (`base_units`); the tests check that the parser gives every
# entry of this table.
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

# the exponents of FMI 2.0's BaseUnit, in the order the attributes are written
BASE_UNITS = ("kg", "m", "s", "A", "K", "mol", "cd", "rad")
# the symbols a unit string may use: the SI base units, rad, the SI derived units (as base-unit exponents), "1"
SYMBOLS: dict[str, dict[str, int]] = {
    **{b: {b: 1} for b in BASE_UNITS},
    "1": {},
    "N": {"kg": 1, "m": 1, "s": -2},                     # newton
    "J": {"kg": 1, "m": 2, "s": -2},                     # joule
    "W": {"kg": 1, "m": 2, "s": -3},                     # watt
    "V": {"kg": 1, "m": 2, "s": -3, "A": -1},            # volt
    "C": {"s": 1, "A": 1},                               # coulomb
    "F": {"kg": -1, "m": -2, "s": 4, "A": 2},            # farad
    "H": {"kg": 1, "m": 2, "s": -2, "A": -2},            # henry
    "Wb": {"kg": 1, "m": 2, "s": -2, "A": -1},           # weber
    "T": {"kg": 1, "s": -2, "A": -1},                    # tesla
    "Ohm": {"kg": 1, "m": 2, "s": -3, "A": -2},          # ohm
    "S": {"kg": -1, "m": -2, "s": 3, "A": 2},            # siemens
    "Pa": {"kg": 1, "m": -1, "s": -2},                   # pascal
    "Hz": {"s": -1},                                     # hertz
}
_FACTOR = re.compile(r"([A-Za-z]+|1)(-?[0-9]+)?")


def base_units(unit: str) -> dict[str, int]:
    """The FMI 2.0 BaseUnit exponents of a unit string: UNITS' entry (its order of attributes, as the paper's
    FMUs have always written them), else `parse_unit`'s."""
    known = UNITS.get(unit) if isinstance(unit, str) else None
    return dict(known) if known is not None else parse_unit(unit)


def parse_unit(unit: str) -> dict[str, int]:
    """The FMI 2.0 BaseUnit exponents of a unit string (in the order of BASE_UNITS, zeros left out).

    A unit string is factors joined by "." (multiply) or "/" (divide by the next factor only: "Wb2/J/s" is
    Wb^2 J^-1 s^-1), each a symbol of SYMBOLS with an optional integer exponent ("m/s2", "N.s/m", "kg.m/s",
    "1/Ohm"). No prefixes (write "m", not "mm"). ValueError naming the unit and the factor otherwise."""
    if not isinstance(unit, str) or not unit:
        raise ValueError(f"unit {unit!r} is not a unit string")
    total = dict.fromkeys(BASE_UNITS, 0)
    for sign, factor in re.findall(r"(^|[./])([^./]*)", unit):
        match = _FACTOR.fullmatch(factor)
        if match is None or match.group(1) not in SYMBOLS or (match.group(1) == "1" and match.group(2)):
            raise ValueError(f"unit {unit!r}: factor {factor!r} is not a symbol of {sorted(SYMBOLS)} with an "
                             "optional integer exponent (factors joined by '.' or '/')")
        power = int(match.group(2) or 1) * (-1 if sign == "/" else 1)
        for base, exponent in SYMBOLS[match.group(1)].items():
            total[base] += power * exponent
    return {b: e for b, e in total.items() if e}


class _RateUnits(dict):
    """unit -> the unit of its time derivative: the paper's FMUs' names where they have one (kg.m/s -> N),
    else one more power of s in the denominator: kg.m2/s -> kg.m2/s2, m/s2 -> m/s3, rad -> rad/s."""

    def __missing__(self, unit: str) -> str:
        if unit == "1":
            return "1/s"
        match = re.fullmatch(r"(.*)/s(\d*)", unit)
        if match:
            return f"{match.group(1)}/s{int(match.group(2) or 1) + 1}"
        return f"{unit}/s"


# the unit of the time derivative of a quantity in `unit` (der(q) of a state q)
RATE_UNITS: dict[str, str] = _RateUnits({"m": "m/s", "kg.m/s": "N", "C": "C/s", "Wb": "Wb/s", "J": "J/s"})


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
        if self.unit is not None:
            try:
                base_units(self.unit)
            except ValueError as exc:
                raise ValueError(f"{model}: {self.name}: {exc}") from None
        if self.integer and self.causality != "parameter":
            raise ValueError(f"{model}: {self.name}: only parameters may be Integer")
