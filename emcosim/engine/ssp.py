"""Pack a scenario into a self-contained SSP archive (.ssp): SystemStructure.ssd at the root,
its .ssv files beside it and every FMU under resources/, with the .ssd's `source` attributes
rewritten to point there. Other SSP tools (libcosim, OMSimulator, ...) open such archives."""
from __future__ import annotations

import zipfile
from pathlib import Path
from xml.etree import ElementTree as ET

from .errors import ScenarioError
from .ssd import NS, SSD_NAME, Scenario, _parse, read_scenario, resolve_path


def pack_ssp(scenario: str | Path | Scenario, output: str | Path, fmu_dir: str | Path | None = None) -> Path:
    """Write the scenario (an .ssd file or its folder, or a parsed Scenario whose component sources
    are used) with its FMUs to the archive `output`. With `fmu_dir`, FMUs are taken from there."""
    if isinstance(scenario, Scenario):
        parsed, ssd = scenario, scenario.path
    else:
        ssd = resolve_path(scenario)
        parsed = read_scenario(ssd, fmu_dir=fmu_dir)  # checks the files before packing
    tree = ET.ElementTree(_parse(ssd, insert_comments=True))      # any encoding; written as UTF-8
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
    ssvs = {src for c in parsed.components for src in c.parameter_sources}
    output = Path(output)
    output.parent.mkdir(parents=True, exist_ok=True)
    with zipfile.ZipFile(output, "w", zipfile.ZIP_DEFLATED) as z:
        z.writestr(SSD_NAME, '<?xml version="1.0" encoding="UTF-8"?>\n'
                   + ET.tostring(tree.getroot(), encoding="unicode") + "\n")
        for src in sorted(ssvs):
            z.write(ssd.parent / src, src)
        for target, path in sorted(fmus.items()):
            z.write(path, target)
    return output
