"""From a plant description file to a registered device: parse it, decide which designs apply, register it.

`emcosim plant ...` starts from the description file; `certify` and the reports start from a scenario whose
controller FMU was built from one (the FMU carries its description in resources/, DESCRIPTION_RESOURCE).
"""
from __future__ import annotations

import zipfile
from pathlib import Path

from components import catalog
from components.device import Device
from fmus.build import DESCRIPTION_RESOURCE  # noqa: F401 - where `emcosim plant build` puts the file in an FMU


def load(path: str | Path, q_d=None, reference=None, horizon: float | None = None, reference_of=None):
    """(description, check report, device) of a description file; the device has the designs the check
    finds applicable. DescriptionError (a ValueError) names a wrong entry. `reference_of(desc)`, if given,
    makes the reference from the parsed description.

    The file is parsed and checked, and the model module generated, in a worker process
    (components.bounded.in_worker): a signal or the time limit stops it even inside C; this process only
    executes the generated source (names checked, text as string literals)."""
    return _checked(str(path), None, q_d, reference, horizon, reference_of)


def _checked(path: str | None, text: tuple[str, str] | None, q_d=None, reference=None, horizon: float | None = None,
             reference_of=None):
    from components import bounded, codegen, plant_check  # noqa: F401 - imported before the fork: the worker imports nothing

    desc, report, source = bounded.in_worker(_parse_and_check, path, text, q_d, reference, horizon, reference_of,
                                             what=f"{path or text[1]}: parsing and checking")
    return desc, report, codegen.device(desc, list(report.designs), source)


def _parse_and_check(path: str | None, source_or_text: tuple[str, str] | None, q_d, reference, horizon, reference_of):
    """In the worker: (description, report, generated module source)."""
    from components import codegen, plant_check
    from components import description as descriptions

    if path is not None:
        desc = descriptions.load(path)
    else:
        text, source = source_or_text or ("", "")
        desc = descriptions.parse(text, source)
    if reference_of is not None:
        reference = reference_of(desc)
    report = plant_check.check(desc, q_d=q_d, reference=reference, horizon=horizon)
    return desc, report, codegen.module_source(desc, Path(desc.source).name)


def register_description(path: str | Path) -> Device:
    """Load a description and register its device (components.catalog.register). A device of that name
    already registered is returned if it is the same (parameters, variables, designs); another one of the same
    name is refused (ValueError)."""
    return _register(*load(path))


def _register(desc, _report, device: Device) -> Device:
    known = catalog.DEVICES.get(desc.name)
    if known is not None:
        if _signature(known) == _signature(device):
            return known
        raise ValueError(f"{desc.source}: a different device named {desc.name!r} is already known; rename it (name = ...)")
    catalog.register(device)
    return device


def _signature(device: Device) -> tuple:
    return (device.parameters, device.q, device.p, device.x_e, device.u,
            {name: d.gains for name, d in device.designs.items()})


def register_fmu(fmu: str | Path) -> Device | None:
    """The device of an FMU built by `emcosim plant build` (None for any other FMU), registered."""
    try:
        with zipfile.ZipFile(fmu) as z:
            if DESCRIPTION_RESOURCE not in z.namelist():
                return None
            text = z.read(DESCRIPTION_RESOURCE).decode("utf-8")
    except (OSError, zipfile.BadZipFile, UnicodeDecodeError):
        return None
    return _register(*_checked(None, (text, f"{fmu}:{DESCRIPTION_RESOURCE}")))
