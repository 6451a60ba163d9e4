"""One place for every physical parameter: name, default, unit, description and admissible range.

The FMU adapters, scenario files, reports and plots read these records, so a parameter has the
same name, unit and description everywhere.
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Mapping


@dataclass(frozen=True)
class Parameter:
    """A scalar physical parameter.

    `condition` is one of "> 0", ">= 0", "any" (finite) and is checked by `check`.
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
