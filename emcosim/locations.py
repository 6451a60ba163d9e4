"""Where emcosim finds the paper's scenarios and their FMUs, from a checkout or from an installed wheel.

In a checkout (plain or an editable install) the scenarios are the repository's scenarios/ and their FMUs its
build/fmus, where the .ssd files point. An installed wheel holds the scenarios as package data,
emcosim/scenarios/<name>/ (read-only), and their FMUs go to build/fmus of the working folder (where `emcosim
reproduce` builds them), never into site-packages. Knows no physics: the paper's layer, the API and the command
line read these names, and none of them needs to import emcosim.paper to do so.
"""
from __future__ import annotations

from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]                    # the checkout, when run from one
PACKAGED = Path(__file__).resolve().parent / "scenarios"      # emcosim/scenarios/: the wheel's package data
INSTALLED = PACKAGED.is_dir()                                 # a wheel's install (else a checkout)
SCENARIOS = PACKAGED if INSTALLED else ROOT / "scenarios"     # the paper's scenarios, found from any folder


def fmu_dir() -> Path:
    """Where the paper's scenarios take their FMUs from, and where `emcosim reproduce` builds them
    (fmus.build.default_dest): a checkout's build/fmus (where the .ssd files point), else the working
    folder's build/fmus, writable for the user (never site-packages)."""
    from fmus.build import default_dest

    return default_dest()


def fmus_of(ssd: Path, given: str | Path | None) -> str | Path | None:
    """The FMU folder to read the scenario `ssd` with: `given` (--fmu-dir) if any; for one of the paper's
    scenarios `fmu_dir()`; else None (the .ssd's own paths)."""
    if given is not None:
        return given
    if Path(ssd).resolve().is_relative_to(SCENARIOS.resolve()):
        return fmu_dir()
    return None
