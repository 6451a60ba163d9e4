"""Export a scenario as one closed-loop FMU with fmpy's container FMU (fmpy.container_fmu).

The container holds the scenario's FMUs and connections; its variables are
- `time` (independent; the container's value references start after it),
- every parameter value of the scenario's .ssv files, as a parameter "component.variable" whose
  start is the .ssv value (so `fmpy simulate loop.fmu --start-values controller.D_d -0.4` works),
- every output connector, as an output "component.variable".
Each keeps the unit and description of its component's variable; the components' unit definitions
are copied into the container's modelDescription (fmpy.container_fmu copies none by itself).
The container runs with the fixed step given here and `parallelDoStep=False` (parallel stepping
aborts the process): it steps the components one after the other and propagates their outputs
through the connections at communication points. For a loop of state-output plants and static
controllers whose outputs are computed on demand, this gives the same trajectory as our master
(measured: tests/test_master.py and tests/test_scenarios.py compare them); with parallel (Jacobi)
stepping a feedthrough controller would act one step late, as in libcosim.
"""
from __future__ import annotations

import shutil
import uuid
from pathlib import Path
from typing import Any

from fmpy import read_model_description
from fmpy.container_fmu import Configuration
from fmpy.container_fmu.cli import create_container_fmu
from fmpy.container_fmu.config import Component, Connection
from fmpy.model_description import CoSimulation, DefaultExperiment, ModelDescription, ModelVariable, Unknown

from . import tempdirs
from .binding import check_connections, load, parameter_values
from .errors import OptionError, ScenarioError
from .outputs import check_destination, write_file
from .ssd import Scenario


def export_container(scenario: Scenario, filename: Path, step_size: float | None = None) -> Path:
    """Write `scenario` as a container FMU to `filename` and return it. The destination is checked
    first (its folder is created if missing; a link or a read-only file is refused)."""
    filename = Path(filename).absolute()
    try:
        filename.parent.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise ScenarioError(f"{filename}: cannot create folder {filename.parent}: {exc.strerror or exc}") from None
    check_destination(filename)
    h = scenario.hold_step(step_size, "the container FMU")
    if h is None or not h > 0:
        raise OptionError("{where}: the container needs a positive fixed step (give {step_size})", "step_size",
                          where=scenario.path)
    instances = load(scenario)
    connections = check_connections(scenario, instances)
    for c in connections:
        if c.factor != 1.0 or c.offset != 0.0:
            raise ScenarioError(f"{scenario.path}: connection {c.start} -> {c.end}: the container FMU "
                                "cannot apply linear transformations")
    parameters = parameter_values(scenario, instances, {})
    components = {name: Component(name=name, filename=inst.path, modelDescription=inst.model_description)
                  for name, inst in instances.items()}
    if len({inst.path.stem for inst in instances.values()}) != len(instances):
        # the container unpacks each FMU to resources/<file stem>: one instance per FMU file
        raise ScenarioError(f"{scenario.path}: the container FMU needs a distinct FMU file per component")

    variables = [ModelVariable(type="Real", variability="continuous", causality="independent", name="time")]
    mappings: dict[str, Any] = {}
    for name, inst in instances.items():
        for var, value in parameters[name]:
            v = ModelVariable(type=var.type, variability=var.variability or "fixed", causality="parameter",
                              initial="exact", name=f"{name}.{var.name}", description=var.description,
                              start=_literal(value), unit=_unit(var))
            variables.append(v)
            mappings[v] = [(components[name], var)]
    outputs = []
    for comp in scenario.components:
        for k in comp.connectors:
            var = instances[comp.name].variables[k.name]
            if var.causality != "output":
                continue
            v = ModelVariable(type=var.type, variability="continuous", causality="output",
                              initial="calculated", name=f"{comp.name}.{k.name}", description=var.description,
                              unit=_unit(var))
            variables.append(v)
            mappings[v] = [(components[comp.name], var)]
            outputs.append(Unknown(variable=v, dependencies=[]))
    if not outputs:
        raise ScenarioError(f"{scenario.path}: no output connectors to expose in the container")
    md = ModelDescription(
        fmiVersion="2.0", modelName=scenario.name, instantiationToken="{%s}" % uuid.uuid4(),
        description=scenario.description or f"closed loop of scenario {scenario.name}",
        generationTool="emcosim export (fmpy.container_fmu)", variableNamingConvention="structured",
        defaultExperiment=DefaultExperiment(startTime=repr(scenario.start_time),
                                            stopTime=None if scenario.stop_time is None else repr(scenario.stop_time),
                                            stepSize=repr(h)),
        coSimulation=CoSimulation(modelIdentifier="container_fmu", fixedInternalStepSize=h),
        modelVariables=variables)
    md.unitDefinitions = _unit_definitions(instances, variables)
    md.outputs = outputs
    md.initialUnknowns = [Unknown(variable=u.variable, dependencies=[]) for u in outputs]
    conns = []
    for c in connections:
        src = instances[c.start_element].variables[c.start_connector]
        dst = instances[c.end_element].variables[c.end_connector]
        conns.append(Connection(components[c.start_element], [_typed(src)], components[c.end_element], [_typed(dst)]))
    config = Configuration(parallelDoStep=False, modelDescription=md, components=list(components.values()),
                           connections=conns, variableMappings=mappings)
    return _write_container(config, filename)


def _write_container(config: Configuration, filename: Path) -> Path:
    """Build the container in a temporary folder of this run (emcosim-PID-export-...: removed at the
    next start if the export is killed), check it, then write it beside `filename` and rename it into
    place: an old FMU there stays until the new one is complete, on any file system."""
    workdir = tempdirs.make("export")
    try:
        built = workdir / "container.fmu"
        (workdir / "unzip").mkdir()
        create_container_fmu(config, workdir / "unzip", built)     # it deletes and recreates that folder
        read_model_description(str(built))                          # fails loudly if unreadable
        with open(built, "rb") as source:
            write_file(filename, lambda f: shutil.copyfileobj(source, f, 1 << 20))
    except OSError as exc:
        raise ScenarioError(f"{filename}: cannot write the container FMU: {exc.strerror or exc}") from None
    finally:
        shutil.rmtree(workdir, ignore_errors=True)
    return filename


def _unit(var) -> str | None:
    """The unit of a Real variable: its own, or its declared type's."""
    if var.type != "Real":
        return None
    return var.unit or (var.declaredType.unit if var.declaredType is not None else None)


def _unit_definitions(instances, variables) -> list:
    """The components' definitions of the units the container's variables use (first definition of
    each name); a unit two components define differently is an error."""
    used = {v.unit for v in variables if v.unit}
    found: dict[str, Any] = {}
    for inst in instances.values():
        for unit in inst.model_description.unitDefinitions:
            if unit.name not in used:
                continue
            if unit.name in found and repr(found[unit.name].baseUnit) != repr(unit.baseUnit):
                raise ScenarioError(f"unit '{unit.name}' is defined differently by two components ({inst.path.name})")
            found.setdefault(unit.name, unit)
    return [found[name] for name in sorted(found)]


def _typed(var) -> ModelVariable:
    """A copy of a component variable whose type is named as the container's runtime expects
    (fmpy writes connection types verbatim, and the runtime knows "Float64", not "Real")."""
    names = {"Real": "Float64", "Integer": "Int32", "Boolean": "Boolean"}
    return ModelVariable(type=names[var.type], variability=var.variability, causality=var.causality,
                         name=var.name, valueReference=var.valueReference)


def _literal(value) -> str:
    if isinstance(value, bool):
        return "true" if value else "false"
    return repr(value) if isinstance(value, float) else str(value)
