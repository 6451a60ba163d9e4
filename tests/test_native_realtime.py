"""Real-time fitness of the native FMUs' C (issue 32; docs/native-fmus.md, "Real-time fitness"): no allocation
after fmi2Instantiate, no writable static storage (so instances share nothing and are independent across
threads; tests/test_native_sanitizers.py runs four at once under ThreadSanitizer), and a stated bound on the
substeps of a Co-Simulation step.

Truths: a host that replaces the process's allocator and counts its calls (tests/native/realtime_host.c); the
object files' own section sizes (objdump); the twin's PlantStepper, which needs more substeps for the step than
the bound a build is given."""
from __future__ import annotations

import re
import shutil
import subprocess
import zipfile
from pathlib import Path

import numpy as np
import pytest

from fmus.native_build import (
    CFLAGS,
    CONTROLLER_SOURCE_FILES,
    REFERENCE_SOURCE_FILES,
    SOURCE_FILES,
    build_native,
    build_native_controller,
    build_native_reference,
)

# slow: three native builds and C compiles, about 7 CPU-seconds (the quick set has no room left)
pytestmark = [pytest.mark.skipif(shutil.which("gcc") is None or shutil.which("objdump") is None,
                                 reason="needs gcc and objdump"), pytest.mark.slow]
HOST = Path(__file__).resolve().parent / "native" / "realtime_host.c"
DISCARD = 2


@pytest.fixture(scope="module")
def built(tmp_path_factory) -> dict[str, tuple[Path, tuple[str, ...]]]:
    """One plant, one controller and the Reference: FMU path and the source files it compiles."""
    dest = tmp_path_factory.mktemp("native")
    return {"MEMS": (build_native("MEMS", dest), SOURCE_FILES),
            "Maglev_Theorem3": (build_native_controller("Maglev_Theorem3", dest), CONTROLLER_SOURCE_FILES),
            "Reference": (build_native_reference(dest), REFERENCE_SOURCE_FILES)}


def _sources(fmu: Path, into: Path) -> Path:
    sources = into / "sources"
    sources.mkdir(parents=True)
    with zipfile.ZipFile(fmu) as z:
        for member in z.namelist():
            if member.startswith("sources/"):
                (sources / Path(member).name).write_bytes(z.read(member))
    return sources


def test_no_allocation_after_instantiation(built, tmp_path: Path) -> None:
    """After fmi2Instantiate, 500 CS steps with order-3 input polynomials, outputs, output derivatives, FMU states
    (get, set, serialize, deserialize, free), 1000 ME evaluations with directional derivatives, and refused calls
    whose messages are formatted: not one call of malloc, calloc or realloc in the whole process."""
    sources = _sources(built["MEMS"][0], tmp_path)
    exe = tmp_path / "host"
    subprocess.run(["gcc", "-std=c99", "-Wall", "-Wextra", "-Werror", "-O2", "-I", str(sources), str(HOST),
                    *(str(sources / f) for f in SOURCE_FILES), "-o", str(exe), "-lm"], check=True, capture_output=True)
    run = subprocess.run([str(exe)], capture_output=True, text=True, timeout=60)
    assert run.returncode == 0, run.stdout + run.stderr
    assert "0 allocations after instantiation\n0 mismatches" in run.stdout, run.stdout


@pytest.mark.parametrize("name", ["MEMS", "Maglev_Theorem3", "Reference"])
def test_no_writable_static_storage(built, tmp_path: Path, name: str) -> None:
    """Every source file of a plant, a controller and the Reference compiles to an object whose .data and .bss
    are empty: the only writable memory is the instance's (constant tables live in .rodata and .data.rel.ro),
    so two instances share nothing."""
    fmu, files = built[name]
    sources = _sources(fmu, tmp_path)
    for f in files:
        obj = tmp_path / f"{f}.o"
        subprocess.run(["gcc", *(c for c in CFLAGS if c != "-shared"), "-c", "-I", str(sources), str(sources / f),
                        "-o", str(obj)], check=True, capture_output=True)
        sections = subprocess.run(["objdump", "-h", str(obj)], check=True, capture_output=True, text=True).stdout
        sizes = {m.group(1): int(m.group(2), 16) for m in re.finditer(r"^\s*\d+\s+(\S+)\s+([0-9a-f]+)\s", sections, re.M)}
        assert ".text" in sizes, sections
        writable = {s: n for s, n in sizes.items() if (s.startswith((".data", ".bss")) and not s.startswith(".data.rel.ro")
                                                         and n > 0)}
        assert not writable, (f, writable)


def test_substeps_of_a_step_are_bounded(built, tmp_path: Path) -> None:
    """EMC_MAX_SUBSTEPS bounds a doStep's substeps (100000 by default, components.plant_step.MAX_SUBSTEPS; a
    real-time target compiles with -DEMC_MAX_SUBSTEPS=N). A MEMS step that needs more (a 1300 V jump with no
    charge at q = 0.06 m, the layer refused: the twin's PlantStepper takes > 5 substeps) answers fmi2Discard
    with the state kept when built with N = 3, and fmi2OK with the default bound."""
    from fmpy import extract, read_model_description
    from fmpy.fmi1 import FMICallException
    from fmpy.fmi2 import FMU2Slave

    from components.mems import MEMS
    from components.plant_step import PlantStepper
    plant, eta, u = MEMS(), (0.06, 2.8e-9, 0.0), 1300.0
    h = 5.0 * 35.6e-9 * (0.06 + 15e-6) * 100.0                   # five electrical time constants
    twin = PlantStepper(plant, rtol=1e-9)
    twin.step(np.array(eta), u, h)
    assert not twin.layer_applied and twin.n_substeps + twin.n_rejected > 5
    fmu = built["MEMS"][0]
    md = read_model_description(str(fmu))
    vr = {v.name: v.valueReference for v in md.modelVariables}
    for bound in (3, None):
        unzipped = Path(extract(str(fmu)))
        if bound is not None:                  # the same sources with the bound lowered
            library = unzipped / "binaries" / "linux64" / "MEMS.so"
            subprocess.run(["gcc", *CFLAGS, f"-DEMC_MAX_SUBSTEPS={bound}", "-I", str(unzipped / "sources"),
                            *(str(unzipped / "sources" / f) for f in SOURCE_FILES), "-o", str(library), "-lm"],
                           check=True, capture_output=True)
        slave = FMU2Slave(guid=md.guid, unzipDirectory=str(unzipped), modelIdentifier="MEMS", instanceName="m")
        slave.instantiate()
        slave.setupExperiment(startTime=0.0)
        slave.enterInitializationMode()
        slave.setReal([vr["q_0"], vr["p_0"], vr["x_e_0"], vr["rtol"]], [*eta, 1e-9])
        slave.exitInitializationMode()
        slave.setReal([vr["u"]], [u])
        if bound is not None:
            with pytest.raises(FMICallException) as info:
                slave.doStep(0.0, h)
            assert info.value.status == DISCARD
            assert slave.getReal([vr["q"], vr["p"], vr["x_e"]]) == list(eta)
        else:
            slave.doStep(0.0, h)
            assert slave.getReal([vr["x_e"]])[0] > 0.0
        slave.terminate()
        slave.freeInstance()
        shutil.rmtree(unzipped, ignore_errors=True)
