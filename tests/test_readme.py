"""Every command of README.md works as written, in a fresh virtual environment.

The README's `bash` blocks are run line by line, in order, with bash, in a copy of the repository
(the files git tracks, as a fresh clone has them): the first line creates `.venv` and installs the
suite into it (pip's cache makes this a matter of seconds to a minute), builds the FMUs and runs
the full `emcosim reproduce`. The one line not run is the test command itself (it would run this
test again); it is checked to be what CI runs (.ci/run). Cost: about 3 minutes on 2 cores, most of
it the full reproduce (about 90 s), the install and the FMU build.
"""
from __future__ import annotations

import json
import os
import re
import shutil
import subprocess
import time
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
TEST_COMMAND = '.venv/bin/pip install -e ".[test]" && .venv/bin/python -m pytest -q'


def readme_commands(text: str) -> list[str]:
    """The lines of the README's ```bash blocks, in order."""
    blocks = re.findall(r"```bash\n(.*?)```", text, re.S)
    return [line for block in blocks for line in block.splitlines() if line.strip()]


def test_readme_lists_the_commands_it_promises():
    commands = readme_commands((ROOT / "README.md").read_text())
    assert commands[0].startswith("python3.11 -m venv .venv && .venv/bin/pip install -e . && ")
    assert commands[1] == TEST_COMMAND
    ci = (ROOT / ".ci" / "run").read_text()
    assert '-m pip install --quiet -e ".[test]"' in ci and "\n.venv/bin/python -m pytest -q\n" in ci
    assert not any("../shared" in c for c in commands)


def _tracked_copy(target: Path) -> None:
    files = subprocess.run(["git", "ls-files", "-z"], cwd=ROOT, capture_output=True, check=True).stdout
    for name in files.decode().split("\0"):
        if name and (ROOT / name).is_file():
            (target / name).parent.mkdir(parents=True, exist_ok=True)
            shutil.copy2(ROOT / name, target / name)


@pytest.mark.slow                        # about 3 minutes
def test_every_readme_command_runs_in_a_fresh_venv(tmp_path):
    if shutil.which("python3.11") is None:
        pytest.skip("the README's commands need python3.11 on PATH")
    if shutil.which("git") is None or not (ROOT / ".git").exists():
        pytest.skip("needs a git checkout (the copy is made of the files git tracks)")
    repo = tmp_path / "emcosim"
    _tracked_copy(repo)
    env = {k: v for k, v in os.environ.items() if k not in ("VIRTUAL_ENV", "PYTHONPATH", "PYTHONHOME")}
    for command in readme_commands((repo / "README.md").read_text()):
        if command == TEST_COMMAND:
            continue
        tic = time.monotonic()
        run = subprocess.run(["bash", "-c", command], cwd=repo, env=env, capture_output=True, text=True, timeout=1200)
        assert run.returncode == 0, f"{command}\n{run.stdout[-2000:]}\n{run.stderr[-3000:]}"
        print(f"{time.monotonic() - tic:6.1f} s  {command}")                # pytest -s shows the costs
    for name in ["results/claims.md", "results/fig3_maglev_tracking.png", "r.png", "r.csv", "mems_tracking_Dd-0.4.csv",
                 "loop.fmu", "loop.csv", "mems.csv", "jet.csv", "sweep_maglev_tracking_D0_R0.82/sweep.csv", "me.csv",
                 "mems_me.csv", "build/Solenoid/Solenoid_Proposition1.fmu", "my_scenario/SystemStructure.ssd",
                 "my_scenario.png"]:
        assert (repo / name).stat().st_size > 0, name
    claims = json.loads((repo / "results" / "claims.json").read_text())
    assert claims["banner"] is None and len(claims["claims"]) == 14
    assert len((repo / "loop.csv").read_text().splitlines()) > 100


def test_gitignore_covers_what_the_readme_writes():
    """git status stays clean after the README's commands (issue 33): every file or folder they name as an
    output (-o, --output, --out, --plot, --output-file, a run's default NAME.csv) is ignored by git."""
    if shutil.which("git") is None or not (ROOT / ".git").exists():
        pytest.skip("needs a git checkout")
    written = set()
    for command in readme_commands((ROOT / "README.md").read_text()):
        for part in command.split("&&"):
            words = part.split()
            for flag, value in zip(words, words[1:]):
                if flag in ("-o", "--output", "--out", "--plot", "--output-file", "--json"):
                    written.add(value)
            if words[:2] == [".venv/bin/emcosim", "run"] and not {"-o", "--output"} & set(words):
                written.add(Path(words[2]).name + ".csv")
            if words[:2] == [".venv/bin/emcosim", "sweep"] and "--out" not in words:
                written.add(f"sweep_{words[2]}/")
    assert {"results", "r.csv", "r.png", "loop.fmu", "my_scenario"} <= {w.rstrip("/") for w in written}
    for name in sorted(written):
        path = name.rstrip("/") + ("/x" if name.endswith("/") or "." not in Path(name).name else "")
        check = subprocess.run(["git", "check-ignore", "-q", "--no-index", path], cwd=ROOT)
        assert check.returncode == 0, f"{name}: written by the README's commands, not ignored by .gitignore"
