"""`emcosim plant check | build | scenario`: from a plant description file to FMUs and a closed-loop scenario.

    emcosim plant check FILE [--q-d Q ...] [--reference SPEC ...] [--json OUT]
    emcosim plant build FILE --out DIR [--native]
    emcosim plant scenario FILE --controller DESIGN --out DIR --stop-time T [--step-size H] [...]

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
import sys
import warnings
from pathlib import Path

from components.device import DESIGNS

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
    build.add_argument("--native", action="store_true",
                       help="build native (C, self-contained) FMUs instead (docs/native-fmus.md)")
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
                      help="initial positions (default: q_d or q*(0))")
    scen.add_argument("--p0", type=float, nargs="+", metavar="P", help="initial momenta (default: rest, p = 0)")
    scen.add_argument("--x-e0", type=float, nargs="+", metavar="X",
                      help="initial electrical states (default: those of the equilibrium at q0, x_e = 0 where the "
                           "potential holds q0 alone)")
    scen.add_argument("--gain", action="append", default=[], metavar="NAME=VALUE",
                      help="a gain of the controller (repeatable; default: the description's); strict=0 writes a "
                           "scenario whose gains violate a condition of the design (warned), strict=1 (the default) "
                           "refuses it, here and at the controller's initialization")
    scen.add_argument("--name", help="scenario name (default: the folder's name, so that `emcosim run DIR` writes DIR.csv)")
    scen.add_argument("--operating-point", metavar="RULE", help=OPERATING_POINT_HELP)
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
    from .build import description_file, q_d_gains
    from .scenario import StackedReference, reference_components

    if args.json:
        check_destination(Path(args.json))
    try:
        reference_of = None
        if args.reference:
            references = _references(args.reference)

            def reference_of(desc):
                return StackedReference(reference_components(desc.q, references, desc.name))
        with description_file(args.file, args.operating_point) as file:
            desc, report, device = registry.load(file, q_d=args.q_d, horizon=args.horizon, reference_of=reference_of)
            from .start import attach
            attach(report, device, desc, references=_references(args.reference), q_0=args.q0, p_0=args.p0,
                   x_e_0=args.x_e0, gains=q_d_gains(device, args.q_d))
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
    from fmus.native_build import NativeBuildError

    from .build import build_fmus_of, build_native_fmus_of, description_file

    build = build_native_fmus_of if args.native else build_fmus_of
    try:
        with description_file(args.file, args.operating_point) as file:
            build(file, Path(args.out), progress=lambda line: print(line, flush=True))
    except (BuildError, NativeBuildError, ValueError) as exc:            # a wrong description or --operating-point
        raise _describe(exc) from None
    return 0


def cmd_scenario(args) -> int:
    from components.certificates import DesignConditionWarning

    from .build import description_file, scenario_of
    from .scenario import gain_values

    out = Path(args.out)
    try:
        with description_file(args.file, args.operating_point) as file, warnings.catch_warnings(record=True) as warned:
            warnings.simplefilter("always", DesignConditionWarning)
            files, fmu_dir, missing = scenario_of(file, out, args.controller, args.stop_time, args.step_size,
                                                  fmu_dir=args.fmu_dir, q_d=args.q_d,
                                                  references=_references(args.reference), q0=args.q0, p0=args.p0,
                                                  x_e0=args.x_e0, gains=dict(gain_values(args.gain)), name=args.name)
    except ValueError as exc:
        raise _describe(exc) from None
    for w in warned:
        print(f"emcosim: warning: {w.message}", file=sys.stderr)
    print(f"scenario    {out} ({', '.join(sorted(files))}); run it with `emcosim run {out}`")
    if args.step_size is None:
        print(f"step        {_chosen_step(files['SystemStructure.ssd'])}")
    if missing:
        print(f"emcosim: note: {', '.join(missing)} not in {fmu_dir} yet: "
              f"`emcosim plant build {args.file} --out {fmu_dir}`", file=sys.stderr)
    return 0


def _chosen_step(ssd: str) -> str:
    """The sentence of the .ssd's notes that says how its default step was chosen (step_choice.py)."""
    import re

    found = re.search(r"Default step .*?(?=\.\s*(?:-->|\n|$))", ssd, flags=re.S)
    return " ".join(found.group(0).split()) if found else "chosen from the loop's linearization"
