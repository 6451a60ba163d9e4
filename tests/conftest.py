"""Session fixtures: the FMUs, built once per test session by build.py into a temporary folder."""
from __future__ import annotations

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
