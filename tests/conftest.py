"""Session fixtures: the FMUs, built once per test session (fmus.build, a no-op when build/fmus is up to date)."""
from __future__ import annotations

import os
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
if str(ROOT) not in sys.path:
    sys.path.insert(0, str(ROOT))


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
