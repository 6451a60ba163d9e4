"""An installed wheel builds the FMUs: fmus/build.py finds its sources (the fmus package with the loader's C
file, components/) beside itself, not in a checkout. The wheel is built from the files git tracks and
installed into a folder of its own; the build runs there, from another working directory, and its FMUs
run in fmpy. And the README's commands and Python example run from the wheel installed in a fresh virtual
environment, in an empty folder (issue 33)."""
from __future__ import annotations

import os
import re
import shutil
import subprocess
import sys
import sysconfig
from pathlib import Path

import pytest
from fmpy import simulate_fmu
from fmpy.validation import validate_fmu

ROOT = Path(__file__).resolve().parents[1]


@pytest.mark.slow                        # about a minute: the wheel's build environment and the FMU build
def test_an_installed_wheel_builds_fmus_that_run(tmp_path):
    if shutil.which("git") is None or not (ROOT / ".git").exists():
        pytest.skip("needs a git checkout (the wheel is built from the files git tracks)")
    source = tmp_path / "source"
    files = subprocess.run(["git", "ls-files", "-z"], cwd=ROOT, capture_output=True, check=True).stdout
    for name in files.decode().split("\0"):
        if name and (ROOT / name).is_file():
            (source / name).parent.mkdir(parents=True, exist_ok=True)
            shutil.copy2(ROOT / name, source / name)
    pip = [sys.executable, "-m", "pip", "--disable-pip-version-check", "-q"]
    subprocess.run(pip + ["wheel", "--no-deps", "-w", str(tmp_path / "dist"), str(source)], check=True,
                   capture_output=True)
    wheel = next((tmp_path / "dist").glob("emcosim-*.whl"))
    site = tmp_path / "site"
    subprocess.run(pip + ["install", "--no-deps", "--target", str(site), str(wheel)], check=True, capture_output=True)
    work = tmp_path / "elsewhere"
    work.mkdir()
    env = {**os.environ, "PYTHONPATH": str(site)}
    code = "import fmus.build, components; print(fmus.build.__file__); print(components.__file__)"
    where = subprocess.run([sys.executable, "-c", code], cwd=work, env=env, capture_output=True, text=True, check=True)
    assert all(line.startswith(str(site)) for line in where.stdout.split()), where.stdout     # the wheel's, not ours
    run = subprocess.run([sys.executable, "-m", "fmus.build", "--dest", str(work / "fmus")], cwd=work, env=env,
                         capture_output=True, text=True)
    assert run.returncode == 0, run.stderr
    built = sorted(p.stem for p in (work / "fmus").glob("*.fmu"))
    assert built == sorted(["MEMS", "Maglev", "MEMS_Proposition1", "MEMS_Theorem2", "Maglev_Proposition2",
                            "Maglev_Theorem3", "Reference"]), built
    assert validate_fmu(str(work / "fmus" / "Maglev.fmu")) == []
    result = simulate_fmu(str(work / "fmus" / "Maglev.fmu"), stop_time=0.01, output_interval=1e-3)
    assert len(result) == 11 and result["q"][0] == pytest.approx(0.0025)


def _venv_with_wheel(tmp_path: Path) -> tuple[Path, Path]:
    """A fresh virtual environment with the wheel of the files git tracks installed in it (not editable);
    its dependencies are this environment's, reached through a .pth line (no download). Returns (its python,
    its site-packages)."""
    source = tmp_path / "source"
    files = subprocess.run(["git", "ls-files", "-z"], cwd=ROOT, capture_output=True, check=True).stdout
    for name in files.decode().split("\0"):
        if name and (ROOT / name).is_file():
            (source / name).parent.mkdir(parents=True, exist_ok=True)
            shutil.copy2(ROOT / name, source / name)
    pip = [sys.executable, "-m", "pip", "--disable-pip-version-check", "-q"]
    subprocess.run(pip + ["wheel", "--no-deps", "-w", str(tmp_path / "dist"), str(source)], check=True,
                   capture_output=True)
    wheel = next((tmp_path / "dist").glob("emcosim-*.whl"))
    venv = tmp_path / "venv"
    subprocess.run([sys.executable, "-m", "venv", "--without-pip", str(venv)], check=True, capture_output=True)
    python = venv / "bin" / "python"
    site = Path(subprocess.run([str(python), "-c", "import sysconfig; print(sysconfig.get_paths()['purelib'])"],
                               capture_output=True, text=True, check=True).stdout.strip())
    ours = sysconfig.get_paths()["purelib"]
    (site / "zz_emcosim_test_dependencies.pth").write_text(ours + "\n")    # after the wheel's own packages
    subprocess.run(pip + ["--python", str(python), "install", "--no-deps", str(wheel)], check=True,
                   capture_output=True)
    return python, site


def _tree(folder: Path) -> dict[str, int]:
    return {str(p.relative_to(folder)): p.stat().st_size for p in folder.rglob("*")
            if p.is_file() and "__pycache__" not in p.parts}


@pytest.mark.slow                        # about 2 minutes on 2 cores: the wheel, two FMU builds, a short reproduce
def test_the_readme_runs_from_an_installed_wheel_in_an_empty_folder(tmp_path):
    """Issue 33: `pip install` of the wheel, then, in an empty folder, the README's main job (reproduce, with a
    shortened horizon), info, run, plant check/build/scenario of an example and the README's Python example;
    nothing is written into site-packages."""
    if shutil.which("git") is None or not (ROOT / ".git").exists():
        pytest.skip("needs a git checkout (the wheel is built from the files git tracks)")
    python, site = _venv_with_wheel(tmp_path)
    emcosim = python.parent / "emcosim"
    before = _tree(site)
    assert (site / "emcosim" / "scenarios" / "maglev_regulation_prop2" / "SystemStructure.ssd").is_file()
    work = tmp_path / "empty"
    work.mkdir()
    env = {k: v for k, v in os.environ.items() if k not in ("VIRTUAL_ENV", "PYTHONPATH", "PYTHONHOME",
                                                             "EMCOSIM_FMU_DIR")}

    def ok(*command: str, cwd: Path = work) -> str:
        run = subprocess.run([str(c) for c in command], cwd=cwd, env=env, capture_output=True, text=True,
                             timeout=900)
        assert run.returncode == 0, f"{command}\n{run.stdout[-2000:]}\n{run.stderr[-3000:]}"
        return run.stdout

    ok(emcosim, "reproduce", "--stop-time", "0.01", "--out", "results")
    assert (work / "results" / "claims.md").stat().st_size > 0
    assert len(list((work / "build" / "fmus").glob("*.fmu"))) == 7           # built here, where it runs
    info = ok(emcosim, "info")
    assert "maglev_regulation_prop2" in info and "not built" not in info
    ok(emcosim, "run", "maglev_regulation_prop2", "--stop-time", "1", "--no-progress", "-o", "prop2.csv")
    assert len((work / "prop2.csv").read_text().splitlines()) > 10
    shutil.copy2(ROOT / "examples" / "solenoid" / "solenoid.toml", work / "solenoid.toml")
    assert "Proposition1" in ok(emcosim, "plant", "check", "solenoid.toml")
    ok(emcosim, "plant", "build", "solenoid.toml", "--out", "build/Solenoid")
    ok(emcosim, "plant", "scenario", "solenoid.toml", "--controller", "Proposition1", "--fmu-dir", "build/Solenoid",
       "--q0", "0.0007", "--stop-time", "0.01", "--step-size", "2e-5", "--out", "my_scenario")
    ok(emcosim, "run", "my_scenario", "--no-progress")
    assert (work / "my_scenario.csv").stat().st_size > 0
    blocks = re.findall(r"```python\n(.*?)```", (ROOT / "README.md").read_text(), re.S)
    assert blocks and "import emcosim" in blocks[0]
    printed = ok(python, "-c", blocks[0].replace("stop_time=5.0", "stop_time=0.5"))
    assert printed.split()[-1] == "m" and 0 < float(printed.split()[-2]) < 0.01
    ok(python, "-m", "emcosim.paper.scenarios")                               # regenerates ./scenarios
    assert (work / "scenarios" / "maglev_regulation_prop2" / "plant.ssv").is_file()
    after = _tree(site)
    assert after == before, sorted(set(after.items()) ^ set(before.items()))[:10]   # site-packages untouched
