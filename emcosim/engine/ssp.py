"""Pack a scenario into a self-contained SSP archive (.ssp): SystemStructure.ssd at the root,
its .ssv files beside it and every FMU under resources/, with the .ssd's `source` attributes
rewritten to point there. Other SSP engines run such archives as they are (docs/ssp-engines.md):
the archive's model and System names are identifiers (`ssd.identifier`, for OMSimulator), its
System has OpenModelica's fixed-step annotation beside the OSP one, and every .ssv parameter set is
named `ssd.PARAMETER_SET` (ecos applies only the set it is told to)."""
from __future__ import annotations

import zipfile
from pathlib import Path
from xml.etree import ElementTree as ET

from .errors import ScenarioError
from .ssd import NS, OMS_ANNOTATION, PARAMETER_SET, SSD_NAME, Scenario, parse, read_scenario, resolve_path
from .ssd_writer import identifier, oms_annotation


def pack_ssp(scenario: str | Path | Scenario, output: str | Path, fmu_dir: str | Path | None = None) -> Path:
    """Write the scenario (an .ssd file or its folder, or a parsed Scenario whose component sources
    are used) with its FMUs to the archive `output`. With `fmu_dir`, FMUs are taken from there."""
    if isinstance(scenario, Scenario):
        parsed, ssd = scenario, scenario.path
    else:
        ssd = resolve_path(scenario)
        parsed = read_scenario(ssd, fmu_dir=fmu_dir)  # checks the files before packing
    tree = ET.ElementTree(parse(ssd, insert_comments=True))      # any encoding; written as UTF-8
    fmus: dict[str, Path] = {}
    for el in tree.getroot().iterfind("ssd:System/ssd:Elements/ssd:Component", NS):
        comp = parsed.component(el.get("name"))
        if not comp.source.is_file():
            raise ScenarioError(f"{ssd}: component '{comp.name}': FMU not found: {comp.source} (build it first)")
        target = f"resources/{comp.source.name}"
        if fmus.get(target, comp.source) != comp.source:
            raise ScenarioError(f"{ssd}: two different FMUs are named {comp.source.name}")
        fmus[target] = comp.source
        el.set("source", target)
    _make_portable(tree.getroot(), parsed.step_size)
    ssvs = {src for c in parsed.components for src in c.parameter_sources}
    output = Path(output)
    output.parent.mkdir(parents=True, exist_ok=True)
    with zipfile.ZipFile(output, "w", zipfile.ZIP_DEFLATED) as z:
        z.writestr(SSD_NAME, '<?xml version="1.0" encoding="UTF-8"?>\n'
                   + ET.tostring(tree.getroot(), encoding="unicode") + "\n")
        for src in sorted(ssvs):
            z.writestr(src, _named_parameter_set(ssd.parent / src))
        for target, path in sorted(fmus.items()):
            z.write(path, target)
    return output


def _make_portable(root: ET.Element, step_size: float | None) -> None:
    """Identifier names for the model and its System; OpenModelica's fixed-step annotation first in
    the System's annotations (added when the .ssd has none and a step size is known)."""
    root.set("name", identifier(root.get("name") or "model"))
    system = root.find("ssd:System", NS)
    system.set("name", identifier(system.get("name") or root.get("name")))
    annotations = system.find("ssd:Annotations", NS)
    has_oms = annotations is not None and any(a.get("type") == OMS_ANNOTATION
                                              for a in annotations.findall("ssc:Annotation", NS))
    if has_oms or step_size is None:
        return
    if annotations is None:
        annotations = ET.SubElement(system, f"{{{NS['ssd']}}}Annotations")
    xml = f'<root xmlns:ssc="{NS["ssc"]}" xmlns:oms="{NS["oms"]}">{"".join(oms_annotation(step_size))}</root>'
    annotations.insert(0, ET.fromstring(xml)[0])


def _named_parameter_set(path: Path) -> str:
    """The text of an .ssv file whose ParameterSet is named PARAMETER_SET (comments kept)."""
    tree = ET.parse(path, ET.XMLParser(target=ET.TreeBuilder(insert_comments=True)))
    tree.getroot().set("name", PARAMETER_SET)
    return '<?xml version="1.0" encoding="UTF-8"?>\n' + ET.tostring(tree.getroot(), encoding="unicode") + "\n"
