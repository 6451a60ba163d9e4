"""Writing SSP files: an .ssd (`system_structure_xml`) and an .ssv (`parameter_set_xml`) from the dataclasses of
ssd.py, with the annotations other tools need (OpenModelica's fixed-step master or, for Model Exchange, its
variable-step solver; libcosim's and ecos's parameter sets)."""
from __future__ import annotations

import re
from dataclasses import dataclass
from typing import Sequence

from .ssd import EMCOSIM_ANNOTATION, NS, OMS_ANNOTATION, OSP_ANNOTATION, Parameter, Scenario


def format_value(value: float | int | bool | str) -> str:
    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, float):
        return repr(value)
    return str(value)


def parameter_set_xml(name: str, parameters: list[Parameter], notes: Sequence[str] = ()) -> str:
    """The text of an .ssv file; each parameter's description becomes an XML comment before it.
    Units go into the comments, not into `unit` attributes (SSP wants those declared in ssc:Units)."""
    lines = ['<?xml version="1.0" encoding="UTF-8"?>']
    lines += [f"<!-- {_comment(n)} -->" for n in notes]
    lines.append(f'<ssv:ParameterSet xmlns:ssv="{NS["ssv"]}" version="1.0" name="{_esc(name)}">')
    lines.append("  <ssv:Parameters>")
    for p in parameters:
        if p.description:
            lines.append(f"    <!-- {_comment(p.description)} -->")
        lines.append(f'    <ssv:Parameter name="{_esc(p.name)}">'
                     f'<ssv:{p.type} value="{_esc(format_value(p.value))}"/></ssv:Parameter>')
    lines += ["  </ssv:Parameters>", "</ssv:ParameterSet>", ""]
    return "\n".join(lines)


def identifier(name: str) -> str:
    """`name` as an identifier (letters, digits, '_'; starting with a letter), as OMSimulator wants
    model and system names: every other character becomes '_'."""
    ident = re.sub(r"[^A-Za-z0-9_]", "_", name)
    return ident if ident[:1].isalpha() else f"s_{ident}"


def system_structure_xml(scenario: Scenario, sources: dict[str, str], step_size: float,
                         tolerance: float | None = None) -> str:
    """The text of an .ssd file. `sources` maps component names to the FMU paths as written
    (relative to the .ssd); each component binds the .ssv files in its `parameter_sources`.
    `scenario.notes` become XML comments at the top, `description`s become attributes. The System
    is named `identifier(scenario.name)` and carries OpenModelica's fixed-step annotation; the
    DefaultExperiment carries the OSP one (both give `step_size`); `tolerance` is the OpenModelica
    annotation's (`oms_annotation`)."""
    ns = " ".join(f'xmlns:{p}="{u}"' for p, u in NS.items())
    desc = f' description="{_esc(scenario.description)}"' if scenario.description else ""
    lines = ['<?xml version="1.0" encoding="UTF-8"?>']
    lines += [f"<!-- {_comment(n)} -->" for n in scenario.notes]
    lines.append(f'<ssd:SystemStructureDescription {ns} version="1.0" name="{_esc(scenario.name)}"{desc}>')
    lines.append(f'  <ssd:System name="{_esc(identifier(scenario.name))}">')
    lines.append("    <ssd:Elements>")
    for c in scenario.components:
        cdesc = f' description="{_esc(c.description)}"' if c.description else ""
        lines.append(f'      <ssd:Component name="{_esc(c.name)}" type="application/x-fmu-sharedlibrary" '
                     f'source="{_esc(sources[c.name])}"{cdesc}>')
        lines.append("        <ssd:Connectors>")
        for k in c.connectors:
            lines.append(f'          <ssd:Connector name="{_esc(k.name)}" kind="{k.kind}"><ssc:{k.type}/></ssd:Connector>')
        lines.append("        </ssd:Connectors>")
        if c.parameter_sources:
            lines.append("        <ssd:ParameterBindings>")
            lines += [f'          <ssd:ParameterBinding source="{_esc(s)}"/>' for s in c.parameter_sources]
            lines.append("        </ssd:ParameterBindings>")
        lines.append("      </ssd:Component>")
    lines.append("    </ssd:Elements>")
    lines.append("    <ssd:Connections>")
    for link in scenario.connections:
        attrs = (f'startElement="{_esc(link.start_element)}" startConnector="{_esc(link.start_connector)}" '
                 f'endElement="{_esc(link.end_element)}" endConnector="{_esc(link.end_connector)}"')
        if link.suppress_unit_conversion:
            attrs += ' suppressUnitConversion="true"'
        if link.factor != 1.0 or link.offset != 0.0:
            lines.append(f"      <ssd:Connection {attrs}>")
            lines.append(f'        <ssc:LinearTransformation factor="{link.factor!r}" offset="{link.offset!r}"/>')
            lines.append("      </ssd:Connection>")
        else:
            lines.append(f"      <ssd:Connection {attrs}/>")
    lines.append("    </ssd:Connections>")
    lines += ["    <ssd:Annotations>", *oms_annotation(step_size, "      ", tolerance), "    </ssd:Annotations>"]
    lines.append("  </ssd:System>")
    stop = f' stopTime="{scenario.stop_time!r}"' if scenario.stop_time is not None else ""
    lines.append(f'  <ssd:DefaultExperiment startTime="{scenario.start_time!r}"{stop}>')
    lines.append("    <ssd:Annotations>")
    lines.append(f'      <ssc:Annotation type="{OSP_ANNOTATION}">')
    lines.append(f'        <osp:Algorithm><osp:FixedStepAlgorithm baseStepSize="{step_size!r}"/></osp:Algorithm>')
    lines.append("      </ssc:Annotation>")
    if scenario.coupling is not None:
        lines.append(f'      <ssc:Annotation type="{EMCOSIM_ANNOTATION}">')
        lines.append(f'        <emcosim:Coupling method="{scenario.coupling}"/>')
        lines.append("      </ssc:Annotation>")
    lines.append("    </ssd:Annotations>")
    lines.append("  </ssd:DefaultExperiment>")
    lines += ["</ssd:SystemStructureDescription>", ""]
    return "\n".join(lines)


# OMSimulator's own tolerance of a System (System.h: absoluteTolerance = relativeTolerance = 1e-4), written
# when no FMU of the scenario says at which tolerance it integrates
OMS_DEFAULT_TOLERANCE = 1e-4


def oms_annotation(step_size: float, indent: str = "", tolerance: float | None = None) -> list[str]:
    """OpenModelica's annotation of a fixed-step co-simulation system (what OMSimulator writes and
    reads: it must be the first ssc:Annotation of the System's ssd:Annotations).

    `tolerance` (default OMS_DEFAULT_TOLERANCE) is written as both `relativeTolerance` and
    `absoluteTolerance`: OMSimulator 2.1.3 reads them from the FixedStepMaster
    (SystemWC::importFromSSD_SimulationInformation) and passes the relative one to every FMU's
    fmi2SetupExperiment (ComponentFMUCS::initialize); its command line replaces both by `--tolerance`
    (oms_RunFile), a Lua script that imports the archive keeps them. The paper scenarios write the
    plants' `rtol` (`ssp.fixed_step_tolerance`)."""
    tol = repr(float(OMS_DEFAULT_TOLERANCE if tolerance is None else tolerance))
    return [indent + line for line in [
        f'<ssc:Annotation type="{OMS_ANNOTATION}">',
        "  <oms:Annotations>",
        "    <oms:SimulationInformation>",
        f'      <oms:FixedStepMaster description="oms-ma" stepSize="{step_size!r}" absoluteTolerance="{tol}" '
        f'relativeTolerance="{tol}"/>',
        "    </oms:SimulationInformation>",
        "  </oms:Annotations>",
        "</ssc:Annotation>"]]


@dataclass(frozen=True)
class VariableStepSolver:
    """OMSimulator's solver of a strongly coupled system (`oms:VariableStepSolver`): every FMU of the System
    is loaded as Model Exchange and integrated by `method` ("cvode": BDF with a dense Jacobian of finite
    differences, or "euler"). OMSimulator 2.1.3 reads every attribute and takes a missing one as 0, and
    `maximumStepSize` 0 hangs it, so all five are always written.

    `maximum_step` is also OMSimulator's output grid: each of its steps calls CVODE up to `time +
    maximum_step` and writes a result row there. CVODE's absolute tolerance of a state is 0.01 *
    `absolute_tolerance` * the FMU's nominal of it. OMSimulator's command line replaces both tolerances
    of the root System by its `--tolerance` (default 1e-4); the step sizes stay the archive's."""

    relative_tolerance: float
    absolute_tolerance: float
    initial_step: float
    minimum_step: float
    maximum_step: float
    method: str = "cvode"

    def __post_init__(self) -> None:
        if self.method not in ("cvode", "euler"):
            raise ValueError(f"VariableStepSolver method {self.method!r}: OMSimulator knows 'cvode' and 'euler'")
        for name in ("relative_tolerance", "absolute_tolerance", "minimum_step", "maximum_step"):
            if not getattr(self, name) > 0:
                raise ValueError(f"VariableStepSolver {name} must be > 0 (OMSimulator hangs or fails on 0)")
        if not 0 <= self.initial_step <= self.maximum_step or self.minimum_step > self.maximum_step:
            raise ValueError(f"VariableStepSolver steps: need 0 <= initial ({self.initial_step:g}) <= maximum "
                             f"({self.maximum_step:g}) and minimum ({self.minimum_step:g}) <= maximum "
                             "(initial 0: CVODE estimates it)")


def oms_solver_annotation(solver: VariableStepSolver, indent: str = "") -> list[str]:
    """OpenModelica's annotation of a strongly coupled system (Model Exchange FMUs under OMSimulator's own
    solver), in the same place as `oms_annotation`'s."""
    return [indent + line for line in [
        f'<ssc:Annotation type="{OMS_ANNOTATION}">',
        "  <oms:Annotations>",
        "    <oms:SimulationInformation>",
        f'      <oms:VariableStepSolver description="{solver.method}" '
        f'absoluteTolerance="{solver.absolute_tolerance!r}" relativeTolerance="{solver.relative_tolerance!r}" '
        f'minimumStepSize="{solver.minimum_step!r}" maximumStepSize="{solver.maximum_step!r}" '
        f'initialStepSize="{solver.initial_step!r}"/>',
        "    </oms:SimulationInformation>",
        "  </oms:Annotations>",
        "</ssc:Annotation>"]]


def _esc(s: str) -> str:
    return (str(s).replace("&", "&amp;").replace("<", "&lt;").replace(">", "&gt;").replace('"', "&quot;"))


def _comment(s: str) -> str:
    """Text for an XML comment: no "--" (which would end or break it, even after one replacement: "--->"),
    not ending in "-", on one line."""
    text = " ".join(str(s).split())
    while "--" in text:
        text = text.replace("--", "- -")
    return text + " " if text.endswith("-") else text
