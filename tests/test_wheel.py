"""An installed wheel builds the FMUs: fmus/build.py finds its sources (the fmus package with the loader's C
file, components/) beside itself, not in a checkout. The wheel is built from the files git tracks and
installed into a folder of its own; the build runs there, from another working directory, and its FMUs
run in fmpy."""
from __future__ import annotations

import os
import shutil
import subprocess
import sys
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
