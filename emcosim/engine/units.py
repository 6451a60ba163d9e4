"""Units as SSP 1.0 and FMI 2.0 define them: the exponents of the SI base units (kg, m, s, A, K, mol,
cd, rad) plus a factor and an offset, value in SI = factor * value + offset (FMI 2.0 section 2.2.2,
SSP 1.0 ssc:BaseUnit). Two units convert into each other when their exponents agree.

The master uses this for the `unit` of an .ssv parameter (converted to the FMU variable's unit
before it is set) and for connections between variables of different units (SSP: the value is
converted to the end's unit, then the connection's LinearTransformation is applied, unless the
connection says suppressUnitConversion="true").
"""
from __future__ import annotations

from dataclasses import dataclass
from xml.etree import ElementTree as ET

BASE = ("kg", "m", "s", "A", "K", "mol", "cd", "rad")


@dataclass(frozen=True)
class Unit:
    """A unit: `exponents` of the SI base units (None: a unit known by name only, e.g. an FMU's
    Unit without a BaseUnit), value in SI = factor * value + offset."""

    name: str
    exponents: tuple[float, ...] | None
    factor: float = 1.0
    offset: float = 0.0

    def dimension(self) -> str:
        """The SI dimension, e.g. 'kg.m.s-1' ('1' if dimensionless, the name if unknown)."""
        if self.exponents is None:
            return f"'{self.name}' (no BaseUnit)"
        parts = [b if e == 1 else f"{b}{e:g}" for b, e in zip(BASE, self.exponents) if e != 0]
        return ".".join(parts) or "1"


def conversion(source: Unit, target: Unit) -> tuple[float, float] | None:
    """(a, b) such that value in `target` = a * value in `source` + b; None if the dimensions
    differ (or the units are known by name only and the names differ)."""
    if source.exponents is None or target.exponents is None:
        return (1.0, 0.0) if source.name == target.name else None
    if tuple(source.exponents) != tuple(target.exponents):
        return None
    return source.factor / target.factor, (source.offset - target.offset) / target.factor


def of_model_description(md) -> dict[str, Unit]:
    """The UnitDefinitions of an fmpy model description, by name."""
    units = {}
    for u in md.unitDefinitions or []:
        b = u.baseUnit
        units[u.name] = Unit(u.name, None) if b is None else \
            Unit(u.name, tuple(float(getattr(b, k)) for k in BASE), float(b.factor), float(b.offset))
    return units


def unit_of_variable(var) -> str | None:
    """The unit name of an fmpy ModelVariable (its own, else its declared type's), or None."""
    if getattr(var, "unit", None):
        return var.unit
    declared = getattr(var, "declaredType", None)
    return getattr(declared, "unit", None) or None


def parse_units(element: ET.Element | None, ns: dict[str, str], where: str) -> dict[str, Unit]:
    """The ssc:Unit definitions inside an ssd:Units or ssv:Units element, by name; raises ValueError
    (with `where` and the unit) for a malformed definition."""
    units: dict[str, Unit] = {}
    if element is None:
        return units
    for u in element.findall("ssc:Unit", ns):
        name = u.get("name")
        if not name:
            raise ValueError(f"{where}: ssc:Unit without a name")
        base = u.find("ssc:BaseUnit", ns)
        if base is None:
            raise ValueError(f"{where}: unit '{name}' has no ssc:BaseUnit")
        try:
            exponents = tuple(float(base.get(k, "0")) for k in BASE)
            factor, offset = float(base.get("factor", "1")), float(base.get("offset", "0"))
        except ValueError:
            raise ValueError(f"{where}: unit '{name}': BaseUnit attributes must be numbers") from None
        if not (factor != 0 and abs(factor) < float("inf") and abs(offset) < float("inf")):
            raise ValueError(f"{where}: unit '{name}': factor must be finite and non-zero, offset finite")
        units[name] = Unit(name, exponents, factor, offset)
    return units
