"""Pack a scenario into a self-contained SSP archive (.ssp): SystemStructure.ssd at the root,
its .ssv files beside it and every FMU under resources/, with the .ssd's `source` attributes
rewritten to point there. Other SSP engines run such archives as they are (docs/ssp-engines.md):
the archive's model and System names are identifiers (`ssd.identifier`, for OMSimulator), its
System has OpenModelica's fixed-step annotation beside the OSP one, and every .ssv parameter set is
named `ssd.PARAMETER_SET` (ecos applies only the set it is told to).

With `model_exchange=True` the System's OpenModelica annotation is a variable-step solver instead
(`ssd_writer.VariableStepSolver`): OMSimulator then runs the System as a strongly coupled one, every FMU
as Model Exchange under its CVODE (docs/ssp-engines.md, "Model Exchange in OMSimulator"). The OSP
annotation stays: our engine and libcosim still run such an archive as Co-Simulation, and ours as Model
Exchange with `--interface-type ModelExchange`."""
from __future__ import annotations

import zipfile
from pathlib import Path
from xml.etree import ElementTree as ET

from .errors import ScenarioError
from .ssd import NS, OMS_ANNOTATION, PARAMETER_SET, SSD_NAME, Scenario, parse, read_scenario, resolve_path
from .ssd_writer import VariableStepSolver, identifier, oms_annotation, oms_solver_annotation

# Default step sizes of a Model Exchange archive, as fractions of the scenario's communication step h:
# CVODE starts at 1e-9 h and may go down to 1e-15 h (the MEMS loops' charge layer, r_e c1 (q + c0) ~ 5e-11 s,
# needs steps far below OMSimulator's default minimum of 1e-12 s at the start), and OMSimulator writes its
# results and bounds CVODE's step at h.
INITIAL_STEP_FRACTION = 1e-9
MINIMUM_STEP_FRACTION = 1e-15


def model_exchange_solver(scenario: Scenario, relative_tolerance: float = 1e-6,
                          absolute_tolerance: float | None = None,
                          step_sizes: tuple[float, float, float] | None = None) -> VariableStepSolver:
    """OMSimulator's CVODE for a Model Exchange archive of `scenario`: `absolute_tolerance` defaults to
    `relative_tolerance`, `step_sizes` (initial, minimum, maximum) to fractions of the scenario's step
    (INITIAL_STEP_FRACTION, MINIMUM_STEP_FRACTION, 1)."""
    if step_sizes is None:
        h = scenario.step_size
        if h is None:
            raise ScenarioError(f"{scenario.path}: no step size (osp:FixedStepAlgorithm) to derive OMSimulator's "
                                "step sizes from: give step_sizes=(initial, minimum, maximum)")
        step_sizes = (float(f"{INITIAL_STEP_FRACTION * h:.3g}"), float(f"{MINIMUM_STEP_FRACTION * h:.3g}"), h)
    initial, minimum, maximum = step_sizes
    return VariableStepSolver(relative_tolerance=relative_tolerance,
                              absolute_tolerance=relative_tolerance if absolute_tolerance is None else absolute_tolerance,
                              initial_step=initial, minimum_step=minimum, maximum_step=maximum)


def pack_ssp(scenario: str | Path | Scenario, output: str | Path, fmu_dir: str | Path | None = None, *,
             model_exchange: bool = False, relative_tolerance: float = 1e-6, absolute_tolerance: float | None = None,
             step_sizes: tuple[float, float, float] | None = None) -> Path:
    """Write the scenario (an .ssd file or its folder, or a parsed Scenario whose component sources
    are used) with its FMUs to the archive `output`. With `fmu_dir`, FMUs are taken from there.

    With `model_exchange`, the System's OpenModelica annotation (the .ssd's own, if any, is replaced) asks
    OMSimulator for a strongly coupled system: `model_exchange_solver(scenario, relative_tolerance,
    absolute_tolerance, step_sizes)`. Without it the tolerances and step sizes are not used: the System's
    fixed-step master gets the plants' tolerance (`fixed_step_tolerance`) as its relativeTolerance and
    absoluteTolerance, the tolerance OMSimulator passes to the FMUs when it imports the archive."""
    if isinstance(scenario, Scenario):
        parsed, ssd = scenario, scenario.path
    else:
        ssd = resolve_path(scenario)
        parsed = read_scenario(ssd, fmu_dir=fmu_dir)  # checks the files before packing
    solver = (model_exchange_solver(parsed, relative_tolerance, absolute_tolerance, step_sizes)
              if model_exchange else None)
    tolerance = None if model_exchange else fixed_step_tolerance(parsed)
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
    _make_portable(tree.getroot(), parsed.step_size, solver, tolerance)
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


def fixed_step_tolerance(scenario: Scenario) -> float | None:
    """The tolerance an archive's fixed-step master passes to the FMUs: the tightest `rtol` parameter of
    the scenario's components (its .ssv value, else the FMU's start value), None if no FMU has one.

    OMSimulator passes its System's relativeTolerance to every FMU's fmi2SetupExperiment, and the plants
    integrate at the tighter of that and their `rtol` (docs/fmus.md): with the plants' own rtol there, an
    archive imported with its tolerance gives our plants exactly the accuracy the scenario sets, in every
    engine, and an FMU that takes the master's tolerance instead gets the same number."""
    values = []
    for comp in scenario.components:
        p = comp.parameters.get("rtol")
        value = p.value if p is not None and p.type == "Real" else _fmu_start(comp.source, "rtol")
        try:
            v = float(value) if value is not None else None
        except (TypeError, ValueError):
            v = None
        if v is not None and 0 < v < 1:
            values.append(v)
    return min(values) if values else None


def _fmu_start(fmu: Path, name: str) -> str | None:
    """The start value of the Real parameter `name` in the FMU's modelDescription.xml (None if none)."""
    try:
        with zipfile.ZipFile(fmu) as z:
            md = ET.fromstring(z.read("modelDescription.xml"))
    except (OSError, KeyError, zipfile.BadZipFile, ET.ParseError):
        return None
    for sv in md.iterfind("ModelVariables/ScalarVariable"):
        real = sv.find("Real")
        if sv.get("name") == name and sv.get("causality") == "parameter" and real is not None:
            return real.get("start")
    return None


def _make_portable(root: ET.Element, step_size: float | None, solver: VariableStepSolver | None = None,
                   tolerance: float | None = None) -> None:
    """Identifier names for the model and its System; OpenModelica's fixed-step annotation first in
    the System's annotations (added when the .ssd has none and a step size is known), with `tolerance`
    (if not None) as its relative and absolute tolerance (an .ssd's own annotation gets it too). With
    `solver`, its variable-step annotation replaces every OpenModelica annotation of the System, first."""
    root.set("name", identifier(root.get("name") or "model"))
    system = root.find("ssd:System", NS)
    system.set("name", identifier(system.get("name") or root.get("name")))
    annotations = system.find("ssd:Annotations", NS)
    if solver is not None:
        if annotations is None:
            annotations = ET.SubElement(system, f"{{{NS['ssd']}}}Annotations")
        old = [a for a in annotations.findall("ssc:Annotation", NS) if a.get("type") == OMS_ANNOTATION]
        tail = old[-1].tail if old else None
        for a in old:
            annotations.remove(a)
        xml = f'<root xmlns:ssc="{NS["ssc"]}" xmlns:oms="{NS["oms"]}">{"".join(oms_solver_annotation(solver))}</root>'
        new = ET.fromstring(xml)[0]
        if annotations.text and annotations.text.strip() == "":       # the .ssd is indented: so is the annotation
            ET.indent(new, space="  ", level=annotations.text.count(" ") // 2)
            new.tail = tail or annotations.text
        annotations.insert(0, new)
        return
    has_oms = annotations is not None and any(a.get("type") == OMS_ANNOTATION
                                              for a in annotations.findall("ssc:Annotation", NS))
    if not has_oms and step_size is not None:
        if annotations is None:
            annotations = ET.SubElement(system, f"{{{NS['ssd']}}}Annotations")
        xml = (f'<root xmlns:ssc="{NS["ssc"]}" xmlns:oms="{NS["oms"]}">'
               f'{"".join(oms_annotation(step_size, tolerance=tolerance))}</root>')
        annotations.insert(0, ET.fromstring(xml)[0])
    if tolerance is None or annotations is None:
        return
    for a in annotations.findall("ssc:Annotation", NS):
        if a.get("type") == OMS_ANNOTATION:
            for master in a.iterfind("oms:Annotations/oms:SimulationInformation/oms:FixedStepMaster", NS):
                master.set("absoluteTolerance", repr(tolerance))
                master.set("relativeTolerance", repr(tolerance))


def _named_parameter_set(path: Path) -> str:
    """The text of an .ssv file whose ParameterSet is named PARAMETER_SET (comments kept)."""
    tree = ET.parse(path, ET.XMLParser(target=ET.TreeBuilder(insert_comments=True)))
    tree.getroot().set("name", PARAMETER_SET)
    return '<?xml version="1.0" encoding="UTF-8"?>\n' + ET.tostring(tree.getroot(), encoding="unicode") + "\n"
