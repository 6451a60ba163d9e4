"""Session fixtures: the FMUs, built once per test session by build.py into a temporary folder."""
from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
if str(ROOT) not in sys.path:
    sys.path.insert(0, str(ROOT))


@pytest.fixture(scope="session")
def fmus(tmp_path_factory) -> dict[str, Path]:
    """Model identifier -> path of the freshly built FMU."""
    import build

    return build.build(tmp_path_factory.mktemp("fmus"), force=True, verbose=False)


@pytest.fixture(scope="session")
def fmu_dir() -> Path:
    """build/fmus, brought up to date with build.py (a no-op when nothing changed); or
    $EMCOSIM_FMU_DIR as it is. Missing FMUs fail the tests that need them (never a silent skip)."""
    import build

    if "EMCOSIM_FMU_DIR" in os.environ:
        d = Path(os.environ["EMCOSIM_FMU_DIR"])
    else:
        d = build.DEFAULT_DEST
        subprocess.run([sys.executable, str(ROOT / "build.py")], cwd=ROOT, check=True, capture_output=True)
    missing = [m for m in build.FMUS if not (d / f"{m}.fmu").is_file()]
    assert not missing, f"FMUs not built: {missing} in {d}"
    return d
