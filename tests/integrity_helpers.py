"""Helpers of the integrity tests (issue 15): the toy FMUs (tests/fixtures: a gain y = k x and an
integrator x' = u), a toy closed loop x' = k x written as an SSP folder (optionally with units,
a linear transformation, in another encoding), and `emcosim` in a subprocess."""
from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

from emcosim.engine.ssd import Component, Connection, Connector, Parameter, Scenario
from emcosim.engine.ssd_writer import parameter_set_xml, system_structure_xml

ROOT = Path(__file__).resolve().parents[1]
FIXTURES = ROOT / "tests" / "fixtures"
GAIN = [Connector("x", "input", "Real"), Connector("y", "output", "Real")]
INTEGRATOR = [Connector("u", "input", "Real"), Connector("x", "output", "Real")]


def build_toys(out: Path) -> dict[str, Path]:
    for script in ("emcosim_toy_gain.py", "emcosim_toy_integrator.py"):
        subprocess.run([sys.executable, "-m", "pythonfmu", "build", "-f", str(FIXTURES / script), "-d", str(out),
                        "--handle-state"], check=True, capture_output=True)
    return {"gain": out / "ToyGain.fmu", "integrator": out / "ToyIntegrator.fmu"}


def toy_loop(folder: Path, fmus: dict[str, Path], k: float = -1.0, x0: float = 1.0, stop_time: float = 1.0,
             step_size: float = 0.01, extra_ssv: dict | None = None, factor: float = 1.0) -> Path:
    """The loop plant.x -> ctrl.x, ctrl.y -> plant.u with ctrl.k = k, plant.x0 = x0: x' = k x,
    x_{n+1} = (1 + k h) x_n at the communication points (the master resolves the gain at the
    same instant). extra_ssv: more parameters {component: {name: value}}; factor: a
    LinearTransformation on plant.x -> ctrl.x."""
    folder.mkdir(parents=True, exist_ok=True)
    params = {"ctrl": {"k": k}, "plant": {"x0": x0}}
    for comp, values in (extra_ssv or {}).items():
        params[comp].update(values)
    comps = []
    for name, key, connectors in (("plant", "integrator", INTEGRATOR), ("ctrl", "gain", GAIN)):
        comp = Component(name, fmus[key], connectors=connectors)
        ps = [Parameter(n, "Integer" if isinstance(v, int) else "Real", v) for n, v in params[name].items()]
        (folder / f"{name}.ssv").write_text(parameter_set_xml(name, ps))
        comp.parameter_sources = [f"{name}.ssv"]
        comps.append(comp)
    scenario = Scenario("toy", folder / "SystemStructure.ssd", comps,
                        [Connection("plant", "x", "ctrl", "x", factor=factor), Connection("ctrl", "y", "plant", "u")],
                        stop_time=stop_time)
    (folder / "SystemStructure.ssd").write_text(
        system_structure_xml(scenario, {c.name: str(c.source) for c in comps}, step_size))
    return folder


def emcosim(args: list[str], timeout: float = 300, env: dict | None = None, **kwargs) -> subprocess.CompletedProcess:
    """`emcosim ARGS` in a subprocess (from the project's root)."""
    return subprocess.run([sys.executable, "-m", "emcosim.cli", *args], capture_output=True, text=True,
                          cwd=str(ROOT), timeout=timeout, env={**os.environ, **(env or {})}, **kwargs)


def popen(args: list[str], env: dict | None = None, **kwargs) -> subprocess.Popen:
    return subprocess.Popen([sys.executable, "-m", "emcosim.cli", *args], cwd=str(ROOT), stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE, text=True, env={**os.environ, **(env or {})}, **kwargs)


def partial_of(out: Path) -> Path:
    """Where a run writing `out` keeps its rows when it fails: NAME.partial.csv."""
    return out.with_name(f"{out.stem}.partial{out.suffix}")


def partial_note(path: Path) -> str | None:
    """Why a results file is partial: its sidecar's reason, or the marker line of a file kept in place (a killed
    run's, a full disk's); None for a complete file (emcosim.engine.results.partial_note)."""
    from emcosim.engine.results import partial_note as note

    return note(path)
