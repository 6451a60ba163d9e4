"""Command line interface `emcosim`: run, export and inspect SSP scenarios.

    emcosim run SCENARIO [--stop-time T] [--step-size H] [--set component.variable=value ...]
                         [--output results.csv] [--plot results.png] [--record a.x,b.y]
    emcosim export SCENARIO -o loop.fmu
    emcosim info [SCENARIO ...]
    emcosim reproduce [--out DIR]
    emcosim certify SCENARIO [--radius R] [--include-start] [--json FILE]
    emcosim linearize SCENARIO [--t T] [--at reference|start|NAME=VALUE,...] [--inputs a.u,...] [--outputs a.y,...]
                               [--out FILE.json]

SCENARIO is a scenario name (a folder of scenarios/), a folder holding SystemStructure.ssd, an
.ssd file or an .ssp archive. Errors are reported on one line; the exit status is then 1 (2 for
a usage error, 128 + the signal's number for a run stopped by SIGINT (130) or SIGTERM (143)); certify
exits 3 when it certifies no rate, 4 when a condition of the design's result fails. docs/cli.md has
the one table of every status.
Results are written safely: see emcosim.engine.results (a failed or interrupted run leaves
NAME.partial.csv or NAME.partial/, never a half-written NAME.csv).
"""
from __future__ import annotations

import argparse
import re
import shutil
import sys
from pathlib import Path

from .engine.errors import Interrupted, ResultNotAccepted, ScenarioError, SimulationError

# the command line's names of the engine's options (the engine's messages name them as its API does)
FLAGS = {"stop_time": "--stop-time", "step_size": "--step-size", "tolerance": "--tolerance", "max_step": "--max-step",
         "coupling": "--coupling", "coupling_order": "--coupling-order", "max_steps": "--max-steps",
         "start_values": "--set", "max_bytes": "--ssp-max-size", "max_files": "--ssp-max-files",
         "allow_external": "--allow-external", "interface_type": "--interface-type", "solver": "--solver",
         "solver_steps": "--solver-steps", "rtol": "--rtol", "max_runs": "--max-runs",
         "error_threshold": "--error-threshold"}


NOT_ACCEPTED = 5              # exit status of a run whose result the library does not accept (engine/verdict.py)

NUMBER_OPTIONS = ("--error-threshold", "--stop-time", "--step-size", "--tolerance", "--max-step", "--radius", "--rtol")
NEGATIVE_NUMBER = re.compile(r"^-(\d+\.?\d*|\.\d+)([eE][-+]?\d+)?$")


def _join_negative_numbers(argv: list[str]) -> list[str]:
    """`--step-size -1e-5` as `--step-size=-1e-5`: argparse takes '-1e-5' for an option (it only
    recognises negative numbers without an exponent), so the value would be missing."""
    out: list[str] = []
    for token in argv:
        if out and out[-1] in NUMBER_OPTIONS and NEGATIVE_NUMBER.match(token):
            out[-1] = f"{out[-1]}={token}"
        else:
            out.append(token)
    return out


def main(argv: list[str] | None = None) -> int:
    parser = _parser()
    args = parser.parse_args(_join_negative_numbers(sys.argv[1:] if argv is None else list(argv)))
    if args.command is None:
        parser.print_help(sys.stderr)
        return 2
    from .engine import stopping, tempdirs

    tempdirs.clean_stale()                         # unpacked FMUs of killed runs
    try:
        # the sweep's client and the plant commands run no FMU: a signal may stop them at once; elsewhere
        # between two steps
        with stopping.on_signals(graceful=args.command not in ("sweep", "plant")):
            status = args.func(args)
            signum = stopping.requested()
        if signum is not None:                     # a command that never stopped to look: it ran to its end
            name = "SIGTERM" if signum == 15 else "SIGINT"
            print(f"emcosim: interrupted by {name} (the command finished before it could stop)", file=sys.stderr)
            return 128 + signum
        return status
    except ResultNotAccepted as exc:               # a complete run whose result is not accepted (engine/verdict.py)
        print(f"emcosim: warning: {error_line(exc)} (exit status {NOT_ACCEPTED}, docs/cli.md)", file=sys.stderr)
        return NOT_ACCEPTED
    except Interrupted as exc:                     # stopped between two communication points
        print(f"emcosim: error: {error_line(exc)}", file=sys.stderr)
        return 128 + exc.signal
    except ScenarioError as exc:                   # includes SimulationError
        print(f"emcosim: error: {error_line(exc)}", file=sys.stderr)
        return 1
    except BrokenPipeError:                        # e.g. `emcosim info | head`
        return 0
    except KeyboardInterrupt as exc:               # a second Ctrl-C, or a signal to the sweep
        signum = getattr(exc, "signal", 2)
        print(f"emcosim: interrupted by {'SIGTERM' if signum == 15 else 'SIGINT'}", file=sys.stderr)
        return 128 + signum
    except Exception as exc:                       # anything unforeseen: still one line
        print(f"emcosim: error: {type(exc).__name__}: {' '.join(str(exc).split())}", file=sys.stderr)
        return 1


def error_line(exc: ScenarioError) -> str:
    """The engine's error as one line, its options named by their flags, with the notes added on the way."""
    return " ".join("; ".join([exc.describe(FLAGS), *getattr(exc, "__notes__", [])]).split())


def _parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog="emcosim", description="Co-simulation of SSP scenarios of FMI 2.0 FMUs.")
    p.add_argument("--version", action="version", version=f"emcosim {_version()}")
    sub = p.add_subparsers(dest="command")
    ssp = _archive_options()

    run = sub.add_parser("run", help="run a scenario and record its variables to CSV", parents=[ssp])
    run.add_argument("scenario")
    run.add_argument("--stop-time", type=float, help="stop time [s] (default: the scenario's)")
    run.add_argument("--step-size", type=float, help="communication step [s] (default: the scenario's)")
    run.add_argument("--set", action="append", default=[], metavar="COMPONENT.VARIABLE=VALUE",
                     help="override a parameter or input start value (repeatable)")
    run.add_argument("--output", "-o", help="results CSV (default: SCENARIO_NAME.csv); written as the run goes "
                                           "and renamed into place at the end (a failed run: NAME.partial.csv)")
    run.add_argument("--plot", metavar="FILE.png",
                     help="also draw the run to this image file (.png, .svg, .pdf): for the paper's scenarios "
                          "q against q*, the error q - q*, u, x_e and H in physical units; for any other "
                          "scenario one axis per recorded variable, in its unit")
    run.add_argument("--record", metavar="COMPONENT.VARIABLE,...",
                     help="comma-separated full variable names to record, e.g. plant.q,controller.u "
                          "(`emcosim info SCENARIO` lists every variable). Default: every output connector "
                          "and every unconnected input, so each connected value is recorded once (a "
                          "connection's two ends carry the same value)")
    run.add_argument("--tolerance", type=float, metavar="TOL",
                     help="relative error [1, dimensionless, e.g. 1e-3] that every recorded variable keeps over "
                          "the run, measured against the largest magnitude it reaches: the communication steps are "
                          "chosen for it (FMU-state rollback, a shadow copy of the FMUs for the error estimate) and "
                          "--step-size is the first step [s]; the run prints the steps taken and rejected and the "
                          "estimated error. Needs FMUs with canGetAndSetFMUstate")
    run.add_argument("--max-step", type=float, metavar="H",
                     help="largest communication step with --tolerance [s] (default: a fiftieth of the run)")
    run.add_argument("--coupling-order", type=int, choices=range(0, 4), metavar="K",
                     help="highest time derivative of a connected value handed to its input [0..3]: 0 holds the "
                          "value over a step (zero-order hold), K >= 1 passes the derivatives 1..K [unit of the "
                          "value per s^k] so the input follows a polynomial of degree K. Default: as many as both "
                          "ends of a connection declare (maxOutputDerivativeOrder, canInterpolateInputs), plus one "
                          "estimated by backward difference where the target takes it. Explicit coupling only: "
                          "with it, a scenario whose default is implicit runs explicitly")
    run.add_argument("--coupling", choices=("explicit", "implicit"),
                     help="explicit: the inputs follow polynomials from their sources' derivatives at the start "
                          "of each step; implicit: each step is repeated (FMU-state rollback) until the inputs "
                          "of the FMUs with states agree with their sources at its end, stable on stiff loops at "
                          "any step (third order; second where a source gives no derivatives; the run prints the "
                          "trial steps). Default: the scenario's "
                          "(its emcosim:Coupling annotation; `emcosim info` shows it), else explicit")
    run.add_argument("--interface-type", choices=("CoSimulation", "ModelExchange"), default="CoSimulation",
                     help="CoSimulation (default): the master steps every FMU; ModelExchange: every FMU is "
                          "instantiated for Model Exchange and their states are integrated as one ODE by scipy "
                          "(--solver): one solve at --rtol (default 1e-6), or the solves that keep the global error "
                          "within --tolerance; rows every --step-size")
    run.add_argument("--rtol", type=float, help="the solver's relative tolerance of a ModelExchange run [1], "
                                                "1e-13 or more (absolute: rtol times each state's nominal value)")
    run.add_argument("--solver", choices=("LSODA", "BDF", "Radau"),
                     help="scipy's integrator of a ModelExchange run (default LSODA)")
    run.add_argument("--solver-steps", action="store_true",
                     help="a ModelExchange run records a row at every step of the solver instead of every --step-size")
    run.add_argument("--error-threshold", type=float, default=None, metavar="E",
                     help="a fixed-step co-simulation estimates its coupling error by step doubling on a sample of "
                          "its steps; above E [1] of a recorded variable's range (default 1e-2) the run warns, "
                          "keeps its rows as NAME.partial.csv and exits with status 5 (docs/cli.md)")
    run.add_argument("--no-progress", action="store_true", help="never show the progress bar")
    run.add_argument("--fmu-dir", help="take every FMU from this folder (by file name) instead of the .ssd's paths")
    run.add_argument("--max-steps", type=float, default=None, metavar="N",
                     help="confirm a run of more than 1e8 communication steps (refused otherwise; a ModelExchange "
                          "run: rows of its grid, and steps of each solve)")
    run.set_defaults(func=cmd_run)

    export = sub.add_parser("export", help="export a scenario as a closed-loop container FMU", parents=[ssp])
    export.add_argument("scenario")
    export.add_argument("-o", "--output", required=True, help="the .fmu to write")
    export.add_argument("--step-size", type=float, help="fixed step of the container (default: the scenario's)")
    export.add_argument("--fmu-dir", help="take every FMU from this folder (by file name)")
    export.set_defaults(func=cmd_export)

    pack = sub.add_parser("pack", help="pack a scenario with its FMUs into a self-contained SSP archive (.ssp) "
                          "for other SSP tools", parents=[ssp])
    pack.add_argument("scenario")
    pack.add_argument("-o", "--output", required=True, help="the .ssp to write")
    pack.add_argument("--model-exchange", action="store_true",
                      help="ask OMSimulator for a strongly coupled system: every FMU as Model Exchange under its "
                           "CVODE (default: Co-Simulation at the scenario's fixed step)")
    pack.add_argument("--rtol", type=float, default=1e-6,
                      help="with --model-exchange: CVODE's relative and absolute tolerance in the archive "
                           "(default 1e-6; OMSimulator's --tolerance replaces it)")
    pack.add_argument("--fmu-dir", help="take every FMU from this folder (by file name)")
    pack.set_defaults(func=cmd_pack)

    info = sub.add_parser("info", help="list the scenarios and their FMUs with their variables", parents=[ssp])
    info.add_argument("scenario", nargs="*", help="scenarios to describe (default: all in scenarios/)")
    info.add_argument("--fmu-dir", help="take every FMU from this folder (by file name)")
    info.set_defaults(func=cmd_info)

    rep = sub.add_parser("reproduce", help="build the FMUs if needed, run every paper scenario, write figures and reports")
    rep.add_argument("--out", default="results", help="output folder (default: results)")
    rep.add_argument("--fmu-dir", help="take every FMU from this folder (by file name)")
    rep.add_argument("--stop-time", type=float, help="shorten every scenario to this stop time [s] (a quick look)")
    rep.add_argument("--jobs", "-j", type=int, help="scenarios run at the same time, each in its own process "
                                                    "(default: one per core)")
    rep.set_defaults(func=cmd_reproduce)

    cert = sub.add_parser("certify", help="check the paper's conditions and certify a contraction rate for a scenario's design",
                          parents=[ssp])
    cert.add_argument("scenario")
    cert.add_argument("--radius", type=_radius, default=0.1,
                      help="half-width of the neighbourhood around the reference, relative to each state's scale (default 0.1)")
    cert.add_argument("--include-start", action="store_true", help="widen the neighbourhood to contain the initial state")
    cert.add_argument("--json", help="also write the certificate as JSON to this file")
    cert.set_defaults(func=cmd_certify)

    lin = sub.add_parser("linearize", help="the closed loop's A, B, C, D and poles at its reference (or start) state",
                         parents=[ssp])
    lin.add_argument("scenario")
    lin.add_argument("--t", type=float, default=0.0, help="time [s] of the reference state (default 0)")
    lin.add_argument("--at", default="reference", metavar="reference|start|NAME=VALUE,...",
                     help="the state: on the reference at --t (default), the initial state, or values of states "
                          "(e.g. plant.q=0.002,plant.p=0; the others keep their initial values)")
    lin.add_argument("--inputs", default="", metavar="A.U,...",
                     help="variables a disturbance is added to, for B and D (inputs such as plant.u, or outputs such "
                          "as reference.q_star)")
    lin.add_argument("--outputs", default=None, metavar="A.Y,...",
                     help="states, outputs or inputs observed, for C and D (default: the states)")
    lin.add_argument("--set", action="append", default=[], metavar="COMPONENT.VARIABLE=VALUE",
                     help="override a parameter or start value (repeatable)")
    lin.add_argument("--fmu-dir", help="take every FMU from this folder (by file name)")
    lin.add_argument("--out", help="also write the linearization as JSON to this file")
    lin.set_defaults(func=cmd_linearize)

    sw = sub.add_parser("sweep", help="run a scenario over a parameter grid (and random plant samples) on Dask; "
                                      "table and plots of the metrics", parents=[ssp])
    sw.add_argument("scenario")
    sw.add_argument("--grid", action="append", default=[], metavar="COMPONENT.PARAMETER=START:STOP:N",
                    help="N equally spaced values from START to STOP (or V1,V2,...); repeat for a product grid")
    sw.add_argument("--sample", action="append", default=[], metavar="COMPONENT.PARAMETER=LOW:HIGH",
                    help="uncertain parameter drawn uniformly from [LOW, HIGH] (repeatable; needs --samples)")
    sw.add_argument("--samples", type=int, default=0, help="random draws per grid point (same draws for every point)")
    sw.add_argument("--seed", type=int, default=0, help="seed of the random draws (default 0)")
    sw.add_argument("--max-runs", type=int, default=None, metavar="N",
                    help="run a sweep of up to N runs (default: refused above 100000, emcosim.sweeps.MAX_RUNS)")
    sw.add_argument("--workers", type=int, help="local worker processes (default: one per core)")
    sw.add_argument("--scheduler", metavar="tls://HOST:PORT", help="use this running dask scheduler instead of a local cluster "
                                                                  "(the local cluster uses TLS with temporary credentials)")
    sw.add_argument("--tls-ca-file", help="with --scheduler: CA certificate of the cluster (PEM), as for `dask scheduler`")
    sw.add_argument("--tls-cert", help="with --scheduler: this client's certificate (PEM)")
    sw.add_argument("--tls-key", help="with --scheduler: this client's private key (PEM)")
    sw.add_argument("--out", help="output folder (default: sweep_SCENARIO_NAME)")
    sw.add_argument("--stop-time", type=float, help="stop time [s] of every run (default: the scenario's)")
    sw.add_argument("--step-size", type=float, help="communication step [s] (default: the scenario's, chosen for "
                                                    "its own gains: other gains may need a smaller one, or --tolerance)")
    sw.add_argument("--tolerance", type=float, metavar="TOL",
                    help="error-controlled communication steps in every run, as `run --tolerance` (relative error)")
    sw.add_argument("--coupling", choices=("explicit", "implicit"),
                    help="the coupling of every run, as `run --coupling` (default: the scenario's); implicit "
                         "coupling bears gains that make the loop stiff at the scenario's step")
    sw.add_argument("--coupling-order", type=int, choices=range(0, 4), metavar="K",
                    help="highest derivative handed along a connection in every run, as `run --coupling-order` "
                         "[0..3] (explicit coupling only)")
    sw.add_argument("--interface-type", choices=("CoSimulation", "ModelExchange"), default="CoSimulation",
                    help="as `run --interface-type`: ModelExchange runs every point as one ODE of the FMUs' states")
    sw.add_argument("--rtol", type=float, help="the solver's relative tolerance of ModelExchange runs, as `run --rtol`")
    sw.add_argument("--solver", choices=("LSODA", "BDF", "Radau"), help="scipy's integrator of ModelExchange runs")
    sw.add_argument("--fmu-dir", help="take every FMU from this folder (by file name) instead of the .ssd's paths")
    sw.add_argument("--error-threshold", type=float, default=None, metavar="E",
                    help="as `run --error-threshold`: a fixed-step run whose estimated coupling error exceeds E of a "
                         "recorded variable's range is marked 'not accepted' in the table, left out of the plots, and "
                         "the sweep exits 5 (default 1e-2)")
    sw.add_argument("--no-plots", action="store_true", help="write the table only")
    sw.add_argument("--no-progress", action="store_true", help="no progress lines on stderr")
    sw.set_defaults(func=cmd_sweep)

    from .devices.commands import add_parser as add_plant_parser
    add_plant_parser(sub)                          # emcosim plant check | build | scenario (a description file)
    return p


def _archive_options() -> argparse.ArgumentParser:
    """Options of every command that reads a scenario: the limits of an .ssp archive."""
    p = argparse.ArgumentParser(add_help=False)
    p.add_argument("--ssp-max-size", type=float, default=2048, metavar="MIB",
                   help="refuse an .ssp archive that unpacks to more than this many MiB (default 2048)")
    p.add_argument("--ssp-max-files", type=int, default=10_000, metavar="N",
                   help="refuse an .ssp archive of more than N files (default 10000)")
    p.add_argument("--allow-external", action="store_true",
                   help="let an .ssp archive's .ssd reference files outside the archive (absolute paths, ..)")
    return p


def _limits(args):
    from .engine.archive import ArchiveLimits
    return ArchiveLimits(max_bytes=int(args.ssp_max_size * 2**20), max_files=args.ssp_max_files,
                         allow_external=args.allow_external)


def _version() -> str:
    from importlib.metadata import PackageNotFoundError, version
    try:
        return version("emcosim")
    except PackageNotFoundError:                    # run from a checkout without installing
        return "unknown (not installed)"


def _resolve(name: str, limits=None) -> Path:
    from .api import find_scenario
    return find_scenario(name, limits)


def _read(name: str, fmu_dir: str | None = None, args=None):
    from .api import load_scenario
    return load_scenario(name, fmu_dir, None if args is None else _limits(args))


def run_options(args):
    """The engine's RunOptions of `run` or `sweep`'s flags (checked there: one check for every command and the
    Python API)."""
    from .engine.options import MAX_STEPS, RunOptions

    return RunOptions(stop_time=args.stop_time, step_size=args.step_size, tolerance=args.tolerance,
                      max_step=getattr(args, "max_step", None), coupling=args.coupling,
                      coupling_order=args.coupling_order, max_steps=getattr(args, "max_steps", None) or MAX_STEPS,
                      interface_type=getattr(args, "interface_type", "CoSimulation"),
                      rtol=getattr(args, "rtol", None), solver=getattr(args, "solver", None),
                      solver_steps=getattr(args, "solver_steps", False))


def cmd_run(args) -> int:
    from .api import run
    from .engine.outputs import ResultFile
    from .progress import ProgressBar

    options = run_options(args)                   # every setting checked before anything is read
    threshold = _error_threshold(args.error_threshold)
    scenario = _read(args.scenario, args.fmu_dir, args)
    start_values = _start_values(args.set)
    record = [r.strip() for r in args.record.split(",") if r.strip()] if args.record else None
    output = Path(args.output or f"{scenario.name}.csv")
    if args.plot:
        check_plot(Path(args.plot), output)
    sink = ResultFile(output, what=scenario.name)   # checked before the run
    for note in sink.notes:
        print(f"emcosim: note: {note}", file=sys.stderr)
    bar = None if args.no_progress else ProgressBar(scenario.name)
    result = failure = None
    try:
        with sink:
            result = run(scenario, options, start_values=start_values, record=record, progress=bar, sink=sink,
                         error_threshold=threshold)       # ResultNotAccepted: the library's verdict (exit 5)
    except SimulationError as exc:                 # the rows computed so far are in sink.final
        failure, result = exc, exc.result
    finally:
        if bar is not None:
            bar.close()
    for warning in getattr(result, "warnings", []):
        print(f"emcosim: warning: {warning}", file=sys.stderr)
    if failure is not None:
        _raise_failure(failure, sink, scenario, args.plot, start_values)
    try:
        figure = plot_run(scenario, sink.final, args.plot, start_values) if args.plot else None
    except ScenarioError as exc:
        exc.add_note(f"the run's {sink.rows} rows are in {sink.final}")
        raise
    print(f"{scenario.name}: {sink.rows} rows to {sink.final}" + (f", plot {figure}" if figure else ""))
    if getattr(result, "step_control", None) is not None:
        print(f"{scenario.name}: {result.step_control.summary()}")
    if getattr(result, "implicit", None) is not None:
        print(f"{scenario.name}: {result.implicit.summary()}")
    if getattr(result, "model_exchange", None) is not None:
        print(f"{scenario.name}: {result.model_exchange.summary()}")
    if getattr(result, "coupling_error", None) is not None:
        print(f"{scenario.name}: {result.coupling_error.summary()}")
    return 0


def _error_threshold(value: float | None) -> float:
    """--error-threshold: a finite number > 0 (default doubling.THRESHOLD), checked as the library checks it."""
    from .engine.verdict import check_threshold

    return check_threshold(value)


def _raise_failure(failure: SimulationError, sink, scenario, plot: str | None, start_values: dict) -> None:
    """A failed run: its rows and (with --plot) their figure are kept as partial files; the error
    names them."""
    if sink.final is None:
        raise failure
    failure.add_note(f"{sink.rows} rows up to t = {sink.last_time:.9g} s saved to {sink.final}")
    if plot:
        try:
            failure.add_note(f"plot {plot_run(scenario, sink.final, plot, start_values, partial=True)}")
        except ScenarioError as exc:               # the run's error comes first
            failure.add_note(f"no plot: {error_line(exc)}")
    raise failure


def check_plot(path: Path, results: Path) -> None:
    """--plot: an image format matplotlib writes, a file that can be written, not the results file
    (checked before the run)."""
    fmt = path.suffix[1:].lower()
    if not fmt:
        raise ScenarioError(f"--plot {path}: no image format: give a name ending in .png, .svg or .pdf")
    formats = image_formats()
    if fmt not in formats:
        raise ScenarioError(f"--plot {path}: cannot draw a .{fmt} file (formats: {', '.join(sorted(formats))})")
    if path.absolute() == results.absolute():
        raise ScenarioError(f"--plot {path}: is the results file too; give another name")
    from .engine.outputs import check_destination

    check_destination(path)


def image_formats() -> set[str]:
    """The file suffixes matplotlib can draw to (png, svg, pdf, ...)."""
    from matplotlib.backend_bases import FigureCanvasBase

    return set(FigureCanvasBase.get_supported_filetypes())


def plot_run(scenario, rows: Path, path: str, start_values: dict, partial: bool = False) -> Path:
    """Draw the results file `rows`: the paper's figure of a run for this suite's scenarios
    (emcosim.paper.run_figure), else the engine's figure of the recorded variables in their units.
    Written as results files are (engine.outputs.write_file): in place of `path`, or, for a failed
    run (`partial`), to the first free NAME.partial[-N].SUFFIX, marked on the figure and in the
    file's metadata with the partial file's comment. Returns the file written."""
    import matplotlib.pyplot as plt

    from .api import figure
    from .engine import plotting
    from .engine.outputs import write_file
    from .engine.results import Result, partial_note

    note = (partial_note(rows) or "emcosim: PARTIAL result") if partial else None
    fig = plotting.draw(figure(scenario, Result.from_csv(rows), start_values, mark=note))
    fmt = Path(path).suffix[1:].lower()
    metadata = None
    if note:
        key = {"png": "Description", "svg": "Description", "pdf": "Subject"}.get(fmt)
        metadata = {key: note} if key else None
    try:
        return write_file(Path(path), lambda f: fig.savefig(f, format=fmt, dpi=110, metadata=metadata),
                          partial=partial)
    except (ValueError, OSError) as exc:            # e.g. a full disk
        raise ScenarioError(f"--plot {path}: {getattr(exc, 'strerror', None) or exc}") from None
    finally:
        plt.close(fig)


def cmd_export(args) -> int:
    from .engine.container import export_container
    from .engine.options import RunOptions

    RunOptions(step_size=args.step_size)          # checked as run's
    scenario = _read(args.scenario, args.fmu_dir, args)
    export_container(scenario, Path(args.output), step_size=args.step_size)
    print(f"{scenario.name}: container FMU written to {args.output}")
    return 0


def cmd_pack(args) -> int:
    from .engine import tempdirs
    from .engine.outputs import check_destination, write_file
    from .engine.ssp import model_exchange_solver, pack_ssp

    out = Path(args.output)
    if out.suffix.lower() != ".ssp":
        raise ScenarioError(f"{out}: an SSP archive is named NAME.ssp")
    check_destination(out)                        # before the FMUs are read and zipped
    scenario = _read(args.scenario, args.fmu_dir, args)
    if not 0 < args.rtol < 1:
        raise ScenarioError(f"--rtol {args.rtol:g}: must be a number between 0 and 1 (a relative error)")
    if args.model_exchange:
        try:
            model_exchange_solver(scenario, args.rtol)   # the step sizes checked before anything is packed
        except ValueError as exc:
            raise ScenarioError(str(exc)) from None
    work = tempdirs.make("pack")
    try:
        packed = pack_ssp(scenario, work / out.name, model_exchange=args.model_exchange, relative_tolerance=args.rtol)
        with open(packed, "rb") as f:
            data = f.read()
        write_file(out, lambda f: f.write(data))
    finally:
        shutil.rmtree(work, ignore_errors=True)
    kind = "Model Exchange under OMSimulator's CVODE" if args.model_exchange else "Co-Simulation"
    print(f"{scenario.name}: SSP archive ({kind}) written to {out}")
    return 0


def cmd_info(args) -> int:
    from fmpy import read_model_description

    from .engine.ssd import SSD_NAME

    if args.scenario:
        paths = args.scenario
    else:
        from .api import scenario_dirs

        paths = sorted(str(d) for base in scenario_dirs() for d in base.iterdir() if (d / SSD_NAME).is_file())
        if not paths:
            raise ScenarioError("no scenarios found (looked in ./scenarios and the project's scenarios/)")
    scenarios = [_read(path, args.fmu_dir, args) for path in paths]        # every error before any output
    fmus = {}
    print("Scenarios:")
    for s in scenarios:
        h = f"{s.step_size:g} s" if s.step_size else "?"
        stop = f"{s.stop_time:g} s" if s.stop_time is not None else "?"
        coupling = f", {s.coupling} coupling" if s.coupling else ""
        print(f"  {s.name}: stop time {stop}, step {h}{coupling}")
        if s.description:
            print(f"      {s.description}")
        for c in s.components:
            print(f"      {c.name}: {c.source.name}" + (f" ({c.description})" if c.description else ""))
            fmus.setdefault(c.source, c.name)
    if args.scenario and all(source.is_file() for source in fmus):
        for s in scenarios:
            _print_settings(s)
        return 0
    print("FMUs:" + ("" if args.scenario else " (their defaults; `emcosim info SCENARIO` shows what a scenario sets)"))
    for source in fmus:
        if not source.is_file():
            print(f"  {source}: not built (`emcosim build` builds the paper's FMUs)")
            continue
        md = read_model_description(str(source), validate=False)
        print(f"  {source.name}: {md.modelName}, FMI {md.fmiVersion}" + (f" - {md.description}" if md.description else ""))
        for v in md.modelVariables:
            unit = f" [{v.unit or (v.declaredType.unit if v.declaredType else '')}]" if (v.unit or v.declaredType) else ""
            start = f" = {v.start}" if v.start is not None else ""
            desc = f"  {v.description}" if v.description else ""
            print(f"      {v.causality:<10} {v.type:<8} {v.name}{unit}{start}{desc}")
    return 0


def _print_settings(scenario) -> None:
    """`info SCENARIO`: what the scenario sets, each value beside its FMU's default, '*' where they differ; then
    each component's other variables."""
    from fmpy import read_model_description

    from .api import settings

    experiment, components = settings(scenario)
    print(f"{scenario.name}: the values it sets ('*': differs from the FMU's default)")
    for s in experiment:
        print("  " + _setting_line(s, s.name))
    for comp in scenario.components:
        md = read_model_description(str(comp.source), validate=False)
        print(f"  {comp.name} ({comp.source.name}: {md.modelName}, FMI {md.fmiVersion}):")
        described = {v.name: v for v in md.modelVariables}
        for s in components[comp.name]:
            var = described[s.name.partition(".")[2]]
            desc = f"  {var.description}" if var.description else ""
            print(f"    {var.causality:<10} {var.type:<8} " + _setting_line(s, var.name) + desc)
        shown = {s.name.partition(".")[2] for s in components[comp.name]}
        for v in md.modelVariables:
            if v.name not in shown:
                unit = f" [{v.unit or (v.declaredType.unit if v.declaredType else '')}]" if (v.unit or v.declaredType) else ""
                desc = f"  {v.description}" if v.description else ""
                connected = " (connected)" if v.causality == "input" else ""
                print(f"    {v.causality:<10} {v.type:<8} {v.name}{unit}{connected}{desc}")


def _setting_line(s, name: str) -> str:
    """`* name [unit] = value (FMU default: d)`, the mark and the default only where they differ."""
    unit = f" [{s.unit}]" if s.unit else ""
    value = "not set" if s.value is None else str(s.value)
    if not s.differs:
        return f"  {name}{unit} = {value}"
    default = "none" if s.default is None else str(s.default)
    return f"* {name}{unit} = {value}  (FMU default: {default})"


def cmd_reproduce(args) -> int:
    from .paper.reproduce import ensure_fmus, reproduce

    if args.fmu_dir is None:
        ensure_fmus()                              # into emcosim.paper_fmu_dir(), where the scenarios look
    reproduce(args.out, stop_time=args.stop_time, fmu_dir=args.fmu_dir, jobs=args.jobs)
    return 0


def _radius(text: str) -> float:
    """--radius: a finite number > 0 (argparse reports the error and exits with status 2)."""
    from components.certificates import check_radius

    try:
        return check_radius(text)
    except ValueError as exc:
        raise argparse.ArgumentTypeError(str(exc)) from None


def cmd_certify(args) -> int:
    from .api import certify
    from .engine.outputs import check_destination, write_file
    from .paper.certify import exit_status

    if args.json:
        check_destination(Path(args.json))        # before the certificate is computed: no link, a writable place
    path = _resolve(args.scenario, _limits(args))
    try:
        cert = certify(path, radius=args.radius, include_start=args.include_start)
    except ValueError as exc:                       # an invalid design: a parameter the paper's conditions refuse
        raise ScenarioError(f"{path}: {exc}") from None
    print(cert.report())
    if args.json:
        data = cert.to_json().encode("utf-8")
        write_file(Path(args.json), lambda f: f.write(data))   # beside, then renamed: never through a link
        print(f"certificate written to {args.json}")
    status, why = exit_status(cert)
    if status:
        print(f"emcosim: {why} (exit status {status}, docs/cli.md)", file=sys.stderr)
    return status


def _start_values(items: list[str]) -> dict[str, str]:
    """--set COMPONENT.VARIABLE=VALUE (repeatable) as start values."""
    start_values = {}
    for item in items:
        name, sep, value = item.partition("=")
        if not sep or "." not in name:
            raise ScenarioError(f"--set {item}: expected COMPONENT.VARIABLE=VALUE")
        start_values[name.strip()] = value.strip()
    return start_values


def _names(text: str | None) -> list[str] | None:
    return None if text is None else [n.strip() for n in text.split(",") if n.strip()]


def _at(text: str):
    """--at: 'reference', 'start' or NAME=VALUE,... (a mapping of state values)."""
    if text in ("reference", "start"):
        return text
    state = {}
    for item in text.split(","):
        name, sep, value = item.partition("=")
        try:
            state[name.strip()] = float(value)
        except ValueError:
            raise ScenarioError(f"--at {text!r}: expected reference, start or NAME=VALUE,... ({item!r} is not "
                                "NAME=VALUE with a number)") from None
        if not sep or not name.strip():
            raise ScenarioError(f"--at {text!r}: {item!r} is not NAME=VALUE")
    return state


def cmd_linearize(args) -> int:
    from .api import linearization
    from .engine.outputs import check_destination, write_file

    if args.out:
        check_destination(Path(args.out))          # before the FMUs are loaded: no link, a writable place
    scenario = _read(args.scenario, args.fmu_dir, args)
    lin = linearization(scenario, t=args.t, at=_at(args.at), inputs=_names(args.inputs) or [],
                        outputs=_names(args.outputs), start_values=_start_values(args.set))
    print(lin.report(scenario.name))
    if args.out:
        data = lin.to_json().encode("utf-8")
        write_file(Path(args.out), lambda f: f.write(data))
        print(f"linearization written to {args.out}")
    return 0


def cmd_sweep(args) -> int:
    from .engine.output_folder import OutputFolder
    from .engine.outputs import reason_of
    from .paper.sweep import MAX_RUNS, RowStream, parse_grid, parse_sample, points, security, sweep
    from .paper.sweep_output import plot, write_table

    max_runs = MAX_RUNS if args.max_runs is None else args.max_runs
    if max_runs < 1:
        raise ScenarioError(f"--max-runs {max_runs}: must be >= 1")
    grid = [parse_grid(g, max_runs) for g in args.grid]
    samples = [parse_sample(s) for s in args.sample]
    points(grid, samples, args.samples, args.seed, max_runs)       # its size, before anything is read
    options = run_options(args)                   # checked as run's
    threshold = _error_threshold(args.error_threshold)
    if args.workers is not None and args.workers < 1:
        raise ScenarioError(f"--workers {args.workers}: must be >= 1")
    scenario = _read(args.scenario, args.fmu_dir, args)
    tls = security(args.tls_ca_file, args.tls_cert, args.tls_key)
    out = Path(args.out or f"sweep_{scenario.name}")
    folder = OutputFolder(out)                    # checked before the sweep starts
    for note in folder.notes:
        print(f"emcosim: note: {note}", file=sys.stderr)
    stream = RowStream(folder.path / "sweep.csv", [n for n, _ in grid] + [n for n, _, _ in samples])
    try:
        try:
            rows, info = sweep(scenario, grid, samples, args.samples, args.seed, options, workers=args.workers,
                               scheduler=args.scheduler, stream=None if args.no_progress else sys.stderr,
                               security=tls, on_row=stream, max_runs=max_runs, threshold=threshold)
        finally:
            stream.close()
        files = write_table(rows, folder.path, info)
        if not args.no_plots:
            if not args.no_progress:
                print("sweep: drawing the plots ...", file=sys.stderr, flush=True)
            horizon = args.stop_time if args.stop_time is not None else scenario.stop_time
            files += plot(rows, dict(grid), info["units"], folder.path, title=f"{scenario.name}, horizon {horizon:g} s",
                          horizon=horizon)
    except BaseException as exc:
        if stream.rows == 0:
            folder.discard()
            raise
        kept = folder.abandon(reason_of(exc))
        note = f"{stream.rows} finished runs kept in {kept / 'sweep.csv'} ({out} was left as it was)"
        if isinstance(exc, ScenarioError):
            exc.add_note(note)
        else:
            print(f"emcosim: {note}", file=sys.stderr)
        raise
    folder.commit()
    workers = f"{info['workers']} worker{'s' if info['workers'] != 1 else ''}"
    rejected = f", {info['not_accepted']} not accepted" if info["not_accepted"] else ""
    print(f"{scenario.name}: {info['runs']} runs ({info['failed']} failed{rejected}) on {workers}, "
          f"{info['runs_per_s']:.3g} runs/s; {len(files)} files in {out}")
    if info["failed"] and args.step_size is None and args.tolerance is None:
        step = f" ({scenario.step_size:g} s)" if scenario.step_size else ""
        stiff = ", or --coupling implicit if the gains make the loop stiff" if info["coupling"] != "implicit" else ""
        print(f"emcosim: note: the runs used the scenario's step{step}, chosen for its own gains; "
              f"failed runs may need --step-size or --tolerance{stiff} (the status column says why each failed)",
              file=sys.stderr)
    if info["not_accepted"]:
        print(f"emcosim: warning: {info['not_accepted']} of {info['runs']} runs estimate a coupling error above "
              f"the accepted {threshold:g} of a recorded variable's range (--error-threshold): their rows say "
              f"'not accepted' and the plots leave them out; a shorter --step-size, --coupling implicit or "
              f"--tolerance keeps it (exit status {NOT_ACCEPTED}, docs/cli.md)", file=sys.stderr)
        return NOT_ACCEPTED
    return 0


def entry() -> None:
    """The `emcosim` command (and `python -m emcosim.cli`): `main`, then the process ends with its
    status once Python's own exit handlers have run and the output is flushed, without the native
    libraries' teardown (os._exit after atexit).

    Works around: pythonfmu 0.7.0's export library frees its interpreter state in the process's exit
    handlers in an order that writes into a freed block (docs/reliability.md, finding 1). Our FMUs'
    loader avoids it; a third-party FMU built with stock pythonfmu (the reliability suite's
    ReliabilityFaulty) does not, and glibc then aborts the process at exit ("corrupted double-linked
    list", status 134) after every result and message is written. Measured on 2026-12-01 with
    `python -m emcosim.cli run` on that FMU's loop, the machine loaded by two busy processes: 2-4
    aborts in 40-80 runs where the FMU returns NaN (both reliability tests of it failed in one CI
    run); our own plant FMU failing instead 0 of 50; the loop without the fault 0 of 60; with this
    exit 0 of 100 (NaN) and 0 of 60 (an exception in doStep).
    tests/reliability/test_failing_components.py runs the command in a subprocess and checks the
    status."""
    import atexit
    import os

    status = main()
    status = 0 if status is None else int(status)  # as sys.exit takes it
    atexit._run_exitfuncs()                        # Python's handlers (multiprocessing, logging, ...)
    for stream in (sys.stdout, sys.stderr):
        try:
            stream.flush()
        except (OSError, ValueError):              # a closed pipe: nothing left to say
            pass
    os._exit(status)


if __name__ == "__main__":
    entry()
