"""A device's FMUs and scenario from its description file: the library behind `emcosim plant build | scenario`
and `emcosim.build_plant`, `emcosim.write_scenario` (the command line only parses, calls and prints).
"""
from __future__ import annotations

import os
from pathlib import Path
from typing import Callable, Mapping, Sequence

from ..engine.errors import ScenarioError


def build_fmus_of(description: str | Path, out: Path, progress: Callable[[str], None] | None = None) -> dict[str, Path]:
    """The plant FMU, a controller FMU per design that applies (components.plant_check: the others are
    reported through `progress` with the reason, and not built) and the Reference FMU of a description file,
    into `out` (fmus.build.build_description: the generated model module, no sympy at run time); every FMU
    carries the description as registry.DESCRIPTION_RESOURCE, by which `certify` knows the device. `progress`
    gets one line as each step starts and as each FMU is written. ValueError (a DescriptionError) for a wrong
    entry, fmus.build.BuildError for a missing compiler or header."""
    from fmus.build import build_description, build_fmus

    from . import registry

    say = progress or (lambda line: None)
    desc, report, device = registry.load(description)
    for line in report.not_applicable():                # "<design>: <why>"
        say(f"not built   {device.name}_{line}")
    designs = list(device.designs)
    say(f"building    {device.name} and {', '.join(f'{device.name}_{d}' for d in designs) or 'no controller'} "
        f"into {out} ...")
    paths = build_description(desc.source, out, designs)
    for path in paths.values():
        say(f"built       {path}")
    say("building    Reference ...")
    reference = build_fmus({"Reference": None}, out)
    for path in reference.values():
        say(f"built       {path}")
    return {**paths, **reference}


def scenario_of(description: str | Path, out: str | Path, controller: str, stop_time: float, step_size: float, *,
                fmu_dir: str | Path | None = None, q_d: Sequence[float] | None = None, references: Sequence = (),
                q0: Sequence[float] | None = None, gains: Mapping[str, float] | None = None,
                name: str | None = None) -> tuple[dict[str, str], Path, list[str]]:
    """Write the closed-loop scenario folder `out` of a description file with the design `controller`
    (emcosim.devices.scenario.scenario_files) and return (its files, the FMU folder, the FMUs not yet there). The FMU
    folder (default build/<name> of the working folder) is named in the .ssd relative to `out`. ValueError for
    a wrong setting, ScenarioError for a folder that is not a scenario's. The scenario is named `name`, by
    default after its folder (so `emcosim run DIR` writes DIR.csv)."""
    from . import registry
    from .scenario import Setup, scenario_files

    out = Path(out)
    desc, _, device = registry.load(description)
    chosen = dict(gains or {})
    if q_d is not None:
        names = ["q_d"] if len(q_d) == 1 and device.n_m == 1 else [f"q_d_{i + 1}" for i in range(len(q_d))]
        chosen.update(zip(names, q_d))
    setup = Setup(controller, stop_time, step_size, gains=chosen, references=list(references),
                  q_0=None if q0 is None else list(q0), name=name or out.resolve().name)
    folder = Path(fmu_dir) if fmu_dir else Path("build") / desc.name
    relative = str(folder) if folder.is_absolute() else os.path.relpath(folder.resolve(), out.resolve())
    files = scenario_files(device, setup, relative)
    write_folder(out, files)
    missing = [f"{n}.fmu" for n in (device.name, device.controller_identifier(controller))
               if not (folder / f"{n}.fmu").is_file()]
    return files, folder, missing


def write_folder(out: Path, files: Mapping[str, str]) -> None:
    """Write the scenario's files into `out` (created if missing). A folder holding anything but a
    scenario's files is refused; no file is written through a link."""
    from ..engine.outputs import write_file

    if out.is_symlink() or (out.exists() and not out.is_dir()):
        raise ScenarioError(f"{out}: not a folder (a link or a file); the scenario is written into a folder")
    if out.is_dir():
        foreign = sorted(p.name for p in out.iterdir()
                         if not (p.suffix in (".ssd", ".ssv") and p.is_file() and not p.is_symlink()))
        if foreign:
            raise ScenarioError(f"{out}: holds files that are not a scenario's ({', '.join(foreign[:5])}); "
                                "choose an empty or new folder")
    out.mkdir(parents=True, exist_ok=True)
    for name, text in files.items():
        data = text.encode("utf-8")
        write_file(out / name, lambda f, data=data: f.write(data))   # type: ignore[misc]
