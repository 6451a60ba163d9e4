"""Fixtures: the FMUs, built once per test session (fmus.build, a no-op when build/fmus is up to date); the C toy
FMUs' library and a builder of scenarios over them (`make`); the paper scenarios' monolithic references."""
from __future__ import annotations

import os
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
if str(ROOT) not in sys.path:
    sys.path.insert(0, str(ROOT))

from emcosim.engine.ssd import Component, Connection, Parameter, Scenario, read_scenario  # noqa: E402
from emcosim.engine.ssd_writer import parameter_set_xml, system_structure_xml  # noqa: E402
from tests import toy_fmus  # noqa: E402


@pytest.fixture(scope="session")
def fmu_dir() -> Path:
    """build/fmus, brought up to date once per test session (a no-op when nothing changed); or
    $EMCOSIM_FMU_DIR as it is. Missing FMUs fail the tests that need them (never a silent skip)."""
    from fmus import build

    if "EMCOSIM_FMU_DIR" in os.environ:
        d = Path(os.environ["EMCOSIM_FMU_DIR"])
    else:
        d = build.default_dest()
        build.build(d, verbose=False)
    missing = [m for m in build.FMUS if not (d / f"{m}.fmu").is_file()]
    assert not missing, f"FMUs not built: {missing} in {d}"
    return d


@pytest.fixture(scope="session")
def fmus(fmu_dir) -> dict[str, Path]:
    """Model identifier -> path of the session's FMU (in `fmu_dir`)."""
    from fmus import build

    return {m: fmu_dir / f"{m}.fmu" for m in build.FMUS}


@pytest.fixture(scope="session")
def toy_library(tmp_path_factory) -> Path:
    lib = toy_fmus.compile_library(tmp_path_factory.mktemp("toy_library"))
    if lib is None:
        pytest.skip("needs gcc")
    return lib


@pytest.fixture
def make(tmp_path, toy_library):
    """make(components, connections, parameters, stop_time, step_size) -> scenario folder;
    components: [(name, kind, connectors, interpolate, output order[, the content of <VendorAnnotations>])];
    connections: [(start, end[, factor])]."""
    def build(components, connections, parameters=None, stop_time=1.0, step_size=0.01):
        folder = tmp_path / f"s{len(list(tmp_path.iterdir()))}"
        folder.mkdir()
        comps = []
        for name, kind, connectors, interpolate, order, *vendor in components:
            fmu = toy_fmus.build(folder, toy_library, kind, f"Toy{name.title()}{int(interpolate)}{order}", interpolate,
                                 order, *vendor)
            comp = Component(name, fmu, connectors=connectors)
            if parameters and name in parameters:
                (folder / f"{name}.ssv").write_text(parameter_set_xml(
                    name, [Parameter(k, "Real", float(v)) for k, v in parameters[name].items()]))
                comp.parameter_sources = [f"{name}.ssv"]
            comps.append(comp)
        conns = [Connection(*a.split(".") + b.split("."), *rest) for a, b, *rest in connections]
        scenario = Scenario("toy", folder / "SystemStructure.ssd", comps, conns, stop_time=stop_time)
        (folder / "SystemStructure.ssd").write_text(
            system_structure_xml(scenario, {c.name: str(c.source) for c in comps}, step_size))
        return read_scenario(folder)
    return build


@pytest.fixture(scope="session")
def references():
    """Monolithic references, computed once per (scenario, horizon, grid)."""
    from emcosim.paper.reference_check import monolithic
    cache = {}

    def get(s, t_end, n_samples):
        key = (s.name, t_end, n_samples)
        if key not in cache:
            cache[key] = monolithic(s, stop_time=t_end, n_samples=n_samples)
        return cache[key]
    return get


@pytest.hookimpl(tryfirst=True)                    # before -m deselects
def pytest_collection_modifyitems(config, items):
    """The reliability suite runs in the full set only: its tests are `slow` too, so that the quick set
    (`-m "not slow"`) leaves its subprocesses out (issue 33)."""
    for item in items:
        if item.get_closest_marker("reliability") is not None and item.get_closest_marker("slow") is None:
            item.add_marker(pytest.mark.slow)


@pytest.fixture(scope="session")
def c_calls(tmp_path_factory):
    """tests/fixtures/c_calls.c compiled once (tests/c_host.py): a plain C host that replays FMI calls."""
    from tests.c_host import CALLS_SOURCE, compile_c_host

    exe = tmp_path_factory.mktemp("c_calls") / "c_calls"
    reason = compile_c_host(exe, CALLS_SOURCE)
    if reason:
        pytest.skip(reason)
    return exe
