"""Read and write SSP 1.0 System Structure Descriptions (.ssd) and parameter values (.ssv).

Only the part of SSP the master uses: one flat System of FMU Components, their Connectors,
Connections (optionally with a LinearTransformation), ParameterBindings to .ssv files (or inline
ParameterValues), a DefaultExperiment, and the step size in the Open Simulation Platform's
annotation (`osp:FixedStepAlgorithm baseStepSize`), which libcosim also reads. Units (ssd:Units,
ssv:Units, `unit` on connectors and parameters) are read; the master converts with them.

Files may be in any encoding XML allows (declared in the XML declaration or by a byte-order mark).
An .ssp archive is unpacked with limits (`ArchiveLimits`: total size and number of files) and its
.ssd may only reference files inside the archive unless `allow_external` is set.

Written files also run in other SSP engines (docs/ssp-engines.md): the System carries, beside the
OSP annotation, OpenModelica's (`oms:FixedStepMaster stepSize`, which OMSimulator needs to know the
system is a fixed-step co-simulation), its name is an identifier (OMSimulator refuses '.' and '-'),
and every .ssv parameter set is named PARAMETER_SET (ecos applies a set only when selected by name).

Element prefixes are written exactly as `ssd:`, `ssc:`, `ssv:`: libcosim's parser matches the
prefixed names literally. Reading is namespace-aware. Every error is a `ScenarioError` whose
message names the file and the element.
"""
from __future__ import annotations

import atexit
import codecs
import copy
import math
import re
import shutil
from dataclasses import dataclass, field
from pathlib import Path
from xml.etree import ElementTree as ET

from . import tempdirs
from .archive import ArchiveLimits, check_inside, extract_archive, unpacked
from .errors import ScenarioError
from .units import Unit, parse_units

NS = {
    "ssd": "http://ssp-standard.org/SSP1/SystemStructureDescription",
    "ssc": "http://ssp-standard.org/SSP1/SystemStructureCommon",
    "ssv": "http://ssp-standard.org/SSP1/SystemStructureParameterValues",
    "osp": "http://opensimulationplatform.com/SSP/OSPAnnotations",
    "oms": "https://raw.githubusercontent.com/OpenModelica/OMSimulator/master/schema/oms.xsd",
    "emcosim": "urn:emcosim:ssp:annotations",
}
OSP_ANNOTATION = "com.opensimulationplatform"
OMS_ANNOTATION = "org.openmodelica"
EMCOSIM_ANNOTATION = "org.emcosim"    # our master's default coupling (<emcosim:Coupling method="implicit"/>)
COUPLINGS = ("explicit", "implicit")
PARAMETER_SET = "initialValues"       # the one name of every .ssv set: `ecos` applies the sets of the name it is given
SSD_NAME = "SystemStructure.ssd"
TYPES = ("Real", "Integer", "Boolean", "String")


@dataclass
class Connector:
    name: str
    kind: str                 # input, output, parameter, calculatedParameter, inout
    type: str                 # Real, Integer, Boolean, String
    unit: str | None = None   # `unit` of its ssc:Real, if given
    unit_definition: Unit | None = None      # from the .ssd's ssd:Units (None: not defined there)


@dataclass
class Parameter:
    """A parameter value of an .ssv file (or a start value a caller gives)."""

    name: str
    type: str
    value: float | int | bool | str
    unit: str | None = None
    description: str | None = None          # written as an XML comment before the parameter
    unit_definition: Unit | None = None      # from the .ssv's ssv:Units (None: not defined there)


@dataclass
class Component:
    name: str
    source: Path                             # the FMU, resolved against the .ssd's folder
    connectors: list[Connector] = field(default_factory=list)
    parameters: dict[str, Parameter] = field(default_factory=dict)
    parameter_sources: list[str] = field(default_factory=list)   # .ssv files as written in the .ssd
    description: str | None = None


@dataclass
class Connection:
    start_element: str
    start_connector: str
    end_element: str
    end_connector: str
    factor: float = 1.0                      # ssc:LinearTransformation: end = factor * start + offset
    offset: float = 0.0
    suppress_unit_conversion: bool = False   # SSP: only the LinearTransformation, no unit conversion

    @property
    def start(self) -> str:
        return f"{self.start_element}.{self.start_connector}"

    @property
    def end(self) -> str:
        return f"{self.end_element}.{self.end_connector}"


@dataclass
class Scenario:
    """A flat system of FMU components, as the master runs it."""

    name: str
    path: Path                               # the .ssd file
    components: list[Component]
    connections: list[Connection]
    start_time: float = 0.0
    stop_time: float | None = None
    step_size: float | None = None
    description: str | None = None
    notes: list[str] = field(default_factory=list)   # XML comments of the .ssd (documentation)
    coupling: str | None = None              # "explicit" or "implicit": our master's default (None: explicit)

    def hold_step(self, step_size: float | None, engine: str) -> float | None:
        """The communication step of an engine that holds each input over a step (a zero-order hold:
        the container FMU, libcosim, ecos): `step_size`, else the default step, unless the scenario chose
        it for implicit coupling: on such a stiff loop a hold needs a far shorter step, and a run at that
        default returns finite but wrong numbers (measured: docs/scenarios.md, "Other engines"), so it is
        refused with a ScenarioError."""
        if step_size is not None:
            return step_size
        if self.coupling == "implicit":
            raise ScenarioError(f"{self.name}: its default step {self.step_size:g} s is for implicit coupling; {engine} "
                                "holds each input over a step (zero-order hold), which this stiff loop needs a far "
                                "shorter step for: give the step size (docs/scenarios.md, \"Other engines\")")
        return self.step_size

    def component(self, name: str) -> Component:
        for c in self.components:
            if c.name == name:
                return c
        raise ScenarioError(f"{self.path}: no component named '{name}' "
                            f"(components: {', '.join(c.name for c in self.components)})")


def with_values(scenario: Scenario, values: dict[str, float]) -> Scenario:
    """A copy of the scenario whose parameter sets hold `values` ("component.parameter" -> a Real value)."""
    s = copy.deepcopy(scenario)
    for name, value in values.items():
        comp_name, _, var = name.partition(".")
        s.component(comp_name).parameters[var] = Parameter(var, "Real", float(value))
    return s


# ---- reading --------------------------------------------------------------------------------------

def resolve_path(path: str | Path, scenario_dirs: list[Path] | None = None,
                 limits: ArchiveLimits | None = None) -> Path:
    """The .ssd file of a scenario given as an .ssd file, a folder holding SystemStructure.ssd,
    an .ssp archive (unpacked to a temporary folder, within `limits`), or a bare name looked up in
    scenario_dirs."""
    p = Path(path)
    if not p.exists() and scenario_dirs and len(p.parts) == 1:
        for d in scenario_dirs:
            if (d / p).exists():
                p = d / p
                break
    if p.is_dir():
        p = p / SSD_NAME
        if not p.is_file():
            raise ScenarioError(f"{path}: folder has no {SSD_NAME}")
        return p
    if not p.is_file():
        raise ScenarioError(f"{path}: scenario not found (give an .ssd file, a scenario folder or an .ssp archive)")
    if p.suffix == ".ssp":
        limits = limits or ArchiveLimits()
        target = tempdirs.make(p.stem)
        atexit.register(shutil.rmtree, target, True)
        extract_archive(p, target, limits)
        if not (target / SSD_NAME).is_file():
            raise ScenarioError(f"{p}: archive has no {SSD_NAME}")
        unpacked[target.resolve()] = (p, limits)
        return target / SSD_NAME
    return p


def read_scenario(path: str | Path, scenario_dirs: list[Path] | None = None,
                  fmu_dir: str | Path | None = None, limits: ArchiveLimits | None = None) -> Scenario:
    """Parse a scenario (see `resolve_path`) with its .ssv parameter files. With `fmu_dir`, every
    component's FMU is taken from that folder (same file name) instead of its `source` path."""
    ssd = resolve_path(path, scenario_dirs, limits)
    root, notes = parse(ssd, comments=True)
    if root.tag != _q("ssd", "SystemStructureDescription"):
        raise ScenarioError(f"{ssd}: root element is {root.tag}, expected ssd:SystemStructureDescription")
    system = _child(root, "ssd", "System", ssd)
    units = _units(root.find("ssd:Units", NS), ssd)
    components = []
    elements = system.find("ssd:Elements", NS)
    for el in [] if elements is None else elements:
        if el.tag != _q("ssd", "Component"):
            raise ScenarioError(f"{ssd}: element {el.tag} is not supported (only ssd:Component FMUs)")
        components.append(_read_component(el, ssd, units, check_source=fmu_dir is None))
    names = [c.name for c in components]
    if len(set(names)) != len(names):
        raise ScenarioError(f"{ssd}: duplicate component names in {names}")
    connections = []
    for el in system.findall("ssd:Connections/ssd:Connection", NS):
        lt = el.find("ssc:LinearTransformation", NS)
        connections.append(Connection(
            _attr(el, "startElement", ssd), _attr(el, "startConnector", ssd),
            _attr(el, "endElement", ssd), _attr(el, "endConnector", ssd),
            factor=_float(lt.get("factor", "1"), ssd, "LinearTransformation factor") if lt is not None else 1.0,
            offset=_float(lt.get("offset", "0"), ssd, "LinearTransformation offset") if lt is not None else 0.0,
            suppress_unit_conversion=_bool(el.get("suppressUnitConversion", "false"), ssd,
                                           "Connection suppressUnitConversion")))
    scenario = Scenario(name=root.get("name") or ssd.parent.name, path=ssd, components=components,
                        connections=connections, description=root.get("description") or system.get("description"))
    experiment = root.find("ssd:DefaultExperiment", NS)
    if experiment is not None:
        scenario.start_time = _float(experiment.get("startTime", "0"), ssd, "DefaultExperiment startTime")
        if experiment.get("stopTime") is not None:
            scenario.stop_time = _float(experiment.get("stopTime"), ssd, "DefaultExperiment stopTime")
        algo = experiment.find(f"ssd:Annotations/ssc:Annotation[@type='{OSP_ANNOTATION}']"
                               "/osp:Algorithm/osp:FixedStepAlgorithm", NS)
        if algo is not None:
            scenario.step_size = _float(_attr(algo, "baseStepSize", ssd), ssd, "baseStepSize")
        coupling = experiment.find(f"ssd:Annotations/ssc:Annotation[@type='{EMCOSIM_ANNOTATION}']"
                                   "/emcosim:Coupling", NS)
        if coupling is not None:
            scenario.coupling = _attr(coupling, "method", ssd)
            if scenario.coupling not in COUPLINGS:
                raise ScenarioError(f"{ssd}: emcosim:Coupling method=\"{scenario.coupling}\" must be one of "
                                    f"{', '.join(COUPLINGS)}")
    scenario.notes = notes
    if fmu_dir is not None:
        for comp in components:
            comp.source = Path(fmu_dir).resolve() / comp.source.name
    for conn in connections:                          # names must exist; FMU checks come later
        for element, connector in ((conn.start_element, conn.start_connector), (conn.end_element, conn.end_connector)):
            comp = scenario.component(element)
            if comp.connectors and connector not in {c.name for c in comp.connectors}:
                raise ScenarioError(f"{ssd}: connection {conn.start} -> {conn.end}: component '{element}' "
                                    f"has no connector '{connector}'")
    return scenario


def read_parameter_set(path: Path) -> dict[str, Parameter]:
    """Parameters of an .ssv file, by name."""
    root = parse(path)
    if root.tag != _q("ssv", "ParameterSet"):
        raise ScenarioError(f"{path}: root element is {root.tag}, expected ssv:ParameterSet")
    return _read_parameters(root, path, _units(root.find("ssv:Units", NS), path))


def _read_component(el: ET.Element, ssd: Path, units: dict[str, Unit], check_source: bool = True) -> Component:
    name = _attr(el, "name", ssd)
    source = _attr(el, "source", ssd)
    if check_source:
        check_inside(ssd, source, f"component '{name}': source")
    comp = Component(name=name, source=(ssd.parent / source).resolve(), description=el.get("description"))
    for c in el.findall("ssd:Connectors/ssd:Connector", NS):
        types = [t for t in TYPES if c.find(f"ssc:{t}", NS) is not None]
        if len(types) != 1:
            raise ScenarioError(f"{ssd}: connector {name}.{c.get('name')} needs exactly one of "
                                f"ssc:{', ssc:'.join(TYPES)}")
        unit = c.find(f"ssc:{types[0]}", NS).get("unit")
        comp.connectors.append(Connector(_attr(c, "name", ssd), _attr(c, "kind", ssd), types[0],
                                         unit=unit, unit_definition=units.get(unit) if unit else None))
    for binding in el.findall("ssd:ParameterBindings/ssd:ParameterBinding", NS):
        prefix = binding.get("prefix", "")
        src = binding.get("source")
        if src is not None:
            check_inside(ssd, src, f"component '{name}': parameter binding")
            comp.parameter_sources.append(src)
            values = read_parameter_set(ssd.parent / src)
        else:
            inline = binding.find("ssd:ParameterValues/ssv:ParameterSet", NS)
            if inline is None:
                raise ScenarioError(f"{ssd}: ParameterBinding of '{name}' has neither a source nor ParameterValues")
            values = _read_parameters(inline, ssd, _units(inline.find("ssv:Units", NS), ssd))
        _bind(comp, values, prefix, src or ssd)
    return comp


def _bind(comp: Component, values: dict[str, Parameter], prefix: str, where: str | Path) -> None:
    """A binding's values into the component (a later binding takes priority over an earlier one, as
    SSP says); two names of one binding that are one variable without the prefix are refused."""
    seen: dict[str, str] = {}
    for pname, p in values.items():
        p.name = pname[len(prefix):] if prefix and pname.startswith(prefix) else pname
        if p.name in seen:
            raise ScenarioError(f"{where}: parameters {seen[p.name]} and {pname} both set {comp.name}.{p.name} "
                                f"(binding prefix {prefix!r}); keep one")
        seen[p.name] = pname
        comp.parameters[p.name] = p


def _read_parameters(root: ET.Element, path: Path, units: dict[str, Unit]) -> dict[str, Parameter]:
    """The parameters of a ParameterSet by name; a name given twice is refused, naming both entries
    (which one a tool applies is not defined: emcosim applied the second, others may take the first)."""
    params: dict[str, Parameter] = {}
    where: dict[str, tuple[int, str]] = {}               # name -> (position in the set, value as written)
    for k, p in enumerate(root.findall("ssv:Parameters/ssv:Parameter", NS), 1):
        name = _attr(p, "name", path)
        kinds = [t for t in TYPES if p.find(f"ssv:{t}", NS) is not None]
        if len(kinds) != 1:
            raise ScenarioError(f"{path}: parameter {name} needs exactly one of ssv:{', ssv:'.join(TYPES)}")
        v = p.find(f"ssv:{kinds[0]}", NS)
        raw = _attr(v, "value", path)
        if name in where:
            first, value = where[name]
            raise ScenarioError(f"{path}: parameter {name} is set twice: ssv:Parameter {first} (value {value!r}) "
                                f"and ssv:Parameter {k} (value {raw!r}) of the set; keep one")
        where[name] = (k, raw)
        unit = v.get("unit")
        params[name] = Parameter(name, kinds[0], parse_value(raw, kinds[0], f"{path}: parameter {name}"),
                                 unit=unit, unit_definition=units.get(unit) if unit else None)
    return params


def _units(element: ET.Element | None, path: Path) -> dict[str, Unit]:
    try:
        return parse_units(element, NS, str(path))
    except ValueError as exc:
        raise ScenarioError(str(exc)) from None


def _bool(raw: str, path: Path, what: str) -> bool:
    if raw.strip() not in ("true", "false", "1", "0"):
        raise ScenarioError(f"{path}: {what} = {raw!r} is not a boolean (true or false)")
    return raw.strip() in ("true", "1")


def parse_value(raw: str, type_: str, where: str) -> float | int | bool | str:
    """A value of an FMI/SSP type from its text."""
    try:
        if type_ == "Real":
            return float(raw)
        if type_ == "Integer":
            return int(raw)
        if type_ == "Boolean":
            if raw.strip().lower() not in ("true", "false", "1", "0"):
                raise ValueError(raw)
            return raw.strip().lower() in ("true", "1")
        return raw
    except ValueError:
        raise ScenarioError(f"{where}: value {raw!r} is not a valid {type_}") from None


class _Comments(ET.TreeBuilder):
    """A tree builder that also collects every comment (those before the root element too)."""

    def __init__(self, insert_comments: bool = False):
        super().__init__(insert_comments=insert_comments)
        self.comments: list[str] = []

    def comment(self, text):
        self.comments.append(" ".join(text.split()))
        return super().comment(text)


def parse(path: Path, comments: bool = False, insert_comments: bool = False):
    """The root element of an XML file (and with `comments`, its comments, whitespace collapsed;
    with `insert_comments`, the comments inside the root element are kept in the tree).
    Any encoding XML allows is read: expat decodes UTF-8, UTF-16 and ISO-8859-1 itself; for others
    declared in the XML declaration (windows-1252, Shift_JIS, ...) the text is decoded here."""
    try:
        data = Path(path).read_bytes()
    except FileNotFoundError:
        raise ScenarioError(f"{path}: file not found") from None
    except OSError as exc:
        raise ScenarioError(f"{path}: cannot read ({exc.strerror or exc})") from None
    try:
        root, found = _parse_xml(data, insert_comments)
    except (ET.ParseError, ValueError) as exc:          # ValueError: "multi-byte encodings are not supported"
        text = _decode_declared(data)
        if text is None:
            raise ScenarioError(f"{path}: malformed XML ({exc})") from None
        try:
            root, found = _parse_xml(text, insert_comments)
        except ET.ParseError as exc2:
            raise ScenarioError(f"{path}: malformed XML ({exc2})") from None
    return (root, found) if comments else root


def _parse_xml(source: bytes | str, insert_comments: bool):
    """(root element, comments) of an XML document given as bytes or as decoded text."""
    target = _Comments(insert_comments)
    parser = ET.XMLParser(target=target)
    parser.feed(source)
    return parser.close(), target.comments


_DECLARATION = re.compile(rb"""^<\?xml[^>]*?encoding\s*=\s*["']([A-Za-z][A-Za-z0-9._-]*)["']""")


def _decode_declared(data: bytes) -> str | None:
    """The text of an XML document in an encoding expat does not know, decoded with Python's codec
    of the declared encoding and its declaration rewritten to UTF-8; None if there is nothing to do
    (no such declaration, unknown codec, or bytes that are not in that encoding)."""
    match = _DECLARATION.match(data)
    if not match:
        return None
    try:
        name = codecs.lookup(match.group(1).decode("ascii")).name
        if name in ("utf-8", "utf-16", "iso8859-1", "ascii"):
            return None                        # expat knows these: the error is in the XML itself
        text = data.decode(name)
    except (LookupError, UnicodeDecodeError):
        return None
    return text.replace(match.group(1).decode("ascii"), "UTF-8", 1)


def _q(prefix: str, tag: str) -> str:
    return f"{{{NS[prefix]}}}{tag}"


def _child(el: ET.Element, prefix: str, tag: str, path: Path) -> ET.Element:
    c = el.find(f"{prefix}:{tag}", NS)
    if c is None:
        raise ScenarioError(f"{path}: missing element {prefix}:{tag}")
    return c


def _attr(el: ET.Element, name: str, path: Path) -> str:
    v = el.get(name)
    if v is None:
        tag = el.tag.split("}")[-1]
        raise ScenarioError(f"{path}: element {tag} {el.get('name', '')} lacks attribute '{name}'".replace("  ", " "))
    return v


def finite_number(text: str, where: str) -> float:
    """`text` as a finite float, or a ScenarioError "where = 'text' is not a number / not finite"."""
    try:
        x = float(text)
    except ValueError:
        raise ScenarioError(f"{where} = {text.strip()!r} is not a number") from None
    if not math.isfinite(x):
        raise ScenarioError(f"{where} = {text.strip()!r} is not finite")
    return x


def _float(raw: str, path: Path, what: str) -> float:
    return finite_number(raw, f"{path}: {what}")


# the namespaces' prefixes when a scenario is written (ssd_writer.py, ssp.py)
for _prefix, _uri in NS.items():
    ET.register_namespace(_prefix, _uri)
