"""modelDescription.xml of an emcosim FMU, written whole from the slave's declared variables (FMI 2.0,
section 2.2): both interfaces (<ModelExchange> and <CoSimulation>, one binary), UnitDefinitions, every
variable with its unit and description, the state derivatives der(x) of an FMU with states, and a
ModelStructure with real dependencies (Outputs, Derivatives, InitialUnknowns), and emcosim's vendor
annotations: for an FMU that drops input derivatives above some order, which it uses (`TOOL`, below); for a
plant or controller of a device, the device whose model it holds (`DEVICE_TOOL`, below).
The GUID is derived from the content and the build, so that the same inputs give the same bytes.
"""
from __future__ import annotations

import hashlib
import uuid
from dataclasses import dataclass
from typing import Any, NamedTuple
from xml.etree.ElementTree import Element, SubElement, tostring

from .pythonfmu_workarounds import PYTHONFMU_VERSION
from .variables import Variable, base_units

LOG_CATEGORIES = {
    "logStatusWarning": "Log messages with fmi2Warning status.",
    "logStatusDiscard": "Log messages with fmi2Discard status.",
    "logStatusError": "Log messages with fmi2Error status.",
    "logStatusFatal": "Log messages with fmi2Fatal status.",
    "logAll": "Log all messages.",
}
# emcosim's vendor annotation (read by emcosim/engine/vendor.py, which spells the same names):
#   <VendorAnnotations><Tool name="org.emcosim"><InputDerivatives orderUsed="1"/></Tool></VendorAnnotations>
# It works around FMI 2.0 having no attribute for the input derivative order a slave uses: canInterpolateInputs
# says it takes derivatives, not up to which order, so a master passes what the source gives.
TOOL = "org.emcosim"
INPUT_DERIVATIVES = "InputDerivatives"
ORDER_USED = "orderUsed"
# The device whose model a plant or controller FMU holds (read by emcosim/engine/vendor.py), in a Tool of its
# own (fmi2Annotation: one element per Tool, each Tool name once):
#   <Tool name="org.emcosim.device"><Device name="Solenoid" model="<sha256>" role="controller"/></Tool>
# A plant declares the device it is, a controller the device it was designed for: the engine refuses to
# connect FMUs of different devices and warns where their same-named parameters differ.
DEVICE_TOOL = "org.emcosim.device"
DEVICE = "Device"


class DeviceIdentity(NamedTuple):
    """The device whose model an FMU holds: its name, a digest of its model (the sha256 of its description
    file or device module) and the FMU's role ("plant" or "controller")."""

    name: str
    model: str
    role: str


@dataclass(frozen=True)
class Native:
    """What differs in the modelDescription of a native FMU (fmus/native_build.py): no execution tool, the
    generator's name, the C files of sources/ (<SourceFiles>), and whether it provides Co-Simulation."""

    generation_tool: str
    source_files: tuple[str, ...]
    co_simulation: bool


def _flag(value: bool) -> str:
    return "true" if value else "false"


def _number(value: float | int) -> str:
    return repr(int(value)) if isinstance(value, int) else repr(float(value))


def model_description(slave: Any, build: str, options: dict[str, bool], native: Native | None = None) -> Element:
    """The modelDescription of `slave` (an EMSlave after `declare`); options: canGetAndSetFMUstate,
    canSerializeFMUstate; `native`: the native form of the same FMU (fmus/native_build.py)."""
    variables: list[Variable] = slave.variables
    index = {v.name: i + 1 for i, v in enumerate(variables)}
    root = Element("fmiModelDescription", {
        "fmiVersion": "2.0", "modelName": slave.model_identifier, "guid": "",
        "description": slave.summary, "author": type(slave).author, "license": type(slave).license,
        "version": type(slave).version,
        "generationTool": native.generation_tool if native else f"emcosim (pythonfmu {PYTHONFMU_VERSION})",
        "variableNamingConvention": "structured",
        "numberOfEventIndicators": str(slave.number_of_event_indicators),
    })
    state = {"canGetAndSetFMUstate": _flag(options.get("canGetAndSetFMUstate", False)),
             "canSerializeFMUstate": _flag(options.get("canSerializeFMUstate", False))}
    common = {"modelIdentifier": slave.model_identifier, "needsExecutionTool": "false" if native else "true",
              "canBeInstantiatedOnlyOncePerProcess": "false", "canNotUseMemoryManagementFunctions": "true", **state,
              "providesDirectionalDerivative": _flag(slave.provides_directional_derivative)}
    interfaces = [SubElement(root, "ModelExchange", {**common, "completedIntegratorStepNotNeeded": "true"})]
    if native is None or native.co_simulation:
        interfaces.append(SubElement(root, "CoSimulation", {
            **common, "canHandleVariableCommunicationStepSize": "true",
            "canInterpolateInputs": _flag(slave.can_interpolate_inputs),
            "maxOutputDerivativeOrder": str(int(slave.max_output_derivative_order))}))
    if native is not None:                   # FMI 2.0, section 2.2.8: the C sources of a source FMU
        for node in interfaces:
            files = SubElement(node, "SourceFiles")
            for name in native.source_files:
                SubElement(files, "File", {"name": name})

    units = SubElement(root, "UnitDefinitions")
    for name in sorted({v.unit for v in variables if v.unit is not None}):
        unit = SubElement(units, "Unit", {"name": name})
        SubElement(unit, "BaseUnit", {k: str(e) for k, e in base_units(name).items()})
    categories = SubElement(root, "LogCategories")
    for name, description in LOG_CATEGORIES.items():
        SubElement(categories, "Category", {"name": name, "description": description})
    start, stop, step = slave.experiment
    SubElement(root, "DefaultExperiment", {"startTime": repr(float(start)), "stopTime": repr(float(stop)),
                                           "stepSize": repr(float(step))})
    _vendor_annotations(root, slave)         # FMI 2.0: after DefaultExperiment, before ModelVariables

    model_variables = SubElement(root, "ModelVariables")
    for vr, v in enumerate(variables):
        _scalar_variable(model_variables, vr, v, index)

    structure = SubElement(root, "ModelStructure")
    outputs = [v for v in variables if v.causality == "output"]
    derivatives = [v for v in variables if v.derivative_of is not None]
    if outputs:
        node = SubElement(structure, "Outputs")
        for v in outputs:
            SubElement(node, "Unknown", {"index": str(index[v.name]), "dependencies": _indices(v.dependencies, index)})
    if derivatives:
        node = SubElement(structure, "Derivatives")
        for v in derivatives:
            SubElement(node, "Unknown", {"index": str(index[v.name]), "dependencies": _indices(v.dependencies, index)})
    initial = sorted(outputs + derivatives, key=lambda v: index[v.name])
    if initial:
        node = SubElement(structure, "InitialUnknowns")
        for v in initial:
            attrib = {"index": str(index[v.name])}
            if v.initial_deps is not None:
                attrib["dependencies"] = _indices(v.initial_deps, index)
            SubElement(node, "Unknown", attrib)

    # a GUID that changes exactly when the description or the build (every source, pythonfmu, the loader,
    # the Python recorded) changes
    digest = hashlib.sha256(tostring(root) + build.encode()).hexdigest()
    root.set("guid", "{%s}" % uuid.uuid5(uuid.NAMESPACE_URL, "emcosim:" + digest))
    return root


def _vendor_annotations(root: Element, slave: Any) -> None:
    """emcosim's <Tool> (module constants) for a slave that interpolates inputs and drops the orders above
    `input_derivative_orders_used` (none for one that uses every order, a plant, or takes none), and the
    device <Tool> of a slave with a `device_identity`; no <VendorAnnotations> without either."""
    used = slave.input_derivative_orders_used
    identity: DeviceIdentity | None = getattr(slave, "device_identity", None)
    orders = slave.can_interpolate_inputs and used is not None
    if not orders and identity is None:
        return
    annotations = SubElement(root, "VendorAnnotations")
    if orders:
        tool = SubElement(annotations, "Tool", {"name": TOOL})
        SubElement(tool, INPUT_DERIVATIVES, {ORDER_USED: str(int(used))})   # the Tool's one element (fmi2Annotation)
    if identity is not None:
        tool = SubElement(annotations, "Tool", {"name": DEVICE_TOOL})
        SubElement(tool, DEVICE, {"name": identity.name, "model": identity.model, "role": identity.role})


def _indices(names: list[str], index: dict[str, int]) -> str:
    return " ".join(str(i) for i in sorted(index[n] for n in names))


def _scalar_variable(parent: Element, vr: int, v: Variable, index: dict[str, int]) -> None:
    variability = "fixed" if v.causality == "parameter" else "continuous"
    attrib = {"name": v.name, "valueReference": str(vr), "description": v.description,
              "causality": v.causality, "variability": variability}
    if v.causality in ("output", "local"):
        attrib["initial"] = "calculated"
    node = SubElement(parent, "ScalarVariable", attrib)
    kind: dict[str, str] = {}
    if v.start is not None and v.causality in ("parameter", "input"):
        kind["start"] = _number(v.start)
    if v.unit is not None:
        kind["unit"] = v.unit
    if v.derivative_of is not None:
        kind["derivative"] = str(index[v.derivative_of])
    if v.nominal is not None:
        kind["nominal"] = repr(float(v.nominal))
    SubElement(node, "Integer" if v.integer else "Real", kind)
