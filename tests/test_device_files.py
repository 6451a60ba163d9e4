"""Issue 31, items 5 (third bullet) and 6: a device's FMUs know their device, and `emcosim plant build |
scenario` write their outputs by the rules of the other commands (docs/reliability.md, "Devices: files and
identity"). Each test reproduces a finding of the issue as a user meets it and fails on the code before
the fix (main at f377eda): there the loop of two devices ran, a changed k_s went unsaid, a device named
"Reference" lost its plant FMU, `plant build` wrote through a link, `plant scenario` overwrote a user's
scenario and left stale files, and a killed build left its temporary folders for good.

Independent truths: the device names and the description's sha256 (hashlib, here) the FMUs must declare,
the bytes of files that must not change (a victim outside the output folder, a user's scenario), the set
of names in a folder, the lines of a results file."""
from __future__ import annotations

import hashlib
import os
import signal
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import pytest
from fmpy.validation import validate_fmu

from emcosim.cli import main
from emcosim.engine import binding, vendor
from emcosim.engine.errors import ScenarioError
from emcosim.engine.outputs import read_sidecar
from emcosim.engine.results import read_csv
from emcosim.engine.ssd import read_scenario

ROOT = Path(__file__).resolve().parents[1]
SOLENOID = ROOT / "examples" / "solenoid" / "solenoid.toml"
MEMS = ROOT / "components" / "plants" / "mems.toml"
# (at --step-size 1e-4 the run's own error estimate is 15 % of the range of u: exit 5)
SCENARIO_ARGS = ["--controller", "Proposition1", "--q0", "0.0007", "--stop-time", "0.05", "--step-size", "2e-5"]


def renamed(text: str, name: str) -> str:
    old = 'name = "Solenoid"'
    assert old in text
    return text.replace(old, f'name = "{name}"')


@pytest.fixture(scope="module")
def built(tmp_path_factory) -> dict[str, Path]:
    """`emcosim plant build` of the solenoid into `fmus`, where a link `Solenoid.fmu.tmp` points at a victim
    file outside the folder (the issue's link attack, item 6), and the same description renamed "Plunger"
    (another device with the same variable names and units) into the same folder."""
    base = tmp_path_factory.mktemp("devices")
    fmus = base / "fmus"
    fmus.mkdir()
    victim = base / "victim.conf"
    victim.write_text("setting = 1\n")
    (fmus / "Solenoid.fmu.tmp").symlink_to(victim)
    assert main(["plant", "build", str(SOLENOID), "--out", str(fmus)]) == 0
    plunger = base / "plunger.toml"
    plunger.write_text(renamed(SOLENOID.read_text(), "Plunger"))
    assert main(["plant", "build", str(plunger), "--out", str(fmus)]) == 0
    return {"fmus": fmus, "victim": victim, "plunger": plunger}


def scenario(tmp_path: Path, fmus: Path, name: str = "loop") -> Path:
    out = tmp_path / name
    assert main(["plant", "scenario", str(SOLENOID), *SCENARIO_ARGS, "--out", str(out), "--fmu-dir", str(fmus)]) == 0
    return out


def run(args: list[str], capsys) -> tuple[int, str]:
    status = main(args + (["--no-progress"] if args[0] == "run" else []))
    return status, capsys.readouterr().err.strip()


# ---- item 5: a controller knows its device, the engine compares -----------------------------------

def test_plant_and_controller_declare_their_device(built):
    """Both FMUs of one build declare the device's name and the sha256 of its description; the plant as
    "plant", the controller as "controller"; the annotation keeps modelDescription.xml valid (fmpy)."""
    digest = hashlib.sha256(SOLENOID.read_bytes()).hexdigest()
    plant, _ = vendor.device(built["fmus"] / "Solenoid.fmu")
    controller, _ = vendor.device(built["fmus"] / "Solenoid_Proposition1.fmu")
    assert plant == vendor.Device("Solenoid", digest, "plant")
    assert controller == vendor.Device("Solenoid", digest, "controller")
    other, _ = vendor.device(built["fmus"] / "Plunger_Proposition1.fmu")
    assert other == vendor.Device("Plunger", hashlib.sha256(built["plunger"].read_bytes()).hexdigest(), "controller")
    assert vendor.device(built["fmus"] / "Reference.fmu") == (None, "")          # no device: not compared
    for name in ("Solenoid.fmu", "Solenoid_Proposition1.fmu"):
        assert validate_fmu(str(built["fmus"] / name)) == [], name


def test_a_controller_of_another_device_is_refused_by_name(built, tmp_path, capsys):
    """The issue's loop: Plunger's controller (same variable names and units) wired to Solenoid's plant ran
    without a word; now it is refused before anything runs, naming both devices."""
    loop = scenario(tmp_path, built["fmus"])
    ssd = loop / "SystemStructure.ssd"
    text = ssd.read_text()
    assert "Solenoid_Proposition1.fmu" in text
    ssd.write_text(text.replace("Solenoid_Proposition1.fmu", "Plunger_Proposition1.fmu"))
    out = tmp_path / "r.csv"
    status, err = run(["run", str(loop), "-o", str(out)], capsys)
    assert status == 1, err
    last = err.splitlines()[-1]
    assert last.startswith("emcosim: error: "), err
    assert "different devices" in last and "'Plunger'" in last and "'Solenoid'" in last, last
    assert not out.exists() and not list(tmp_path.glob("r.partial*"))


def test_two_models_of_one_device_are_refused(built, tmp_path):
    """A controller built from another version of the device's description (same name, other digest)."""
    scen = read_scenario(scenario(tmp_path, built["fmus"]))
    instances = binding.load(scen)
    controller = instances["controller"]
    controller.device = controller.device._replace(model="0" * 64)
    with pytest.raises(ScenarioError, match="two different models of device 'Solenoid'"):
        binding.check_connections(scen, instances)


def test_the_matching_loop_runs_without_a_warning(built, tmp_path, capsys):
    loop = scenario(tmp_path, built["fmus"])
    out = tmp_path / "r.csv"
    status, err = run(["run", str(loop), "-o", str(out)], capsys)
    assert status == 0 and "warning" not in err, err
    assert out.read_text().startswith("time,") and read_sidecar(out)["notes"] == []


@pytest.mark.parametrize("how", ["--set", ".ssv"])
def test_a_plant_parameter_the_controller_does_not_model_warns_and_the_header_says_so(built, tmp_path, capsys, how):
    """The issue's `--set plant.k_s=7000` (and the same in plant.ssv): the controller's model keeps 5000 and
    the loop settles off q_d = 1 mm. Before: exit 0 and not a word. Now: still run (a robustness study may
    want it), a warning naming both values, and the same note as a comment line at the top of the file."""
    loop = scenario(tmp_path, built["fmus"])
    args = ["run", str(loop), "-o", str(tmp_path / "r.csv"), "--stop-time", "0.1"]
    if how == "--set":
        args += ["--set", "plant.k_s=7000"]
    else:
        ssv = loop / "plant.ssv"
        old = '<ssv:Parameter name="k_s"><ssv:Real value="5000.0"/>'
        assert old in ssv.read_text()
        ssv.write_text(ssv.read_text().replace(old, old.replace("5000.0", "7000.0")))
    status, err = run(args, capsys)
    assert status == 0, err
    warning = [line for line in err.splitlines() if line.startswith("emcosim: warning: ")]
    assert len(warning) == 1 and "plant.k_s = 7000.0" in warning[0] and "controller.k_s = 5000.0" in warning[0], err
    assert (tmp_path / "r.csv").read_text().startswith("time,")       # issue 41: the note in the sidecar
    notes = read_sidecar(tmp_path / "r.csv")["notes"]
    assert len(notes) == 1 and "plant.k_s = 7000.0" in notes[0] and "controller.k_s = 5000.0" in notes[0], notes
    q = read_csv(tmp_path / "r.csv")["plant.q"]
    assert abs(q[-1] - 0.001) > 4e-4                    # the 0.52 mm at 0.1 s, not q_d = 1 mm


def test_a_model_exchange_run_notes_it_too(built, tmp_path, capsys):
    loop = scenario(tmp_path, built["fmus"])
    out = tmp_path / "r.csv"
    status, err = run(["run", str(loop), "-o", str(out), "--interface-type", "ModelExchange",
                       "--set", "controller.R_c=6"], capsys)
    assert status == 0 and "plant.R_c = 5.0, but the controller 'controller' models it with controller.R_c = 6.0" in err
    assert out.read_text().startswith("time,") and read_sidecar(out)["notes"][0].startswith("plant.R_c = 5.0")


# ---- item 6: files -----------------------------------------------------------------------------------

def test_plant_build_never_writes_through_a_link_in_out(built):
    """The fixture's build ran with `Solenoid.fmu.tmp` a link to a file outside --out: the old build wrote
    the FMU through it. The victim is unchanged and the link untouched; the FMU is a zip."""
    assert built["victim"].read_text() == "setting = 1\n"
    assert (built["fmus"] / "Solenoid.fmu.tmp").is_symlink()
    assert (built["fmus"] / "Solenoid.fmu").read_bytes()[:2] == b"PK"


def test_plant_build_refuses_an_fmu_name_that_is_a_link(tmp_path, capsys):
    victim = tmp_path / "victim.conf"
    victim.write_text("setting = 1\n")
    out = tmp_path / "fmus"
    out.mkdir()
    (out / "Solenoid_Theorem2.fmu").symlink_to(victim)
    status, err = run(["plant", "build", str(SOLENOID), "--out", str(out)], capsys)
    assert status == 1 and "symbolic link" in err.splitlines()[-1], err
    assert victim.read_text() == "setting = 1\n" and {p.name for p in out.iterdir()} == {"Solenoid_Theorem2.fmu"}


def test_plant_build_into_a_file_is_refused_before_the_build(tmp_path, capsys):
    out = tmp_path / "fmus"
    out.write_text("a file")
    status, err = run(["plant", "build", str(SOLENOID), "--out", str(out)], capsys)
    assert status == 1 and "is not a folder" in err.splitlines()[-1], err
    assert out.read_text() == "a file"


def test_a_device_named_reference_is_refused(tmp_path, capsys):
    """Its plant FMU Reference.fmu used to be replaced by the reference generator built beside it."""
    desc = tmp_path / "reference.toml"
    desc.write_text(renamed(SOLENOID.read_text(), "Reference"))
    out = tmp_path / "fmus"
    # the description's own check (components.identifiers) refuses the name before any FMU is named
    refused = "name: 'Reference' is taken by the generated model module or the Reference FMU"
    status, err = run(["plant", "build", str(desc), "--out", str(out)], capsys)
    assert status == 1 and refused in err.splitlines()[-1], err
    assert not out.exists()
    status, err = run(["plant", "scenario", str(desc), *SCENARIO_ARGS, "--out", str(tmp_path / "s")], capsys)
    assert status == 1 and refused in err and not (tmp_path / "s").exists()


def test_a_device_named_like_a_paper_fmu_is_refused_in_the_suites_folder(tmp_path, capsys):
    """components/plants/mems.toml is named MEMS: built into the folder of the suite's FMUs (which holds the
    build stamp) it would replace the paper's MEMS.fmu and MEMS_Proposition1.fmu. Elsewhere it builds."""
    from fmus.build import STAMP

    out = tmp_path / "fmus"
    out.mkdir()
    (out / STAMP).write_text("{}")
    (out / "MEMS.fmu").write_bytes(b"the paper's plant")
    status, err = run(["plant", "build", str(MEMS), "--out", str(out)], capsys)
    assert status == 1 and "MEMS.fmu would replace the suite's FMUs" in err.splitlines()[-1], err
    assert (out / "MEMS.fmu").read_bytes() == b"the paper's plant"


def scenario_args(tmp_path: Path, out: Path, design: str = "Proposition1") -> list[str]:
    extra = ["--reference", "sinusoid:offset=0.001,amplitude=5e-5,omega=31.4"] if design == "Theorem2" else []
    return ["plant", "scenario", str(SOLENOID), "--controller", design, "--stop-time", "0.05", "--step-size", "1e-4",
            "--out", str(out), "--fmu-dir", str(tmp_path / "fmus"), *extra]


def test_scenario_refuses_a_users_own_scenario(tmp_path, capsys):
    """A folder of the user's own .ssd/.ssv files used to be overwritten without a question."""
    out = tmp_path / "mine"
    out.mkdir()
    (out / "SystemStructure.ssd").write_text("<my own scenario/>")
    (out / "plant.ssv").write_text("<my parameters/>")
    status, err = run(scenario_args(tmp_path, out), capsys)
    assert status == 1 and "not written by emcosim" in err.splitlines()[-1], err
    assert (out / "SystemStructure.ssd").read_text() == "<my own scenario/>"
    assert (out / "plant.ssv").read_text() == "<my parameters/>" and {p.name for p in out.iterdir()} == {
        "SystemStructure.ssd", "plant.ssv"}


def test_scenario_replaces_its_own_folder_whole(tmp_path, capsys):
    """A tracking scenario, then a regulation one into the same folder: the old reference_q.ssv used to stay
    beside the new files. Now the folder holds exactly the new scenario's files (and emcosim's manifest)."""
    out = tmp_path / "loop"
    assert main(scenario_args(tmp_path, out, "Theorem2")) == 0
    assert (out / "reference_q.ssv").is_file()
    assert main(scenario_args(tmp_path, out, "Proposition1")) == 0
    assert {p.name for p in out.iterdir()} == {".emcosim", "SystemStructure.ssd", "plant.ssv", "controller.ssv"}
    assert "Proposition1" in (out / "SystemStructure.ssd").read_text()
    assert not list(tmp_path.glob("loop.*"))                   # nothing left beside it


def test_scenario_refuses_its_own_folder_once_edited(tmp_path, capsys):
    out = tmp_path / "loop"
    assert main(scenario_args(tmp_path, out)) == 0
    edited = (out / "plant.ssv").read_text().replace('value="5000.0"', 'value="6000.0"')
    (out / "plant.ssv").write_text(edited)
    status, err = run(scenario_args(tmp_path, out), capsys)
    assert status == 1 and "plant.ssv (changed since emcosim wrote it)" in err, err
    assert (out / "plant.ssv").read_text() == edited


def test_a_killed_plant_build_leaves_nothing_the_next_command_does_not_remove(tmp_path, monkeypatch):
    """kill -9 while `plant build` compiles and bundles: its temporary folders (emcosim_plant_*,
    emcosim_description_*, emcosim_build_*) used to stay in $TMPDIR for good. Now they are inside one folder
    marked as emcosim's (engine/tempdirs.py), which the next command removes."""
    tmpdir = tmp_path / "tmp"
    tmpdir.mkdir()
    proc = subprocess.Popen([sys.executable, "-m", "emcosim.cli", "plant", "build", str(SOLENOID), "--out",
                             str(tmp_path / "fmus")], cwd=str(ROOT), env={**os.environ, "TMPDIR": str(tmpdir)},
                            stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, start_new_session=True)
    try:
        deadline = time.monotonic() + 120
        while not list(tmpdir.rglob("emcosim_build_*")) and time.monotonic() < deadline and proc.poll() is None:
            time.sleep(0.05)
        assert proc.poll() is None, "the build ended before it could be killed"
        assert list(tmpdir.rglob("emcosim_build_*")), "the build made no temporary folder within 120 s"
    finally:                                                   # kill -9 of the build and of its gcc, if running
        os.killpg(proc.pid, signal.SIGKILL)
        proc.wait()
    assert list(tmpdir.iterdir())                              # the killed build left its folders
    monkeypatch.setattr(tempfile, "tempdir", str(tmpdir))      # the next command, in the same $TMPDIR
    assert main(["info"]) == 0
    assert list(tmpdir.iterdir()) == []


# ---- the engine's side, generic: toy FMUs (no physics) that declare devices ---------------------------

def _declaring(name: str, model: str = "m1", role: str = "plant") -> str:
    return f'<Tool name="org.emcosim.device"><Device name="{name}" model="{model}" role="{role}"/></Tool>'


def _toy_loop(make, plant: str | None, ctrl: str | None, plant_order: float = 3.0):
    """The x' = -x loop of toy FMUs (tests/toy_fmus.py), each optionally declaring a device; both have a
    parameter input_order (the controller's stays 3)."""
    from .helpers import DYNAMIC, STATIC

    return make([("plant", "dynamic", DYNAMIC, True, 3, plant), ("ctrl", "static", STATIC, True, 3, ctrl)],
                [("plant.x", "ctrl.u1"), ("ctrl.y", "plant.u")],
                {"ctrl": {"k1": -1.0}, "plant": {"x0": 1.0, "input_order": plant_order}})


def test_the_engine_compares_declared_devices_of_any_fmu(make):
    """The engine reads only the declarations: two toy FMUs of devices A and B are refused; of one device,
    a same-named parameter with two values is a note (warnings and Result.notes), with one value none."""
    from emcosim.engine.master import simulate

    with pytest.raises(ScenarioError, match="'A'.*'B'.*different devices"):
        simulate(_toy_loop(make, _declaring("A"), _declaring("B", role="controller")), record=["plant.x"])
    with pytest.raises(ScenarioError, match="two different models of device 'A'"):
        simulate(_toy_loop(make, _declaring("A"), _declaring("A", "m2", "controller")), record=["plant.x"])
    r = simulate(_toy_loop(make, _declaring("A"), _declaring("A", role="controller"), plant_order=2.0),
                 record=["plant.x"])
    note = "plant.input_order = 2.0, but the controller 'ctrl' models it with ctrl.input_order = 3.0 (device 'A')"
    assert len(r.notes) == 1 and r.notes[0].startswith(note) and r.notes[0] in r.warnings, r.warnings
    r = simulate(_toy_loop(make, _declaring("A"), _declaring("A", role="controller")), record=["plant.x"])
    assert r.notes == [] and r.warnings == []


@pytest.mark.parametrize("plant, ctrl, warned", [
    (None, _declaring("B", role="controller"), False),                 # another vendor's FMU: not compared
    (_declaring("A"), '<Tool name="org.emcosim.device"><Device name="B" role="controller"/></Tool>', True),
    (_declaring("A"), _declaring("B\u200b", role="controller"), True),               # not printable
    (_declaring("A"), _declaring("B" * 201, role="controller"), True),
    (_declaring("A"), '<Tool name="org.emcosim.device"><Other/></Tool>', False)])
def test_an_fmu_without_a_readable_declaration_is_not_compared(make, plant, ctrl, warned):
    """FMUs that declare no device (or a declaration that cannot be read: a warning) run as before."""
    from emcosim.engine.master import simulate

    r = simulate(_toy_loop(make, plant, ctrl, plant_order=2.0), record=["plant.x"])
    assert r.notes == [] and len(r["plant.x"]) > 1
    assert [w.startswith("ctrl: ") and "not compared" in w for w in r.warnings] == ([True] if warned else []), r.warnings
