"""`emcosim plant check | build | scenario`: from a plant description file to FMUs and a closed-loop scenario.

    emcosim plant check FILE [--q-d Q ...] [--reference SPEC ...] [--json OUT]
    emcosim plant build FILE --out DIR
    emcosim plant scenario FILE --controller DESIGN --out DIR --stop-time T --step-size H [...]

check: which of Assumptions 1-4 hold, each with its test, and which designs apply (components.plant_check).
build: the plant FMU <name>.fmu, one controller FMU <name>_<design>.fmu per design that applies and the
Reference FMU, into DIR (fmus.build). scenario: an SSP scenario folder (emcosim.devices.scenario).

Their outputs follow the rules of the other commands' (engine/outputs.py, docs/reliability.md): the FMUs are
built in a marked temporary folder (engine/tempdirs.py: removed by the next command if this one is killed)
and each is written into DIR beside its name and renamed onto it (never through a link); a scenario folder is
written whole and replaces only a folder emcosim wrote (engine/output_folder.py); a device named like one of
the suite's FMUs that would be written into the same folder is refused.
"""
from __future__ import annotations

import argparse
import contextlib
import os
import sys
import tempfile
from pathlib import Path
from typing import Iterator

from components.device import DESIGNS, Device

from ..engine.errors import ScenarioError

OPERATING_POINT_HELP = ("how the free electrical coordinates are fixed when n_e > n_m, instead of the file's "
                        "[operating_point]: least_energy, least_input, or bias:NAME=VALUE|NAME=OTHER*RATIO,... "
                        "(docs/plant-description.md)")


def add_parser(sub) -> None:
    """The `plant` command and its three subcommands, on the CLI's subparsers."""
    plant = sub.add_parser("plant", help="a plant description file (TOML): check it, build its FMUs, write a scenario")
    psub = plant.add_subparsers(dest="plant_command")
    check = psub.add_parser("check", help="which of the paper's Assumptions 1-4 hold and which designs apply")
    check.add_argument("file")
    check.add_argument("--q-d", type=float, nargs="+", metavar="Q",
                       help="set-point positions (one per q; default: the description's [controller] q_d)")
    check.add_argument("--reference", action="append", default=[], metavar="KIND:NAME=VALUE,...",
                       help="reference of each position, e.g. sinusoid:offset=0.001,amplitude=3e-4,omega=31.4 "
                            "(repeat per position; kinds: constant, sinusoid, smooth_step)")
    check.add_argument("--horizon", type=float, default=None, help="horizon over which the reference is checked [s]")
    check.add_argument("--q0", type=float, nargs="+", metavar="Q",
                       help="initial positions of the scenario whose start input is reported (as plant scenario)")
    check.add_argument("--p0", type=float, nargs="+", metavar="P", help="initial momenta (default: rest)")
    check.add_argument("--x-e0", type=float, nargs="+", metavar="X",
                       help="initial electrical states (default: those of the equilibrium at q0)")
    check.add_argument("--operating-point", metavar="RULE", help=OPERATING_POINT_HELP)
    check.add_argument("--json", help="also write the report as JSON to this file")
    check.set_defaults(func=cmd_check)

    build = psub.add_parser("build", help="build the plant FMU and a controller FMU per design that applies")
    build.add_argument("file")
    build.add_argument("--out", required=True, help="folder for the FMUs")
    build.add_argument("--operating-point", metavar="RULE", help=OPERATING_POINT_HELP)
    build.set_defaults(func=cmd_build)

    scen = psub.add_parser("scenario", help="write an SSP scenario: the plant in closed loop with one controller")
    scen.add_argument("file")
    scen.add_argument("--controller", required=True, choices=DESIGNS, help="the design")
    scen.add_argument("--out", required=True, help="the scenario folder to write")
    scen.add_argument("--fmu-dir", help="the folder `emcosim plant build` wrote (default: build/<name> of the "
                                        "current folder); the .ssd names it relative to the scenario folder")
    scen.add_argument("--stop-time", type=float, required=True, help="stop time [s]")
    scen.add_argument("--step-size", type=float, required=True, help="communication step [s]")
    scen.add_argument("--q-d", type=float, nargs="+", metavar="Q", help="set-point positions (regulation)")
    scen.add_argument("--reference", action="append", default=[], metavar="KIND:NAME=VALUE,...",
                      help="reference of each position (tracking; repeat per position)")
    scen.add_argument("--q0", type=float, nargs="+", metavar="Q",
                      help="initial positions (default: q_d or q*(0))")
    scen.add_argument("--p0", type=float, nargs="+", metavar="P", help="initial momenta (default: rest, p = 0)")
    scen.add_argument("--x-e0", type=float, nargs="+", metavar="X",
                      help="initial electrical states (default: those of the equilibrium at q0, x_e = 0 where the "
                           "potential holds q0 alone)")
    scen.add_argument("--gain", action="append", default=[], metavar="NAME=VALUE",
                      help="a gain of the controller (repeatable; default: the description's)")
    scen.add_argument("--name", help="scenario name (default: <name>_<design>, lower case)")
    scen.add_argument("--operating-point", metavar="RULE", help=OPERATING_POINT_HELP)
    scen.set_defaults(func=cmd_scenario)
    plant.set_defaults(func=lambda args: _usage(plant))


def _usage(parser: argparse.ArgumentParser) -> int:
    parser.print_help(sys.stderr)
    return 2


def _describe(exc: Exception) -> ScenarioError:
    return ScenarioError(" ".join(str(exc).split()))


@contextlib.contextmanager
def _description_file(path: str, operating_point: str | None) -> Iterator[str]:
    """The description file to read: `path`, or, with a command-line operating point, a copy of it whose
    [operating_point] table is that choice (components.description.with_operating_point), so that the FMUs
    built from it carry the choice in their description."""
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


def _references(items: list[str]):
    from .scenario import parse_reference
    return [parse_reference(s) for s in items]


def cmd_check(args) -> int:
    from ..engine.outputs import check_destination, write_file
    from . import registry
    from .scenario import StackedReference, reference_components

    if args.json:
        check_destination(Path(args.json))
    try:
        with _description_file(args.file, args.operating_point) as file:
            reference = None
            if args.reference:
                from components import description as descriptions
                desc = descriptions.load(file)
                reference = StackedReference(reference_components(desc.q, _references(args.reference), desc.name))
            desc, report, device = registry.load(file, q_d=args.q_d, reference=reference, horizon=args.horizon)
            from .start import attach
            attach(report, device, desc, references=_references(args.reference), q_0=args.q0, p_0=args.p0,
                   x_e_0=args.x_e0, gains=_q_d_gains(device, args.q_d))
    except ValueError as exc:
        raise _describe(exc) from None
    print(report.text())
    if args.json:
        data = report.to_json().encode("utf-8")
        write_file(Path(args.json), lambda f: f.write(data))
        print(f"report written to {args.json}")
    return 0


def _q_d_gains(device, q_d) -> dict[str, float]:
    """The set-point as controller gains: q_d (n_m = 1) or q_d_1, q_d_2, ..."""
    if q_d is None:
        return {}
    names = ["q_d"] if len(q_d) == 1 and device.n_m == 1 else [f"q_d_{i + 1}" for i in range(len(q_d))]
    return dict(zip(names, q_d))


def cmd_build(args) -> int:
    try:
        with _description_file(args.file, args.operating_point) as file:
            return _build(file, Path(args.out))
    except ValueError as exc:                           # a wrong description or --operating-point
        raise _describe(exc) from None


def _build(file: str, out: Path) -> int:
    from fmus.build import BuildError

    from . import registry

    desc, report, device = registry.load(file)          # a ValueError is reported by cmd_build
    check_device_names(device, list(device.designs), out)
    for line in report.not_applicable():                # "<design>: <why>"
        print(f"not built   {device.name}_{line}")
    try:
        paths = build_fmus_of(desc, list(device.designs), out)
    except (BuildError, ValueError) as exc:
        raise _describe(exc) from None
    for path in paths.values():
        print(f"built       {path}")
    return 0


def check_device_names(device: Device, designs: list[str], out: Path) -> None:
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


def build_fmus_of(desc, designs: list[str], out: Path) -> dict[str, Path]:
    """The plant FMU, the controller FMUs of `designs` and the Reference FMU of a description, into `out`
    (fmus.build.build_description: the generated model module, no sympy at run time); every FMU carries the
    description as registry.DESCRIPTION_RESOURCE, by which `certify` knows the device.

    Built in a marked temporary folder of this process (engine/tempdirs.py), then each FMU is written into
    `out` by engine/outputs.write_file (a new file beside its name, renamed onto it: a link in `out` is never
    written through; a link in the FMU's own name is refused before anything is built)."""
    import shutil

    from fmus.build import build_description, build_fmus

    from ..engine import tempdirs
    from ..engine.outputs import check_destination, write_file
    from .registry import DESCRIPTION_RESOURCE

    names = [desc.name] + [f"{desc.name}_{d}" for d in designs] + ["Reference"]
    if out.exists() and not out.is_dir():
        raise ScenarioError(f"{out}: exists and is not a folder; --out names the folder for the FMUs")
    if out.is_dir():
        for name in names:                           # before the build: no minutes spent on a refusal
            check_destination(out / f"{name}.fmu")
    work = tempdirs.make("plant_build")
    try:
        copy = work / Path(DESCRIPTION_RESOURCE).name
        shutil.copyfile(desc.source, copy)
        built = build_description(copy, work / "fmus", designs, temp_root=work)
        built.update(build_fmus({"Reference": None}, work / "fmus", temp_root=work))
        out.mkdir(parents=True, exist_ok=True)
        paths = {}
        for identifier, path in built.items():
            data = path.read_bytes()
            paths[identifier] = write_file(out / path.name, lambda f, data=data: f.write(data))
    except OSError as exc:
        raise ScenarioError(f"{out}: cannot write the FMUs: {exc.strerror or exc}") from None
    finally:
        shutil.rmtree(work, ignore_errors=True)
    return paths


def cmd_scenario(args) -> int:
    from . import registry
    from .scenario import Setup, gain_values, scenario_files

    out = Path(args.out)
    try:
        with _description_file(args.file, args.operating_point) as file:
            desc, _, device = registry.load(file)
        gains = dict(gain_values(args.gain))
        gains.update(_q_d_gains(device, args.q_d))
        setup = Setup(args.controller, args.stop_time, args.step_size, gains=gains, references=_references(args.reference),
                      q_0=args.q0, p_0=args.p0, x_e_0=args.x_e0, name=args.name)
        fmu_dir = Path(args.fmu_dir) if args.fmu_dir else Path("build") / desc.name
        relative = str(fmu_dir) if fmu_dir.is_absolute() else os.path.relpath(fmu_dir.resolve(), out.resolve())
        files = scenario_files(device, setup, relative)
    except ValueError as exc:
        raise _describe(exc) from None
    check_device_names(device, [args.controller], fmu_dir)
    _write_folder(out, files)
    print(f"scenario    {out} ({', '.join(sorted(files))}); run it with `emcosim run {out}`")
    missing = [n for n in (device.name, device.controller_identifier(args.controller)) if not (fmu_dir / f"{n}.fmu").is_file()]
    if missing:
        print(f"emcosim: note: {', '.join(m + '.fmu' for m in missing)} not in {fmu_dir} yet: "
              f"`emcosim plant build {args.file} --out {fmu_dir}`", file=sys.stderr)
    return 0


def _write_folder(out: Path, files: dict[str, str]) -> None:
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
