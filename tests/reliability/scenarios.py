"""Helpers of the reliability suite: the faulty test FMU, small scenario folders, `emcosim run` in a
subprocess, and the checks of the CLI's one-line error."""
from __future__ import annotations

import csv
import subprocess
import sys
from pathlib import Path

from emcosim.engine.ssd import Component, Connection, Connector, Parameter, Scenario
from emcosim.engine.ssd_writer import parameter_set_xml, system_structure_xml

from .harness import ROOT

FIXTURES = ROOT / "tests" / "fixtures"
FAULTY_SCRIPT = FIXTURES / "emcosim_reliability_faulty.py"


def build_faulty_fmu(out: Path) -> Path:
    subprocess.run([sys.executable, "-m", "pythonfmu", "build", "-f", str(FAULTY_SCRIPT), "-d", str(out),
                    "--handle-state"], check=True, capture_output=True)
    return out / "ReliabilityFaulty.fmu"


def write_scenario(folder: Path, components, connections, parameters=None, stop_time=0.01, step_size=1e-3) -> Path:
    """components = [(name, fmu path, [Connector])], connections = [("a.y", "b.x")],
    parameters = {component: {name: value}}."""
    folder.mkdir(parents=True, exist_ok=True)
    comps = []
    for name, fmu, connectors in components:
        comp = Component(name, Path(fmu), connectors=connectors)
        if parameters and name in parameters:
            params = [Parameter(k, "Integer" if isinstance(v, int) else "Real", v) for k, v in parameters[name].items()]
            (folder / f"{name}.ssv").write_text(parameter_set_xml(name, params))
            comp.parameter_sources = [f"{name}.ssv"]
        comps.append(comp)
    scenario = Scenario(folder.name, folder / "SystemStructure.ssd", comps,
                        [Connection(*a.split(".") + b.split(".")) for a, b in connections], stop_time=stop_time)
    (folder / "SystemStructure.ssd").write_text(
        system_structure_xml(scenario, {c.name: str(c.source) for c in comps}, step_size))
    return folder


def real(name: str) -> list[Connector]:
    return [Connector(name, "input", "Real")]


def emcosim_run(args: list[str], timeout: float = 300.0) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "emcosim.cli", "run", *args, "--no-progress"], capture_output=True,
                          text=True, cwd=str(ROOT), timeout=timeout)


def one_line_error(stderr: str) -> str:
    """The CLI's error line: exactly one line starts with 'emcosim: error:', it is the last line, and
    no traceback is dumped. Lines before it may only be the FMUs' own error echoes ('[instance] error: ...')."""
    lines = [x for x in stderr.splitlines() if x.strip()]
    errors = [x for x in lines if x.startswith("emcosim: error:")]
    assert "Traceback" not in stderr, stderr
    assert len(errors) == 1 and lines[-1] == errors[0], stderr
    others = [x for x in lines[:-1] if not (x.startswith("[") and "] error: " in x)]
    assert not others, f"unexpected output on stderr: {others}"
    return errors[0]


def read_csv(path: Path) -> tuple[list[str], list[list[float]]]:
    """Header and rows of a results CSV (a partial file's comment line is skipped)."""
    with open(path, newline="") as f:
        rows = list(csv.reader(line for line in f if not line.startswith("#")))
    return rows[0], [[float(v) for v in row] for row in rows[1:]]


def partial_of(out: Path) -> Path:
    """Where `emcosim run -o out` keeps the rows of a run that failed: NAME.partial.csv."""
    return out.with_name(f"{out.stem}.partial{out.suffix}")
