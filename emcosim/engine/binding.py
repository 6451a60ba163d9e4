"""Binding a scenario to its FMUs: each component's modelDescription read (with emcosim's vendor annotations,
vendor.py) and its connectors checked against it, the connections checked (causality, type, units: a unit
conversion folded into the connection's linear transformation; connected FMUs declaring different devices
refused), and the parameter values to set (the .ssv files', then the start values asked for), each checked
against the variable it sets; where connected FMUs of one device are given different values of a same-named
parameter, `model_differences` says so.
"""
from __future__ import annotations

import dataclasses
import math
from typing import Any

from . import fmi, units, vendor
from .errors import OptionError, ScenarioError
from .instances import Instance
from .ssd import Scenario, parse_value

TRANSFER_TYPES = ("Real", "Integer", "Boolean")   # what a connection or a recorded variable may carry
INT_MIN, INT_MAX = -2**31, 2**31 - 1              # fmi2Integer is a 32-bit int


class _Where:
    """Where a value comes from, for messages: an .ssv file's location, or a start value the caller asked
    for (named as the caller names its start values: option "start_values")."""

    def __init__(self, location: str | None = None, start_value: str | None = None):
        self.location, self.start_value = location, start_value

    def error(self, problem: str) -> ScenarioError:
        if self.start_value is None:
            return ScenarioError(f"{self.location}: {problem}")
        return OptionError("{start_values} {name}: {problem}", "start_values", name=self.start_value, problem=problem)


def load(scenario: Scenario, model_exchange: bool = False) -> dict[str, Instance]:
    """Read every component's modelDescription and check its connectors against it. model_exchange: the
    run integrates the FMUs' states as one ODE, so every FMU must offer Model Exchange."""
    instances = {}
    for comp in scenario.components:
        if "." in comp.name:
            raise ScenarioError(f"{scenario.path}: component name '{comp.name}' must not contain '.'")
        if not comp.source.is_file():
            raise ScenarioError(f"{scenario.path}: component '{comp.name}': FMU not found: {comp.source}")
        try:
            md = fmi.read_model_description(str(comp.source), validate=False)
        except Exception as exc:                      # fmpy raises several kinds for broken FMUs
            raise ScenarioError(f"{comp.source}: cannot read modelDescription.xml "
                                f"({' '.join(str(exc).split())})") from None
        if not md.fmiVersion.startswith("2."):
            raise ScenarioError(f"{comp.source}: not an FMI 2.0 FMU (fmiVersion {md.fmiVersion})")
        if model_exchange and md.modelExchange is None:
            raise ScenarioError(f"{comp.source}: component '{comp.name}' is a Co-Simulation-only FMU (no "
                                "<ModelExchange> in its modelDescription): a Model Exchange run integrates every "
                                "FMU's states as one ODE")
        if not model_exchange and md.coSimulation is None:
            raise ScenarioError(f"{comp.source}: component '{comp.name}' is a Model-Exchange-only FMU (no "
                                "<CoSimulation>): run the scenario as Model Exchange")
        inst = Instance(comp.name, comp.source, md, {v.name: v for v in md.modelVariables})
        inst.input_order_used, note = vendor.input_order_used(comp.source)
        inst.device, device_note = vendor.device(comp.source)
        inst.notes += [n for n in (note, device_note) if n]
        for conn in comp.connectors:
            var = inst.variable(conn.name, scenario)
            if var.type != conn.type:
                raise ScenarioError(f"{scenario.path}: type mismatch: connector {comp.name}.{conn.name} is "
                                    f"{conn.type} but {comp.source.name} declares {var.type}")
            if conn.kind != var.causality and not (conn.kind == "parameter" and var.causality == "parameter"):
                raise ScenarioError(f"{scenario.path}: causality mismatch: connector {comp.name}.{conn.name} is "
                                    f"'{conn.kind}' but {comp.source.name} declares '{var.causality}'")
        instances[comp.name] = inst
    return instances


def check_connections(scenario: Scenario, instances: dict[str, Instance]) -> list:
    """Each connection must run from an output to an input of the same type; an input has one source.
    Returns the connections to run, with the unit conversion between the two ends (SSP: converted
    to the end's unit, then the connection's LinearTransformation) folded into factor and offset."""
    fed: dict[str, str] = {}
    out = []
    for c in scenario.connections:
        for element in (c.start_element, c.end_element):
            if element not in instances:
                raise ScenarioError(f"{scenario.path}: connection {c.start} -> {c.end}: no component '{element}'")
        src = instances[c.start_element].variable(c.start_connector, scenario)
        dst = instances[c.end_element].variable(c.end_connector, scenario)
        if src.causality != "output":
            raise ScenarioError(f"{scenario.path}: causality mismatch: connection starts at {c.start}, "
                                f"which is '{src.causality}', not an output")
        if dst.causality != "input":
            raise ScenarioError(f"{scenario.path}: causality mismatch: connection ends at {c.end}, "
                                f"which is '{dst.causality}', not an input")
        if src.type != dst.type:
            raise ScenarioError(f"{scenario.path}: type mismatch: connection {c.start} ({src.type}) -> "
                                f"{c.end} ({dst.type})")
        if src.type not in TRANSFER_TYPES:
            raise ScenarioError(f"{scenario.path}: connection {c.start} -> {c.end}: {src.type} "
                                "connections are not supported")
        if (c.factor != 1.0 or c.offset != 0.0) and src.type != "Real":
            raise ScenarioError(f"{scenario.path}: connection {c.start} -> {c.end}: a linear "
                                "transformation needs Real variables")
        if c.end in fed:
            raise ScenarioError(f"{scenario.path}: input {c.end} is fed by both {fed[c.end]} and {c.start}")
        fed[c.end] = c.start
        out.append(_with_unit_conversion(scenario, instances, c) if src.type == "Real" else c)
    check_devices(scenario, instances)
    return out


def connected_pairs(scenario: Scenario, instances: dict[str, Instance]) -> list[tuple[Instance, Instance]]:
    """The pairs of components joined by at least one connection (either way), each once, in component order."""
    order = {name: i for i, name in enumerate(instances)}
    pairs = {tuple(sorted((c.start_element, c.end_element), key=order.__getitem__)) for c in scenario.connections
             if c.start_element != c.end_element and c.start_element in order and c.end_element in order}
    return [(instances[a], instances[b]) for a, b in sorted(pairs, key=lambda p: (order[p[0]], order[p[1]]))]


def check_devices(scenario: Scenario, instances: dict[str, Instance]) -> None:
    """Refuse connected FMUs that declare different devices (vendor.py: a controller designed for one device
    connected to the plant of another, or one built from another version of the device's model). FMUs that
    declare none are not compared."""
    for a, b in connected_pairs(scenario, instances):
        if a.device is None or b.device is None or (a.device.name, a.device.model) == (b.device.name, b.device.model):
            continue
        why = ("different devices" if a.device.name != b.device.name else
               f"two different models of device {a.device.name!r} (their descriptions differ)")
        raise ScenarioError(f"{scenario.path}: component '{a.name}' ({a.path.name}: {a.device.shown()}) is connected "
                            f"to '{b.name}' ({b.path.name}: {b.device.shown()}): {why}. A controller runs with the "
                            "plant it was designed for: build both from one description (emcosim plant build)")


def model_differences(scenario: Scenario, instances: dict[str, Instance],
                      parameters: dict[str, list[tuple[Any, Any]]]) -> list[str]:
    """Where connected FMUs of one device (vendor.py) run with different values of a parameter of the same
    name (an .ssv file or a start value set it on one of them): a note each, naming both values, e.g. a
    plant's k_s set to 7000 while the controller's model of it keeps 5000. Not an error (a robustness study
    may want it), but never silent: the runs put these notes among their warnings and into the results
    file's header."""
    notes = []
    for a, b in connected_pairs(scenario, instances):
        if a.device is None or b.device is None or (a.device.name, a.device.model) != (b.device.name, b.device.model):
            continue
        if a.device.role == "controller" and b.device.role != "controller":
            a, b = b, a                                   # name the plant first
        values_a, values_b = _parameter_values(a, parameters), _parameter_values(b, parameters)
        for name in [n for n in values_a if n in values_b]:
            va, vb = values_a[name], values_b[name]
            if va is not None and vb is not None and not math.isclose(va, vb, rel_tol=1e-12, abs_tol=0.0):
                notes.append(f"{a.name}.{name} = {va!r}, but the {b.device.role} '{b.name}' models it with "
                             f"{b.name}.{name} = {vb!r} (device {a.device.name!r}): the {b.device.role} acts on a "
                             f"model that differs from the {a.device.role} it is connected to")
    return notes


def _parameter_values(inst: Instance, parameters: dict[str, list[tuple[Any, Any]]]) -> dict[str, float | None]:
    """Real parameters of an FMU by name: the value to be set, else the start value (None if not a number)."""
    values: dict[str, float | None] = {}
    for name, var in inst.variables.items():
        if var.causality == "parameter" and var.type == "Real":
            values[name] = _number(var.start)
    for var, value in parameters.get(inst.name, []):
        if var.name in values:
            values[var.name] = _number(value)
    return values


def _number(value: Any) -> float | None:
    try:
        number = float(value)
    except (TypeError, ValueError):
        return None
    return number if math.isfinite(number) else None


def _end_unit(scenario: Scenario, inst: Instance, connector: str) -> units.Unit | None:
    """The unit of one end of a connection: the FMU variable's (from its UnitDefinitions), else the
    .ssd connector's, else None (unitless)."""
    var = inst.variables[connector]
    name = units.unit_of_variable(var)
    fmu_units = units.of_model_description(inst.model_description)
    conn = next((k for k in scenario.component(inst.name).connectors if k.name == connector), None)
    if conn is not None and conn.unit:
        declared = conn.unit_definition or fmu_units.get(conn.unit) or units.Unit(conn.unit, None)
        if name is not None:
            fmu = fmu_units.get(name) or units.Unit(name, None)
            if units.conversion(declared, fmu) is None:
                raise ScenarioError(f"{scenario.path}: unit mismatch: connector {inst.name}.{connector} is "
                                    f"[{conn.unit}] ({declared.dimension()}) but {inst.path.name} declares "
                                    f"[{name}] ({fmu.dimension()})")
        else:
            return declared
    if name is None:
        return None
    return fmu_units.get(name) or units.Unit(name, None)


def _with_unit_conversion(scenario: Scenario, instances: dict[str, Instance], c):
    src = _end_unit(scenario, instances[c.start_element], c.start_connector)
    dst = _end_unit(scenario, instances[c.end_element], c.end_connector)
    if c.suppress_unit_conversion or src is None or dst is None:
        return c
    ab = units.conversion(src, dst)
    if ab is None:
        raise ScenarioError(f"{scenario.path}: unit mismatch: connection {c.start} [{src.name}] "
                            f"({src.dimension()}) -> {c.end} [{dst.name}] ({dst.dimension()}): "
                            "the dimensions differ (suppressUnitConversion=\"true\" on the connection "
                            "to connect them anyway)")
    a, b = ab
    if a == 1.0 and b == 0.0:
        return c
    return dataclasses.replace(c, factor=c.factor * a, offset=c.factor * b + c.offset)


def parameter_values(scenario: Scenario, instances: dict[str, Instance],
                     overrides: dict[str, str | float]) -> dict[str, list[tuple[Any, Any]]]:
    """(variable, value) pairs to set per component: .ssv values (converted to the FMU variable's
    unit), then overrides, all checked: the variable can be set and is not a connected input, the
    value has its type, an Integer fits in 32 bits, and values are within a declared min/max."""
    values: dict[str, dict[str, tuple[object, object]]] = {name: {} for name in instances}
    fed = {c.end: c.start for c in scenario.connections}
    for comp in scenario.components:
        inst = instances[comp.name]
        where = f"{scenario.path.parent / (comp.parameter_sources[-1] if comp.parameter_sources else scenario.path.name)}"
        for p in comp.parameters.values():
            if p.name not in inst.variables:
                raise ScenarioError(f"{where}: unknown parameter '{comp.name}.{p.name}' (not in {inst.path.name})")
            var = inst.variables[p.name]
            what = _Where(f"{where}: parameter '{comp.name}.{p.name}'")
            _check_settable(var, what, inst, fed.get(f"{comp.name}.{p.name}"))
            if var.type != p.type and not (var.type == "Real" and p.type == "Integer"):
                raise ScenarioError(f"{where}: type mismatch: parameter '{comp.name}.{p.name}' is {p.type} "
                                    f"but {inst.path.name} declares {var.type}")
            value = float(p.value) if var.type == "Real" else p.value
            if p.unit and var.type == "Real":
                value = _convert_unit(float(value), p, var, inst, what)
            values[comp.name][p.name] = (var, _check_range(value, var, what, inst))
    for full, raw in overrides.items():
        comp_name, _, var_name = full.partition(".")
        what = _Where(start_value=full)
        if comp_name not in instances or not var_name:
            raise what.error(f"no component '{comp_name}' in {scenario.path.name} (components: {', '.join(instances)})")
        inst = instances[comp_name]
        if var_name not in inst.variables:
            raise what.error(f"unknown variable '{var_name}' (not in {inst.path.name})")
        var = inst.variables[var_name]
        _check_settable(var, what, inst, fed.get(full))
        if isinstance(raw, str):
            try:
                value = parse_value(raw, var.type, "")
            except ScenarioError:
                raise what.error(f"value {raw!r} is not a valid {var.type}") from None
        else:
            value = raw
        if var.type == "Real":
            value = float(value)
        values[comp_name][var_name] = (var, _check_range(value, var, what, inst))
    return {name: list(v.values()) for name, v in values.items()}


def _convert_unit(value: float, p, var, inst: Instance, what: _Where) -> float:
    """An .ssv value in the parameter's unit, converted to the unit of the FMU variable."""
    fmu_units = units.of_model_description(inst.model_description)
    source = p.unit_definition or fmu_units.get(p.unit)
    if source is None:
        raise what.error(f"unit '{p.unit}' is defined neither in the file's ssv:Units nor in "
                         f"{inst.path.name}'s UnitDefinitions")
    name = units.unit_of_variable(var)
    target = (fmu_units.get(name) or units.Unit(name, None)) if name else units.Unit("1", (0.0,) * len(units.BASE))
    ab = units.conversion(source, target)
    if ab is None:
        raise what.error(f"unit mismatch: the value is in [{p.unit}] ({source.dimension()}) but "
                         f"{inst.path.name} declares {var.name} in [{name or 'no unit'}] ({target.dimension()})")
    return ab[0] * value + ab[1]


def _check_range(value, var, what: _Where, inst: Instance):
    """Refuse an Integer outside 32 bits (fmi2Integer would wrap it) and a value outside the
    variable's declared min/max."""
    if var.type == "Integer" and not isinstance(value, bool) and not INT_MIN <= value <= INT_MAX:
        raise what.error(f"value {value} does not fit an FMI Integer (32 bits: {INT_MIN} .. {INT_MAX})")
    if var.type in ("Real", "Integer"):
        for bound, ok in ((var.min, lambda b: value >= b), (var.max, lambda b: value <= b)):
            if bound is not None and not ok(float(bound)):
                raise what.error(f"value {value} is outside [{var.min if var.min is not None else '-inf'}, "
                                 f"{var.max if var.max is not None else 'inf'}] declared by {inst.path.name}")
    return value


def _check_settable(var, where: _Where, inst: Instance, source: str | None = None) -> None:
    if var.causality not in ("parameter", "input") or var.variability == "constant":
        raise where.error(f"causality mismatch: {inst.path.name} declares it "
                          f"{var.causality} ({var.variability}); only parameters and inputs can be set")
    if var.causality == "input" and source is not None:
        raise where.error(f"input is connected (fed by {source}); the master sets it from the "
                          "connection, a start value would be ignored")


# ---- what a scenario sets, beside its FMUs' defaults (`emcosim info SCENARIO`) ------------------------

@dataclasses.dataclass(frozen=True)
class Setting:
    """One value a run of the scenario starts from, beside the default it replaces: a parameter or a start value
    of a component (default: the FMU's declared start), or the experiment's start, stop time, step and coupling
    (default: the FMUs' DefaultExperiment, explicit coupling). `source` is the file that sets it (None: nothing
    does, the default holds)."""

    name: str                 # "plant.q_0", or "stop time", "step size", "start time", "coupling"
    unit: str | None
    value: Any                # what the run uses (None: nothing declared)
    default: Any              # what it would be without the scenario (None: nothing declared)
    source: str | None

    @property
    def differs(self) -> bool:
        """True where the scenario's value is not the default (numbers compared to 1e-12 relative)."""
        a, b = _number(self.value), _number(self.default)
        if a is not None and b is not None:
            return not math.isclose(a, b, rel_tol=1e-12, abs_tol=0.0)
        return self.value != self.default


def settings(scenario: Scenario, instances: dict[str, Instance]) -> tuple[list[Setting], dict[str, list[Setting]]]:
    """(the experiment's settings, per component every parameter and unconnected input with the value the
    scenario gives it and the FMU's start value), all checked as a run checks them (`parameter_values`)."""
    values = parameter_values(scenario, instances, {})
    fed = {c.end for c in scenario.connections}
    variables: dict[str, list[Setting]] = {}
    for comp in scenario.components:
        inst = instances[comp.name]
        given = {var.name: value for var, value in values[comp.name]}
        source = str(scenario.path.parent / comp.parameter_sources[-1]) if comp.parameter_sources else str(scenario.path)
        rows = []
        for name, var in inst.variables.items():
            if var.causality not in ("parameter", "input") or f"{comp.name}.{name}" in fed:
                continue
            default = _start(var)
            rows.append(Setting(f"{comp.name}.{name}", units.unit_of_variable(var), given.get(name, default), default,
                                source if name in given else None))
        variables[comp.name] = rows
    return _experiment_settings(scenario, instances), variables


def _experiment_settings(scenario: Scenario, instances: dict[str, Instance]) -> list[Setting]:
    """Start time, stop time, step size (each beside the FMUs' DefaultExperiment: one value if they agree, else
    'component: value' for each) and the coupling (default explicit)."""
    def default(field: str) -> Any:
        found = {name: getattr(inst.model_description.defaultExperiment, field, None) for name, inst in instances.items()
                 if inst.model_description.defaultExperiment is not None}
        found = {name: float(v) for name, v in found.items() if v is not None}
        if len(set(found.values())) <= 1:
            return next(iter(found.values()), None)
        return ", ".join(f"{name}: {v:g}" for name, v in found.items())

    where = str(scenario.path)
    return [Setting("start time", "s", scenario.start_time, default("startTime"), where),
            Setting("stop time", "s", scenario.stop_time, default("stopTime"), where if scenario.stop_time is not None else None),
            Setting("step size", "s", scenario.step_size, default("stepSize"), where if scenario.step_size is not None else None),
            Setting("coupling", None, scenario.coupling or "explicit", "explicit", where if scenario.coupling else None)]


def _start(var) -> Any:
    """An fmpy variable's declared start value in its type (its text if that does not parse; None: none)."""
    if var.start is None:
        return None
    try:
        return parse_value(str(var.start), var.type, "")
    except ScenarioError:
        return var.start
