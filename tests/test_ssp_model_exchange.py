"""`pack_ssp(..., model_exchange=True)`: an archive whose System OMSimulator runs as a strongly coupled
system, every FMU as Model Exchange under its CVODE (docs/ssp-engines.md, "Model Exchange in
OMSimulator"). OMSimulator is not needed: these tests check what it reads (OpenModelica's annotation,
first in the System's annotations, an `oms:VariableStepSolver` with all five attributes: OMSimulator
2.1.3 reads a missing one as 0 and hangs on maximumStepSize 0), that the archive still runs in our
engine as Model Exchange and as Co-Simulation, and that the default archive has not changed.
"""
from __future__ import annotations

import io
import re
import shutil
import zipfile
from pathlib import Path
from xml.etree import ElementTree as ET

import numpy as np
import pytest

from emcosim.engine.errors import ScenarioError
from emcosim.engine.master import simulate
from emcosim.engine.ssd import NS, OMS_ANNOTATION, OSP_ANNOTATION, SSD_NAME, read_scenario
from emcosim.engine.ssd_writer import VariableStepSolver
from emcosim.engine.ssp import INITIAL_STEP_FRACTION, MINIMUM_STEP_FRACTION, pack_ssp
from fmus.build import repack

ROOT = Path(__file__).resolve().parents[1]
FIVE = ("description", "absoluteTolerance", "relativeTolerance", "minimumStepSize", "maximumStepSize",
        "initialStepSize")          # description and the five numbers OMSimulator's SystemSC reads


def _ssd(archive: Path) -> ET.Element:
    with zipfile.ZipFile(archive) as z:
        return ET.fromstring(z.read(SSD_NAME))


def _oms_annotations(root: ET.Element) -> list[ET.Element]:
    system = root.find("ssd:System", NS)
    return [a for a in system.findall("ssd:Annotations/ssc:Annotation", NS) if a.get("type") == OMS_ANNOTATION]


def _solver(root: ET.Element) -> dict[str, str]:
    """The attributes of the System's one oms:VariableStepSolver, checked to be where OMSimulator looks
    (Model::getSystemType: the first org.openmodelica annotation, its oms:SimulationInformation)."""
    system = root.find("ssd:System", NS)
    first = system.find("ssd:Annotations/ssc:Annotation", NS)
    assert first is not None and first.get("type") == OMS_ANNOTATION
    assert len(_oms_annotations(root)) == 1
    info = first.findall("oms:Annotations/oms:SimulationInformation", NS)
    assert len(info) == 1
    children = list(info[0])
    assert [c.tag for c in children] == [f"{{{NS['oms']}}}VariableStepSolver"], [c.tag for c in children]
    return dict(children[0].attrib)


def _normalized(archive: Path, tmp_path: Path) -> bytes:
    """The archive's bytes with sorted entries and fixed timestamps (as build.py writes build/ssp)."""
    out = tmp_path / f"n_{archive.name}"
    repack(archive, out)
    return out.read_bytes()


@pytest.fixture
def tracking(fmu_dir):
    return read_scenario(ROOT / "scenarios" / "mems_tracking_Dd-0.4", fmu_dir=fmu_dir)


def test_model_exchange_archive_has_the_strongly_coupled_annotation(tracking, tmp_path):
    archive = pack_ssp(tracking, tmp_path / "me.ssp", model_exchange=True, relative_tolerance=1e-8,
                       absolute_tolerance=1e-7)
    root = _ssd(archive)
    attrs = _solver(root)
    assert set(attrs) == set(FIVE), attrs
    assert attrs["description"] == "cvode"
    h = tracking.step_size
    assert float(attrs["relativeTolerance"]) == 1e-8
    assert float(attrs["absoluteTolerance"]) == 1e-7
    assert float(attrs["maximumStepSize"]) == h                       # OMSimulator's output grid: ours
    assert float(attrs["initialStepSize"]) == pytest.approx(INITIAL_STEP_FRACTION * h, rel=1e-2)
    assert float(attrs["minimumStepSize"]) == pytest.approx(MINIMUM_STEP_FRACTION * h, rel=1e-2)
    text = ET.tostring(root, encoding="unicode")
    assert "FixedStepMaster" not in text                              # no weakly coupled master left
    # what libcosim and our engine read is still there
    osp = root.find(f"ssd:DefaultExperiment/ssd:Annotations/ssc:Annotation[@type='{OSP_ANNOTATION}']"
                    "/osp:Algorithm/osp:FixedStepAlgorithm", NS)
    assert float(osp.get("baseStepSize")) == h
    # absolute tolerance defaults to the relative one; explicit step sizes are written as given
    root = _ssd(pack_ssp(tracking, tmp_path / "me2.ssp", model_exchange=True, relative_tolerance=1e-9,
                         step_sizes=(1e-14, 1e-20, 1e-6)))
    attrs = _solver(root)
    assert [float(attrs[k]) for k in FIVE[1:]] == [1e-9, 1e-9, 1e-20, 1e-6, 1e-14]


def test_model_exchange_archive_is_valid_ssp(tracking, tmp_path):
    etree = pytest.importorskip("lxml.etree")
    import fmpy
    archive = pack_ssp(tracking, tmp_path / "me.ssp", model_exchange=True)
    schema = etree.XMLSchema(etree.parse(str(Path(fmpy.__file__).parent / "ssp" / "schema"
                                             / "SystemStructureDescription.xsd")))
    with zipfile.ZipFile(archive) as z:
        doc = etree.fromstring(z.read(SSD_NAME))
    assert schema.validate(doc), schema.error_log.last_error


def test_model_exchange_archive_runs_in_our_engine(tracking, tmp_path):
    """Read back, the archive is the same scenario: our Model Exchange and Co-Simulation runs of it
    equal those of the scenario folder."""
    archive = pack_ssp(tracking, tmp_path / "me.ssp", model_exchange=True, relative_tolerance=1e-8)
    back = read_scenario(archive)
    assert back.step_size == tracking.step_size and back.stop_time == tracking.stop_time
    assert back.coupling == tracking.coupling
    t_end = 20 * tracking.step_size
    me = {"interface_type": "ModelExchange", "rtol": 1e-9, "solver": "Radau"}
    a = simulate(back, stop_time=t_end, record=["plant.q", "controller.u"], **me)
    b = simulate(tracking, stop_time=t_end, record=["plant.q", "controller.u"], **me)
    assert len(a.time) == 21
    np.testing.assert_array_equal(a["plant.q"], b["plant.q"])
    np.testing.assert_array_equal(a["controller.u"], b["controller.u"])
    assert np.ptp(a["plant.q"]) > 0                                   # it moved: the parameters were applied
    c = simulate(back, stop_time=t_end, record=["plant.q"])
    d = simulate(tracking, stop_time=t_end, record=["plant.q"])
    np.testing.assert_array_equal(c["plant.q"], d["plant.q"])
    np.testing.assert_array_equal(c.time, a.time)


def test_default_archive_is_unchanged(tracking, tmp_path):
    """Without the keyword (or with it False, whatever the tolerances) the archive is what pack_ssp
    always wrote: the same bytes, and the .ssd's own fixed-step annotation untouched."""
    plain = _normalized(pack_ssp(tracking, tmp_path / "a.ssp"), tmp_path)
    off = _normalized(pack_ssp(tracking, tmp_path / "b.ssp", model_exchange=False, relative_tolerance=1e-3,
                               absolute_tolerance=1e-2, step_sizes=(1e-9, 1e-12, 1e-3)), tmp_path)
    assert plain == off
    me = _normalized(pack_ssp(tracking, tmp_path / "c.ssp", model_exchange=True), tmp_path)
    assert me != plain
    with zipfile.ZipFile(io.BytesIO(plain)) as z:
        root = ET.fromstring(z.read(SSD_NAME))
    source = ET.parse(tracking.path).getroot()
    [ours], [theirs] = _oms_annotations(root), _oms_annotations(source)
    assert ET.tostring(ours) == ET.tostring(theirs)
    master = ours.find("oms:Annotations/oms:SimulationInformation/oms:FixedStepMaster", NS)
    assert float(master.get("stepSize")) == tracking.step_size
    # only the System's OpenModelica annotation differs between the two archives
    with zipfile.ZipFile(io.BytesIO(me)) as z:
        me_root = ET.fromstring(z.read(SSD_NAME))
    for r in (root, me_root):
        system = r.find("ssd:System/ssd:Annotations", NS)
        for a in _oms_annotations(r):
            system.remove(a)
    assert ET.tostring(root) == ET.tostring(me_root)


def test_hand_written_scenario_gets_the_annotation(fmu_dir, tmp_path):
    """A scenario with no OpenModelica annotation and no step size: the annotation is added, with the
    step sizes given (without them, and without a step size to derive them from, packing is refused)."""
    folder = tmp_path / "loop"
    shutil.copytree(ROOT / "scenarios" / "maglev_regulation_prop2", folder)
    ssd = folder / "SystemStructure.ssd"
    text = re.sub(r"\s*<ssd:Annotations>\s*<ssc:Annotation type=\"org.openmodelica\">.*?</ssd:Annotations>", "",
                  ssd.read_text(), count=1, flags=re.S)
    text = re.sub(r"\s*<ssc:Annotation type=\"com.opensimulationplatform\">.*?</ssc:Annotation>", "", text,
                  count=1, flags=re.S)
    ssd.write_text(text)
    s = read_scenario(folder, fmu_dir=fmu_dir)
    assert s.step_size is None and OMS_ANNOTATION not in text
    with pytest.raises(ScenarioError, match="step_sizes"):
        pack_ssp(s, tmp_path / "x.ssp", model_exchange=True)
    attrs = _solver(_ssd(pack_ssp(s, tmp_path / "y.ssp", model_exchange=True, step_sizes=(0.0, 1e-12, 0.01))))
    assert float(attrs["maximumStepSize"]) == 0.01 and float(attrs["initialStepSize"]) == 0.0


@pytest.mark.parametrize("kwargs", [
    {"relative_tolerance": 0.0},                          # CVODE: "Initial ewt has component(s) equal to zero"
    {"step_sizes": (1e-6, 1e-12, 0.0)},                   # OMSimulator 2.1.3 hangs on maximumStepSize 0
    {"step_sizes": (1e-2, 1e-12, 1e-3)},                  # initial above maximum
    {"step_sizes": (1e-6, 1e-2, 1e-3)},                   # minimum above maximum
])
def test_bad_solver_settings_are_refused(tracking, tmp_path, kwargs):
    with pytest.raises(ValueError):
        pack_ssp(tracking, tmp_path / "bad.ssp", model_exchange=True, **kwargs)
    assert not (tmp_path / "bad.ssp").exists()


def test_solver_method_is_checked():
    with pytest.raises(ValueError, match="cvode"):
        VariableStepSolver(1e-6, 1e-6, 1e-9, 1e-15, 1e-3, method="rk4")


def _cli(args: list[str]) -> tuple[int, str]:
    import subprocess
    import sys
    proc = subprocess.run([sys.executable, "-m", "emcosim.cli", *args], capture_output=True, text=True, timeout=300,
                          cwd=ROOT)
    return proc.returncode, proc.stdout + proc.stderr


def test_pack_on_the_command_line_writes_the_model_exchange_archive(fmu_dir, tmp_path):
    """`emcosim pack NAME -o x.ssp --model-exchange --rtol R`: the archive pack_ssp writes (the annotation
    with R), and it runs in our engine as Model Exchange like its scenario folder."""
    out = tmp_path / "m.ssp"
    rc, text = _cli(["pack", "maglev_regulation_prop2", "-o", str(out), "--model-exchange", "--rtol", "1e-8",
                     "--fmu-dir", str(fmu_dir)])
    assert rc == 0 and "Model Exchange" in text, text
    attrs = _solver(_ssd(out))
    assert float(attrs["relativeTolerance"]) == 1e-8 and float(attrs["absoluteTolerance"]) == 1e-8
    assert float(attrs["maximumStepSize"]) == 0.02                  # the scenario's step
    folder = read_scenario(ROOT / "scenarios" / "maglev_regulation_prop2", fmu_dir=fmu_dir)
    a = simulate(read_scenario(out), stop_time=1.0, interface_type="ModelExchange")
    b = simulate(folder, stop_time=1.0, interface_type="ModelExchange")
    assert np.array_equal(np.array(a.rows), np.array(b.rows))
    rc, text = _cli(["pack", "maglev_regulation_prop2", "-o", str(tmp_path / "c.ssp"), "--fmu-dir", str(fmu_dir)])
    assert rc == 0 and _oms_annotations(_ssd(tmp_path / "c.ssp")) and not _ssd(tmp_path / "c.ssp").findall(
        ".//oms:VariableStepSolver", NS)


@pytest.mark.parametrize("args, words", [
    (["-o", "{tmp}/x.zip"], "is named NAME.ssp"),
    (["-o", "{tmp}/x.ssp", "--model-exchange", "--rtol", "2"], "--rtol 2: must be a number between 0 and 1"),
    (["-o", "{tmp}/x.ssp", "--model-exchange", "--rtol", "0"], "--rtol 0: must be a number between 0 and 1"),
    (["-o", "{tmp}/link.ssp"], "symbolic link"),
    (["-o", "{tmp}/missing/x.ssp"], "missing"),
])
def test_pack_refuses_bad_arguments_in_one_line_and_writes_nothing(fmu_dir, tmp_path, args, words):
    victim = tmp_path / "victim.txt"
    victim.write_text("mine\n")
    (tmp_path / "link.ssp").symlink_to(victim)
    before = sorted(p.name for p in tmp_path.iterdir())
    rc, text = _cli(["pack", "maglev_regulation_prop2", "--fmu-dir", str(fmu_dir),
                     *[a.replace("{tmp}", str(tmp_path)) for a in args]])
    assert rc == 1 and words in text and "Traceback" not in text, text
    assert sorted(p.name for p in tmp_path.iterdir()) == before and victim.read_text() == "mine\n"
