"""`emcosim plant check | build | scenario`: from a plant description file to FMUs and a closed-loop scenario.

    emcosim plant check FILE [--q-d Q ...] [--reference SPEC ...] [--json OUT]
    emcosim plant build FILE --out DIR
    emcosim plant scenario FILE --controller DESIGN --out DIR --stop-time T [--step-size H] [...]

check: which of Assumptions 1-4 hold, each with its test, and which designs apply (components.plant_check).
build: the plant FMU <name>.fmu, one controller FMU <name>_<design>.fmu per design that applies and the
Reference FMU, into DIR (fmus.build). scenario: an SSP scenario folder (emcosim.devices.scenario).
"""
from __future__ import annotations

import argparse
import os
import sys
from pathlib import Path

from components.device import DESIGNS

from ..engine.errors import ScenarioError


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
    check.add_argument("--json", help="also write the report as JSON to this file")
    check.set_defaults(func=cmd_check)

    build = psub.add_parser("build", help="build the plant FMU and a controller FMU per design that applies")
    build.add_argument("file")
    build.add_argument("--out", required=True, help="folder for the FMUs")
    build.set_defaults(func=cmd_build)

    scen = psub.add_parser("scenario", help="write an SSP scenario: the plant in closed loop with one controller")
    scen.add_argument("file")
    scen.add_argument("--controller", required=True, choices=DESIGNS, help="the design")
    scen.add_argument("--out", required=True, help="the scenario folder to write")
    scen.add_argument("--fmu-dir", help="the folder `emcosim plant build` wrote (default: build/<name> of the "
                                        "current folder); the .ssd names it relative to the scenario folder")
    scen.add_argument("--stop-time", type=float, required=True, help="stop time [s]")
    scen.add_argument("--step-size", type=float, help="communication step [s] (default: chosen from the closed loop's "
                      "linearization at its initial state, and explicit or implicit coupling with it: the scenario's "
                      "notes and this command say how; emcosim/devices/step_choice.py)")
    scen.add_argument("--q-d", type=float, nargs="+", metavar="Q", help="set-point positions (regulation)")
    scen.add_argument("--reference", action="append", default=[], metavar="KIND:NAME=VALUE,...",
                      help="reference of each position (tracking; repeat per position)")
    scen.add_argument("--q0", type=float, nargs="+", metavar="Q",
                      help="initial positions: at rest with the equilibrium's electrical state (default: q_d or q*(0))")
    scen.add_argument("--gain", action="append", default=[], metavar="NAME=VALUE",
                      help="a gain of the controller (repeatable; default: the description's)")
    scen.add_argument("--name", help="scenario name (default: <name>_<design>, lower case)")
    scen.set_defaults(func=cmd_scenario)
    plant.set_defaults(func=lambda args: _usage(plant))


def _usage(parser: argparse.ArgumentParser) -> int:
    parser.print_help(sys.stderr)
    return 2


def _describe(exc: Exception) -> ScenarioError:
    return ScenarioError(" ".join(str(exc).split()))


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
        reference = None
        if args.reference:
            from components import description as descriptions
            desc = descriptions.load(args.file)
            reference = StackedReference(reference_components(desc.q, _references(args.reference), desc.name))
        _, report, _ = registry.load(args.file, q_d=args.q_d, reference=reference, horizon=args.horizon)
    except ValueError as exc:
        raise _describe(exc) from None
    print(report.text())
    if args.json:
        data = report.to_json().encode("utf-8")
        write_file(Path(args.json), lambda f: f.write(data))
        print(f"report written to {args.json}")
    return 0


def cmd_build(args) -> int:
    from fmus.build import BuildError

    from . import registry

    try:
        desc, report, device = registry.load(args.file)
    except ValueError as exc:
        raise _describe(exc) from None
    for line in report.not_applicable():                # "<design>: <why>"
        print(f"not built   {device.name}_{line}")
    try:
        paths = build_fmus_of(desc, list(device.designs), Path(args.out))
    except (BuildError, ValueError) as exc:
        raise _describe(exc) from None
    for path in paths.values():
        print(f"built       {path}")
    return 0


def build_fmus_of(desc, designs: list[str], out: Path) -> dict[str, Path]:
    """The plant FMU, the controller FMUs of `designs` and the Reference FMU of a description, into `out`
    (fmus.build.build_description: the generated model module, no sympy at run time); every FMU carries the
    description as registry.DESCRIPTION_RESOURCE, by which `certify` knows the device."""
    import shutil
    import tempfile

    from fmus.build import build_description, build_fmus

    from .registry import DESCRIPTION_RESOURCE

    with tempfile.TemporaryDirectory(prefix="emcosim_plant_") as tmp:
        copy = Path(tmp) / Path(DESCRIPTION_RESOURCE).name
        shutil.copyfile(desc.source, copy)
        paths = build_description(copy, out, designs)
    paths.update(build_fmus({"Reference": None}, out))
    return paths


def cmd_scenario(args) -> int:
    from . import registry
    from .scenario import Setup, gain_values, scenario_files

    out = Path(args.out)
    try:
        desc, _, device = registry.load(args.file)
        gains = dict(gain_values(args.gain))
        if args.q_d is not None:
            names = ["q_d"] if len(args.q_d) == 1 and device.n_m == 1 else [f"q_d_{i + 1}" for i in range(len(args.q_d))]
            gains.update(zip(names, args.q_d))
        setup = Setup(args.controller, args.stop_time, args.step_size, gains=gains, references=_references(args.reference),
                      q_0=args.q0, name=args.name)
        fmu_dir = Path(args.fmu_dir) if args.fmu_dir else Path("build") / desc.name
        relative = str(fmu_dir) if fmu_dir.is_absolute() else os.path.relpath(fmu_dir.resolve(), out.resolve())
        files = scenario_files(device, setup, relative)
    except ValueError as exc:
        raise _describe(exc) from None
    _write_folder(out, files)
    print(f"scenario    {out} ({', '.join(sorted(files))}); run it with `emcosim run {out}`")
    if args.step_size is None:
        print(f"step        {_chosen_step(files['SystemStructure.ssd'])}")
    missing = [n for n in (device.name, device.controller_identifier(args.controller)) if not (fmu_dir / f"{n}.fmu").is_file()]
    if missing:
        print(f"emcosim: note: {', '.join(m + '.fmu' for m in missing)} not in {fmu_dir} yet: "
              f"`emcosim plant build {args.file} --out {fmu_dir}`", file=sys.stderr)
    return 0


def _chosen_step(ssd: str) -> str:
    """The sentence of the .ssd's notes that says how its default step was chosen (step_choice.py)."""
    import re

    found = re.search(r"Default step .*?(?=\.\s*(?:-->|\n|$))", ssd, flags=re.S)
    return " ".join(found.group(0).split()) if found else "chosen from the loop's linearization"


def _write_folder(out: Path, files: dict[str, str]) -> None:
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
        write_file(out / name, lambda f, data=data: f.write(data))
