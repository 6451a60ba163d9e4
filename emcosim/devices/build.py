"""A device's FMUs and scenario from its description file: the library behind `emcosim plant build | scenario`
and `emcosim.build_plant`, `emcosim.write_scenario` (the command line only parses, calls and prints).
"""
from __future__ import annotations

import contextlib
import os
import tempfile
from pathlib import Path
from typing import Callable, Iterator, Mapping, Sequence

from ..engine.errors import ScenarioError


@contextlib.contextmanager
def description_file(path: str | Path, operating_point: str | None) -> Iterator[str]:
    """The description file to read: `path`, or, with an operating point chosen by the caller (the command
    line's --operating-point), a copy of it whose [operating_point] table is that choice
    (components.description.with_operating_point), so that the FMUs built from it carry the choice in their
    description. A ValueError raised inside names the user's file, not the copy."""
    path = str(path)
    if operating_point is None:
        yield path
        return
    from components.description import with_operating_point
    try:
        text = Path(path).read_text(encoding="utf-8")
    except OSError:
        yield path                                       # components.description.load says why
        return
    with tempfile.TemporaryDirectory(prefix="emcosim_operating_point_") as tmp:
        copy = Path(tmp) / Path(path).name
        copy.write_text(with_operating_point(text, operating_point, path), encoding="utf-8")
        try:
            yield str(copy)
        except ValueError as exc:                        # name the user's file, not the copy
            raise type(exc)(str(exc).replace(str(copy), f"{path} (--operating-point {operating_point})")) from None


def q_d_gains(device, q_d: Sequence[float] | None) -> dict[str, float]:
    """The set-point as controller gains: q_d (n_m = 1) or q_d_1, q_d_2, ..."""
    if q_d is None:
        return {}
    names = ["q_d"] if len(q_d) == 1 and device.n_m == 1 else [f"q_d_{i + 1}" for i in range(len(q_d))]
    return dict(zip(names, q_d))


def check_device_names(device, designs: list[str], out: Path) -> None:
    """Refuse a device whose FMUs would take the name of one of the suite's own FMUs in `out`: the Reference
    FMU (built beside every device's) always; the paper's (fmus/models.py) when `out` is the suite's FMU
    folder (it holds the build stamp, or is fmus.build.default_dest())."""
    from fmus.build import FMUS, STAMP, default_dest

    names = [device.name] + [device.controller_identifier(d) for d in designs]
    suite = out.is_dir() and ((out / STAMP).exists() or out.resolve() == default_dest().resolve())
    taken = [n for n in names if n == "Reference" or (suite and n in FMUS)]
    if taken:
        where = "the Reference FMU built beside it" if taken == ["Reference"] else f"the suite's FMUs in {out}"
        raise ScenarioError(f"device {device.name!r}: its FMU {taken[0]}.fmu would replace {where}; "
                            "rename the device (its description's name) or build into another folder")


def build_fmus_of(description: str | Path, out: Path, progress: Callable[[str], None] | None = None) -> dict[str, Path]:
    """The plant FMU, a controller FMU per design that applies (components.plant_check: the others are
    reported through `progress` with the reason, and not built) and the Reference FMU of a description file,
    into `out` (fmus.build.build_description: the generated model module, no sympy at run time); every FMU
    carries the description as registry.DESCRIPTION_RESOURCE, by which `certify` knows the device. `progress`
    gets one line as each step starts and as each FMU is written. ValueError (a DescriptionError) for a wrong
    entry, fmus.build.BuildError for a missing compiler or header, ScenarioError for an `out` it cannot write.

    Built in a marked temporary folder of this process (engine/tempdirs.py), then each FMU is written into
    `out` by engine/outputs.write_file (a new file beside its name, renamed onto it: a link in `out` is never
    written through; a link in the FMU's own name is refused before anything is built)."""
    import shutil

    from fmus.build import build_description, build_fmus

    from ..engine import tempdirs
    from ..engine.outputs import check_destination, write_file
    from . import registry

    say = progress or (lambda line: None)
    desc, report, device = registry.load(description)
    designs = list(device.designs)
    check_device_names(device, designs, out)
    for line in report.not_applicable():                # "<design>: <why>"
        say(f"not built   {device.name}_{line}")
    names = [desc.name] + [f"{desc.name}_{d}" for d in designs] + ["Reference"]
    if out.exists() and not out.is_dir():
        raise ScenarioError(f"{out}: exists and is not a folder; --out names the folder for the FMUs")
    if out.is_dir():
        for name in names:                           # before the build: no minutes spent on a refusal
            check_destination(out / f"{name}.fmu")
    work = tempdirs.make("plant_build")
    try:
        say(f"building    {', '.join(names[:-1])} ...")
        built = build_description(desc.source, work / "fmus", designs, temp_root=work)
        say("building    Reference ...")
        built.update(build_fmus({"Reference": None}, work / "fmus", temp_root=work))
        out.mkdir(parents=True, exist_ok=True)
        paths = {}
        for identifier, path in built.items():
            data = path.read_bytes()
            paths[identifier] = write_file(out / path.name, lambda f, data=data: f.write(data))  # type: ignore[misc]
            say(f"built       {paths[identifier]}")
    except OSError as exc:
        raise ScenarioError(f"{out}: cannot write the FMUs: {exc.strerror or exc}") from None
    finally:
        shutil.rmtree(work, ignore_errors=True)
    return paths


def build_native_fmus_of(description: str | Path, out: Path,
                         progress: Callable[[str], None] | None = None) -> dict[str, Path]:
    """`plant build --native`: the native (C, self-contained) plant FMU of a description file, a native controller
    FMU per design that applies (any n_m, n_e: fmus.native_build) and the native Reference FMU, into `out`.
    NativeBuildError for a missing compiler or a design whose feasible reference has no native form (n_e < n_m,
    coupled coils with n_e > n_m: the pythonfmu controller has none either); the FMUs written before it stay."""
    from fmus.native_build import build_native_description_fmus, build_native_reference

    from . import registry

    say = progress or (lambda line: None)
    desc, report, device = registry.load(description)
    designs = list(device.designs)
    check_device_names(device, designs, out)
    for line in report.not_applicable():                # "<design>: <why>"
        say(f"not built   {device.name}_{line}")
    paths = build_native_description_fmus(desc.source, designs, out)
    paths["Reference"] = build_native_reference(out)
    for path in paths.values():
        say(f"built       {path}")
    return paths


def scenario_of(description: str | Path, out: str | Path, controller: str, stop_time: float, step_size: float | None, *,
                fmu_dir: str | Path | None = None, q_d: Sequence[float] | None = None, references: Sequence = (),
                q0: Sequence[float] | None = None, p0: Sequence[float] | None = None,
                x_e0: Sequence[float] | None = None, gains: Mapping[str, float] | None = None,
                name: str | None = None) -> tuple[dict[str, str], Path, list[str]]:
    """Write the closed-loop scenario folder `out` of a description file with the design `controller`
    (emcosim.devices.scenario.scenario_files) and return (its files, the FMU folder, the FMUs not yet there). The FMU
    folder (default build/<name> of the working folder) is named in the .ssd relative to `out`. The plant
    starts at `q0` (default q_d or q*(0)), `p0` (default rest) and `x_e0` (default the equilibrium's). ValueError for
    a wrong setting, ScenarioError for a folder that is not a scenario's. The scenario is named `name`, by
    default after its folder (so `emcosim run DIR` writes DIR.csv)."""
    from . import registry
    from .scenario import Setup, scenario_files

    out = Path(out)
    desc, report, device = registry.load(description)
    refused = {d.name: d.reason for d in report.design_verdicts if not d.applies}
    if controller in refused:                           # the check's reason, not a later symptom (issue 42)
        raise ValueError(f"{desc.source}: {controller} does not apply: {refused[controller]}")
    chosen = dict(gains or {})
    chosen.update(q_d_gains(device, q_d))
    setup = Setup(controller, stop_time, step_size, gains=chosen, references=list(references),
                  q_0=None if q0 is None else list(q0), p_0=None if p0 is None else list(p0),
                  x_e_0=None if x_e0 is None else list(x_e0), name=name or out.resolve().name)
    folder = Path(fmu_dir) if fmu_dir else Path("build") / desc.name
    relative = str(folder) if folder.is_absolute() else os.path.relpath(folder.resolve(), out.resolve())
    files = scenario_files(device, setup, relative)
    check_device_names(device, [controller], folder)
    write_folder(out, files)
    missing = [f"{n}.fmu" for n in (device.name, device.controller_identifier(controller))
               if not (folder / f"{n}.fmu").is_file()]
    return files, folder, missing


def write_folder(out: Path, files: Mapping[str, str]) -> None:
    """Write the scenario's files as the folder `out` (its parents created if missing), whole: through an
    engine OutputFolder (its manifest `.emcosim` lists what emcosim wrote), which replaces an existing `out`
    only if that holds nothing but what an earlier run of emcosim wrote there, unchanged (an empty folder
    too), and refuses anything else, naming what it holds; no file is written through a link."""
    from ..engine.files import create_text
    from ..engine.output_folder import OutputFolder

    out.absolute().parent.mkdir(parents=True, exist_ok=True)
    folder = OutputFolder(out)
    try:
        for name, text in files.items():
            create_text(folder.path / name, text)
    except BaseException:
        folder.discard()
        raise
    folder.commit()
