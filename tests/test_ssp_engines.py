"""Packed .ssp archives run as they are in other SSP engines (docs/ssp-engines.md).

- The archive is portable: identifier model and System names (OMSimulator refuses '.' and '-'),
  OpenModelica's fixed-step annotation first in the System's annotations (OMSimulator reads the
  master and its step there) beside the OSP one (libcosim), every .ssv parameter set named
  PARAMETER_SET (ecos applies only the set it selects), and the files still valid SSP 1.0.
- ecos (pip ecospy) runs the archives with the scenario's parameters and agrees with the monolithic
  reference as a Jacobi master should: as the libcosim cross-check of tests/test_scenarios.py, its
  error is about 3 times ours (its controller output reaches the plant one step later) and the two
  engines differ by about twice our error.
"""
from __future__ import annotations

import re
import shutil
import zipfile
from pathlib import Path
from xml.etree import ElementTree as ET

import numpy as np
import pytest

from emcosim.engine.master import simulate
from emcosim.engine.ssd import NS, OMS_ANNOTATION, OSP_ANNOTATION, PARAMETER_SET, read_scenario
from emcosim.engine.ssp import pack_ssp

ROOT = Path(__file__).resolve().parents[1]
IDENT = re.compile(r"^[A-Za-z][A-Za-z0-9_]*$")


def _archive_files(archive: Path) -> dict[str, bytes]:
    with zipfile.ZipFile(archive) as z:
        return {n: z.read(n) for n in z.namelist() if not n.startswith("resources/")}


def check_portable(archive: Path, step: float) -> None:
    files = _archive_files(archive)
    root = ET.fromstring(files["SystemStructure.ssd"])
    system = root.find("ssd:System", NS)
    assert IDENT.match(root.get("name")) and IDENT.match(system.get("name")), (root.get("name"), system.get("name"))
    first = system.find("ssd:Annotations/ssc:Annotation", NS)
    assert first.get("type") == OMS_ANNOTATION
    master = first.find("oms:Annotations/oms:SimulationInformation/oms:FixedStepMaster", NS)
    assert master.get("description") and float(master.get("stepSize")) == step
    osp = root.find(f"ssd:DefaultExperiment/ssd:Annotations/ssc:Annotation[@type='{OSP_ANNOTATION}']"
                    "/osp:Algorithm/osp:FixedStepAlgorithm", NS)
    assert float(osp.get("baseStepSize")) == step
    sets = [ET.fromstring(text) for name, text in files.items() if name.endswith(".ssv")]
    assert sets and all(s.get("name") == PARAMETER_SET for s in sets)
    etree = pytest.importorskip("lxml.etree")
    import fmpy
    schemas = Path(fmpy.__file__).parent / "ssp" / "schema"
    for xsd, names in [("SystemStructureDescription.xsd", ["SystemStructure.ssd"]),
                       ("SystemStructureParameterValues.xsd", [n for n in files if n.endswith(".ssv")])]:
        schema = etree.XMLSchema(etree.parse(str(schemas / xsd)))
        for name in names:
            assert schema.validate(etree.fromstring(files[name])), f"{name}: {schema.error_log.last_error}"


def _fixed_step_master(archive: Path) -> ET.Element:
    root = ET.fromstring(_archive_files(archive)["SystemStructure.ssd"])
    return root.find("ssd:System/ssd:Annotations/ssc:Annotation/oms:Annotations/oms:SimulationInformation/"
                     "oms:FixedStepMaster", NS)


def test_packed_paper_scenario_is_portable(fmu_dir, tmp_path):
    s = read_scenario(ROOT / "scenarios" / "maglev_tracking_D-1_R0.82", fmu_dir=fmu_dir)
    archive = pack_ssp(s, tmp_path / "m.ssp")
    check_portable(archive, s.step_size)
    assert read_scenario(archive).name == "maglev_tracking_D_1_R0_82"


@pytest.mark.parametrize("name", ["maglev_tracking_D-1_R0.82", "mems_regulation_Dd-1"])
def test_fixed_step_master_carries_the_plants_tolerance(name, fmu_dir, tmp_path):
    """OMSimulator reads relativeTolerance and absoluteTolerance of the oms:FixedStepMaster and passes
    the relative one to every FMU's fmi2SetupExperiment (when the archive is imported without a command
    line --tolerance): the archive carries the plant's rtol there (it carried OMSimulator's 1e-4 before),
    in the scenario folder and in the packed archive, also for a plant rtol changed in plant.ssv."""
    s = read_scenario(ROOT / "scenarios" / name, fmu_dir=fmu_dir)
    rtol = float(s.component("plant").parameters["rtol"].value)
    assert rtol == 1e-6
    master = _fixed_step_master(pack_ssp(s, tmp_path / "a.ssp"))
    assert float(master.get("relativeTolerance")) == rtol and float(master.get("absoluteTolerance")) == rtol
    source = ET.parse(s.path).getroot().find(".//oms:FixedStepMaster", NS)
    assert float(source.get("relativeTolerance")) == rtol
    folder = tmp_path / "tighter"
    shutil.copytree(ROOT / "scenarios" / name, folder)
    ssv = folder / "plant.ssv"
    ssv.write_text(ssv.read_text().replace('<ssv:Parameter name="rtol"><ssv:Real value="1e-06"/>',
                                           '<ssv:Parameter name="rtol"><ssv:Real value="2.5e-08"/>'))
    master = _fixed_step_master(pack_ssp(read_scenario(folder, fmu_dir=fmu_dir), tmp_path / "b.ssp"))
    assert master.get("relativeTolerance") == master.get("absoluteTolerance") == "2.5e-08"


def test_packing_makes_any_scenario_portable(fmu_dir, tmp_path):
    """A scenario written by hand (parameter sets named per component, no OpenModelica annotation,
    a name with '.' and '-') is made portable when packed; its runs are unchanged."""
    folder = tmp_path / "my-loop.v2"
    shutil.copytree(ROOT / "scenarios" / "mems_regulation_Dd-1", folder)
    ssd = folder / "SystemStructure.ssd"
    text = ssd.read_text()
    text = re.sub(r"\s*<ssd:Annotations>\s*<ssc:Annotation type=\"org.openmodelica\">.*?</ssd:Annotations>", "",
                  text, count=1, flags=re.S)
    text = re.sub(r'<ssd:System name="[^"]*">', '<ssd:System name="my-loop.v2">', text)
    ssd.write_text(text.replace('name="mems_regulation_Dd-1"', 'name="my-loop.v2"'))
    for ssv in folder.glob("*.ssv"):
        ssv.write_text(ssv.read_text().replace(f'name="{PARAMETER_SET}"', f'name="{ssv.stem}"'))
    s = read_scenario(folder, fmu_dir=fmu_dir)
    assert OMS_ANNOTATION not in ssd.read_text()
    archive = pack_ssp(s, tmp_path / "p.ssp")
    check_portable(archive, s.step_size)
    assert _fixed_step_master(archive).get("relativeTolerance") == "1e-06"     # the plant's rtol
    a = simulate(read_scenario(archive), stop_time=1e-5, record=["plant.q"])
    b = simulate(s, stop_time=1e-5, record=["plant.q"])
    np.testing.assert_array_equal(a["plant.q"], b["plant.q"])


def _ecos_or_skip():
    try:
        import ecospy  # noqa: F401
    except (ImportError, OSError) as exc:        # OSError: its native library needs Debian's libtbb12
        pytest.skip(f"ecos unavailable: {exc}")


@pytest.mark.parametrize("name", ["mems_regulation_Dd-1",
                                  pytest.param("maglev_tracking_D-1_R2.82", marks=pytest.mark.slow)])
def test_ecos_cross_check(name, fmu_dir):
    _ecos_or_skip()
    from emcosim.engine.ecos import simulate_ecos
    from emcosim.paper.reference_check import monolithic, position_error, samples_for
    s = read_scenario(ROOT / "scenarios" / name, fmu_dir=fmu_dir)
    t_end = 4e-4 if name.startswith("mems") else 2.0
    # both at a zero-order hold (ecos passes no derivatives), at a step in its asymptotic range
    h = 5e-7 if name.startswith("mems") else 5e-4
    ref = monolithic(s, stop_time=t_end, n_samples=samples_for(t_end, h, 1001))
    ours = simulate(s, stop_time=t_end, step_size=h, record=["plant.q"], coupling_order=0)
    theirs = simulate_ecos(s, stop_time=t_end, step_size=h, record=["plant.q", "controller.D_d"])
    np.testing.assert_allclose(theirs.time, ours.time, atol=1e-12)
    # the parameter set is applied: the scenario's initial state and gain, not the FMUs' defaults
    assert theirs["plant.q"][0] == s.component("plant").parameters["q_0"].value
    assert theirs["controller.D_d"][0] == s.component("controller").parameters["D_d"].value
    e_ours = position_error(ours.time, ours["plant.q"], ref, 1.0)
    e_theirs = position_error(theirs.time, theirs["plant.q"], ref, 1.0)
    diff = np.max(np.abs(theirs["plant.q"] - ours["plant.q"]))
    assert 2.5 < e_theirs / e_ours < 3.5, (e_ours, e_theirs)
    assert 1.6 < diff / e_ours < 2.4, (e_ours, diff)
