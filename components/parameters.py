"""One place for every physical parameter: name, default, unit, description and admissible range.

The FMU adapters, scenario files, reports and plots read these records, so a parameter has the
same name, unit and description everywhere.
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Mapping

# Magnitudes a parameter may have besides 0: a few products and reciprocals of such numbers stay finite
# in double precision (1e100 cubed is 1e300), so a value outside is refused by name instead of
# surfacing later as an overflow or a division by zero somewhere in the model.
TINY, HUGE = 1e-100, 1e100


@dataclass(frozen=True)
class Parameter:
    """A scalar physical parameter.

    `condition` is one of "> 0", ">= 0", "any" (finite) and is checked by `check`, together with
    TINY <= |value| <= HUGE for every value other than 0.
    """

    name: str
    default: float
    unit: str
    description: str
    condition: str = "> 0"

    def check(self, value: float, owner: str = "") -> float:
        """Return `value` as float, or raise ValueError naming the parameter and the condition."""
        where = f"{owner}: " if owner else ""
        try:
            x = float(value)
        except (TypeError, ValueError):
            raise ValueError(f"{where}parameter {self.name} = {value!r} is not a number") from None
        if not math.isfinite(x):
            raise ValueError(f"{where}parameter {self.name} = {x} must be finite")
        if self.condition == "> 0" and not x > 0:
            raise ValueError(f"{where}parameter {self.name} = {x} violates {self.name} > 0 ({self.description})")
        if self.condition == ">= 0" and not x >= 0:
            raise ValueError(f"{where}parameter {self.name} = {x} violates {self.name} >= 0 ({self.description})")
        if x != 0 and not TINY <= abs(x) <= HUGE:
            raise ValueError(f"{where}parameter {self.name} = {x} violates {TINY:g} <= |{self.name}| <= {HUGE:g} "
                             "(magnitudes the model's arithmetic can represent)")
        return x


def resolve(specs: Mapping[str, Parameter], values: Mapping[str, float], owner: str) -> dict[str, float]:
    """Defaults overridden by `values`, each checked; unknown names are refused."""
    unknown = set(values) - set(specs)
    if unknown:
        raise ValueError(f"{owner}: unknown parameter(s) {sorted(unknown)}; known: {sorted(specs)}")
    return {name: spec.check(values.get(name, spec.default), owner) for name, spec in specs.items()}


def table(specs: Mapping[str, Parameter]) -> str:
    """A Markdown table of parameters (for docs and reports)."""
    rows = ["| name | default | unit | description |", "|---|---|---|---|"]
    rows += [f"| {p.name} | {p.default:g} | {p.unit} | {p.description} |" for p in specs.values()]
    return "\n".join(rows)
