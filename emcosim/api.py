"""emcosim's Python API: the few functions a notebook or a script calls (re-exported by `emcosim`).

    >>> import emcosim
    >>> scenario = emcosim.load_scenario("maglev_regulation_prop2")
    >>> result = emcosim.run(scenario, emcosim.RunOptions(stop_time=1.0))
    >>> q = result.to_pandas()["plant.q"]                   # [m]: from q(0) = 1.5 mm toward q_d = 2.5 mm
    >>> float(q.iloc[0]), bool(q.iloc[-1] > 0.0025)
    (0.0015, True)

Plain functions in the style of FMPy and python-control: a scenario by name or path (`load_scenario`), a run
with one options object (`run`, `RunOptions`), its rows as arrays (`result["plant.q"]`) or as a pandas
DataFrame with the units in `df.attrs["units"]` (`result.to_pandas()`); from a plant description file its
check (`check_plant`), its FMUs, only the designs that apply (`build_plant`), a closed-loop scenario
(`write_scenario`); a run's figure (`figure`); the paper's conditions and a certified contraction rate
(`certify`); a parameter sweep (`sweep`, on emcosim.sweeps). The command line (`emcosim ...`) is a thin layer
over these: it parses flags, calls them and prints, so the two give the same results and record the same
variables.

Where things are found: a bare scenario name is looked up in ./scenarios, then among the paper's scenarios
(package data of the installed wheel, or the checkout's scenarios/); the paper's scenarios take their FMUs
from `paper_fmu_dir()` (the working folder's build/fmus when installed, the checkout's build/fmus in a
checkout; `emcosim reproduce` builds them there) unless an `fmu_dir` is given.

Every example below runs as a doctest (tests/test_api.py), the paper's FMUs built; those marked +SKIP take
longer (an FMU build, a Dask cluster) and are run by the tests of `emcosim plant build` and `sweep`.
"""
from __future__ import annotations

import difflib
from pathlib import Path
from typing import Callable, Iterable, Mapping, Sequence

from .engine.errors import ResultNotAccepted, ScenarioError, SimulationError
from .engine.options import RunOptions
from .engine.plan import default_record
from .engine.results import Result
from .engine.ssd import SSD_NAME, Scenario
from .engine.verdict import ResultNotAcceptedWarning

__all__ = ["ResultNotAccepted", "ResultNotAcceptedWarning",
           "RunOptions", "Result", "Scenario", "scenario_dirs", "scenario_names", "find_scenario", "load_scenario",
           "default_record", "settings", "run", "figure", "paper_fmu_dir", "check_plant", "build_plant", "write_scenario",
           "write_folder", "certify", "sweep", "units_of", "linearize", "linearize_fmu", "linearization", "statespace"]


# ---- scenarios -----------------------------------------------------------------------------------

def scenario_dirs() -> list[Path]:
    """Where bare scenario names are looked up: ./scenarios, then the paper's scenarios (the installed
    package's data, or the checkout's scenarios/).

    >>> any(d.name == "scenarios" for d in scenario_dirs())
    True
    """
    from .locations import SCENARIOS

    dirs = [Path.cwd() / "scenarios", SCENARIOS]
    return [d for d in dict.fromkeys(dirs) if d.is_dir()]


def scenario_names() -> list[str]:
    """The bare scenario names found in `scenario_dirs()`, sorted.

    >>> "maglev_regulation_prop2" in scenario_names()
    True
    """
    return sorted({d.name for base in scenario_dirs() for d in base.iterdir() if (d / SSD_NAME).is_file()})


def find_scenario(name: str | Path, limits=None) -> Path:
    """The .ssd file of a scenario given by name (see `scenario_dirs`), folder, .ssd file or .ssp archive
    (unpacked within `limits`, an engine.archive.ArchiveLimits). A bare name that matches no scenario gets the
    closest names suggested.

    >>> find_scenario("mems_regulation_Dd0").name
    'SystemStructure.ssd'
    >>> find_scenario("mems_regulation_Dd")
    Traceback (most recent call last):
    ...
    emcosim.engine.errors.ScenarioError: mems_regulation_Dd: no such scenario; did you mean ...
    """
    from .engine.ssd import resolve_path

    try:
        return resolve_path(name, scenario_dirs(), limits)
    except ScenarioError:
        if len(Path(name).parts) == 1 and not Path(name).exists():
            close = difflib.get_close_matches(str(name), scenario_names(), n=3, cutoff=0.6)
            if close:
                raise ScenarioError(f"{name}: no such scenario; did you mean {' or '.join(close)}? "
                                    "(`emcosim info` lists them)") from None
        raise


def paper_fmu_dir() -> Path:
    """The folder the paper's scenarios take their FMUs from (and `emcosim reproduce` builds them into):
    build/fmus of the checkout, or of the working folder for an installed wheel.

    >>> paper_fmu_dir().parts[-2:]
    ('build', 'fmus')
    """
    from .locations import fmu_dir

    return fmu_dir()


def load_scenario(name: str | Path, fmu_dir: str | Path | None = None, limits=None) -> Scenario:
    """A scenario (SSP: SystemStructure.ssd and its .ssv files) by name or path, see `find_scenario`. With
    `fmu_dir`, every FMU is taken from that folder by file name; the paper's scenarios default to
    `paper_fmu_dir()`.

    >>> s = load_scenario("maglev_regulation_prop2")
    >>> [c.name for c in s.components], s.stop_time
    (['controller', 'plant'], 20.0)
    """
    from .engine.ssd import read_scenario
    from .locations import fmus_of

    ssd = find_scenario(name, limits)
    return read_scenario(ssd, fmu_dir=fmus_of(ssd, fmu_dir), limits=limits)


def settings(scenario: Scenario | str | Path):
    """What a scenario sets, each value beside the default it replaces: (the experiment's start, stop time, step
    size and coupling beside the FMUs' DefaultExperiment; per component, every parameter and unconnected input
    with the scenario's value beside the FMU's start value), as `emcosim.engine.binding.Setting`s (`differs`).
    Needs the scenario's FMUs (their modelDescriptions hold the defaults).

    >>> experiment, components = settings("maglev_tracking_D-1_R0.82")
    >>> [(s.name, s.value, s.default, s.differs) for s in components["plant"] if s.name == "plant.q_0"]
    [('plant.q_0', 0.0015, 0.0025, True)]
    """
    from .engine import binding

    s = _scenario(scenario)
    return binding.settings(s, binding.load(s))


def _scenario(scenario: Scenario | str | Path) -> Scenario:
    return scenario if isinstance(scenario, Scenario) else load_scenario(scenario)


# ---- running -------------------------------------------------------------------------------------

def run(scenario: Scenario | str | Path, options: RunOptions | None = None, *,
        start_values: Mapping[str, str | float] | None = None, record: Sequence[str] | None = None,
        progress: Callable[[float], None] | None = None, sink=None, error_threshold: float | None = None,
        accept: str = "raise") -> Result:
    """Run a scenario (a Scenario, or its name or path) once with `options` (RunOptions: stop time, step,
    tolerance, coupling, interface type, solver ...; None: the scenario's own). `start_values` override
    parameters ("component.variable" -> value); `record` names the variables to record (default:
    `default_record`, each connected value once); `sink` an engine.outputs.ResultFile to stream the rows to.
    The result's rows: `result.time`, `result["plant.q"]` (numpy arrays), `result.to_pandas()` (a DataFrame
    indexed by time, the units in `df.attrs["units"]`).

    The result is judged as the command line judges it (engine/verdict.py, `result.verdict`): not accepted
    when a fixed-step run's estimated coupling error exceeds `error_threshold` of a recorded variable's range
    (default 1e-2, the command line's --error-threshold), a value is not finite or the horizon is not
    reached. Then `run` raises `ResultNotAccepted`, whose `.result` holds the rows (the command line exits 5);
    `accept="warn"` returns the result anyway, marked (`result.accepted` is False, the reason in
    `result.warnings`), with a `ResultNotAcceptedWarning`.

    >>> r = run("maglev_regulation_prop2", RunOptions(stop_time=0.01))
    >>> r.columns
    ['controller.u', 'plant.q', 'plant.p', 'plant.x_e', 'plant.H']
    >>> r.to_pandas().attrs["units"]["plant.q"]
    'm'
    """
    import warnings
    from dataclasses import asdict

    from .engine import verdict
    from .engine.errors import ResultNotAccepted
    from .engine.master import simulate
    from .engine.options import experiment

    options = RunOptions() if options is None else options
    threshold = verdict.check_threshold(error_threshold)          # checked before anything is read
    verdict.check_accept(accept)
    scenario = _scenario(scenario)
    horizon = experiment(scenario, options).stop_time
    record = None if record is None else list(record)             # None: the engine's default_record
    try:
        result = simulate(scenario, start_values=dict(start_values or {}), record=record, progress=progress,
                          sink=sink, **asdict(options))
    except SimulationError as exc:                                # the rows so far: their sidecar says what ran
        if exc.result is not None:
            try:
                exc.result.units = units_of(scenario, exc.result.columns)
            except ScenarioError:                                 # the run's own error comes first
                pass
            _describe(sink, scenario, options, start_values, record, exc.result)
        raise
    result.units = units_of(scenario, result.columns)
    result.verdict = verdict.judge(result, threshold, horizon)
    _describe(sink, scenario, options, start_values, record, result)
    if not result.verdict.accepted:
        if accept == "raise":
            raise ResultNotAccepted(result.verdict, result)
        result.warnings.append(result.verdict.summary())
        warnings.warn(ResultNotAcceptedWarning(f"{scenario.name}: {result.verdict.describe()}"), stacklevel=2)
    return result


def _describe(sink, scenario: Scenario, options: RunOptions, start_values, record, result: Result) -> None:
    """What the results file's sidecar says beside the rows (engine.outputs.sidecar): the scenario, the options,
    the start values set, the versions, and what the result says (Result.metadata)."""
    if sink is None:
        return
    from dataclasses import asdict

    sink.meta.update(scenario={"name": scenario.name, "path": str(scenario.path)}, options=asdict(options),
                     start_values={k: str(v) for k, v in (start_values or {}).items()}, record=record,
                     versions=versions(), **result.metadata())


def versions() -> dict[str, str]:
    """The versions of emcosim, Python and the libraries a run's numbers depend on."""
    import platform
    from importlib.metadata import PackageNotFoundError, version

    out = {"python": platform.python_version()}
    for name in ("emcosim", "fmpy", "numpy", "scipy"):
        try:
            out[name] = version(name)
        except PackageNotFoundError:
            out[name] = "unknown"
    return out


def units_of(scenario: Scenario, names: Iterable[str]) -> dict[str, str]:
    """The unit of each variable `names` (full names), from its FMU's modelDescription ('' if it has none);
    time in 's'."""
    from .engine.plotting import variable_info

    info = variable_info(scenario)
    units = {"time": "s"}
    units.update({n: info[n].unit if n in info else "" for n in names})
    return units


def figure(scenario: Scenario, result: Result, start_values: Mapping[str, str | float] | None = None,
           mark: str | None = None):
    """The figure of a run (an engine.plotting.FigureSpec; engine.plotting.draw makes it a matplotlib figure):
    for a scenario of this suite's plant and controller FMUs (the paper's, or a device's built by `build_plant`)
    q against q*, the error, u, x_e and H in physical units (emcosim.paper.run_figure); for any other scenario
    one panel per recorded variable in its unit, without importing the paper's layer or touching the device
    catalog. A result that is not accepted (`result.verdict`, see `run`) or partial is marked: a red line under
    the axes says why (`spec.mark`; `mark` gives the text instead).

    >>> r = run("maglev_regulation_prop2", RunOptions(stop_time=0.1))
    >>> [p.ylabel.split(" [")[0] for p in figure(load_scenario("maglev_regulation_prop2"), r).panels][:3]
    ['position q', 'error q - q*', 'input u']
    """
    from .engine import plotting

    spec = None
    if _of_this_suite(scenario):
        from .paper.run_figure import run_figure

        spec = run_figure(scenario, result, dict(start_values or {}))
    spec = spec or plotting.variables_figure(result, plotting.variable_info(scenario), title=scenario.name)
    spec.mark = mark or _mark_of(result)
    return spec


def _mark_of(result: Result) -> str:
    """Why a result is not to be taken as it is ('' if it is accepted or was not judged)."""
    verdict = getattr(result, "verdict", None)
    return f"NOT ACCEPTED: {verdict.describe()}" if verdict is not None and not verdict.accepted else ""


def _of_this_suite(scenario: Scenario) -> bool:
    """Whether a scenario runs FMUs of this suite: a plant of components.catalog (the paper's), or an FMU that
    carries its plant description (built by `build_plant`)."""
    import zipfile

    from components import catalog
    from fmus.build import DESCRIPTION_RESOURCE

    for component in scenario.components:
        if Path(component.source).stem in catalog.PLANTS:
            return True
        try:
            with zipfile.ZipFile(component.source) as z:
                if DESCRIPTION_RESOURCE in z.namelist():
                    return True
        except (OSError, zipfile.BadZipFile):
            continue
    return False


# ---- devices from their description file ---------------------------------------------------------

def check_plant(description: str | Path, q_d: Sequence[float] | None = None, reference=None,
                horizon: float | None = None):
    """Which of the paper's Assumptions 1-4 hold for a plant description file (TOML) and which designs apply
    (components.plant_check.Report: `.text()`, `.designs`, `.to_json()`).

    >>> report = check_plant(EXAMPLES / "solenoid" / "solenoid.toml")
    >>> sorted(report.designs)
    ['Proposition1', 'Theorem2']
    """
    from .devices import registry

    _, report, _ = registry.load(description, q_d=q_d, reference=reference, horizon=horizon)
    return report


def build_plant(description: str | Path, out: str | Path, progress: Callable[[str], None] | None = None,
                operating_point: str | None = None) -> dict[str, Path]:
    """Build the FMUs of a plant description file into `out`: the plant FMU, one controller FMU per design
    that applies (those whose Assumptions hold: `check_plant`) and the Reference FMU. `progress` is called with
    a line as each step starts and ends ("not built  <design>: why", "built  <path>"). Every FMU carries the
    description, by which `certify` knows the device. `operating_point` chooses how the free electrical
    coordinates are fixed when n_e > n_m (the command line's --operating-point; default: the file's).
    Returns model identifier -> FMU path.

    >>> paths = build_plant(EXAMPLES / "solenoid" / "solenoid.toml", tmp / "fmus")   # doctest: +SKIP
    >>> sorted(paths)                                                                # doctest: +SKIP
    ['Reference', 'Solenoid', 'Solenoid_Proposition1', 'Solenoid_Theorem2']
    """
    from .devices.build import build_fmus_of, description_file

    with description_file(description, operating_point) as file:
        return build_fmus_of(file, Path(out), progress=progress)


def write_scenario(description: str | Path, out: str | Path, controller: str, stop_time: float, step_size: float, *,
                   fmu_dir: str | Path | None = None, q_d: Sequence[float] | None = None, references: Sequence = (),
                   q0: Sequence[float] | None = None, p0: Sequence[float] | None = None,
                   x_e0: Sequence[float] | None = None, gains: Mapping[str, float] | None = None,
                   name: str | None = None, operating_point: str | None = None) -> Path:
    """Write an SSP scenario folder `out`: the plant of a description file in closed loop with its controller
    `controller` (a design: Proposition1, Proposition2, Theorem2, Theorem3), its FMUs in `fmu_dir` (default
    build/<name> of the working folder), named in the .ssd relative to `out`. `q_d` set-points (regulation),
    `references` one dict per position (tracking, as devices.scenario.parse_reference gives), `q0` initial
    positions (default q_d or q*(0)), `p0` momenta (default rest), `x_e0` electrical states (default the
    equilibrium's at q0), `gains` the controller's gains, `operating_point` the rule for n_e > n_m (default:
    the file's). Returns the .ssd written.

    >>> ssd = write_scenario(EXAMPLES / "solenoid" / "solenoid.toml", tmp / "sc", "Proposition1",
    ...                      stop_time=0.1, step_size=1e-4, q0=[0.0007])
    >>> sorted(p.name for p in ssd.parent.iterdir())          # .emcosim: the list of what emcosim wrote
    ['.emcosim', 'SystemStructure.ssd', 'controller.ssv', 'plant.ssv']
    """
    from .devices.build import description_file, scenario_of

    with description_file(description, operating_point) as file:
        scenario_of(file, out, controller, stop_time, step_size, fmu_dir=fmu_dir, q_d=q_d, references=references,
                    q0=q0, p0=p0, x_e0=x_e0, gains=gains, name=name)
    return Path(out) / SSD_NAME


def write_folder(out: str | Path, files: Mapping[str, str]) -> None:
    """Write a scenario's files (name -> text) into the folder `out`; see devices.build.write_folder."""
    from .devices.build import write_folder as write

    write(Path(out), files)


# ---- the paper's analyses on any scenario ---------------------------------------------------------

def certify(scenario: str | Path, radius: float = 0.1, include_start: bool = False, limits=None):
    """The paper's conditions and a certified contraction rate of a scenario's design over a tube of relative
    half-width `radius` around its reference (components.certificates.Certificate: `.report()`, `.to_json()`);
    `limits` those of an .ssp archive (see `find_scenario`). ValueError for a design the paper's conditions refuse.

    >>> print(certify("mems_regulation_Dd-1").report())                    # doctest: +ELLIPSIS
    Certificate for MEMS_Theorem2 (Theorem 2) in scenario mems_regulation_Dd-1
    ...
    """
    from .paper.certify import certify_scenario

    return certify_scenario(find_scenario(scenario, limits), radius=radius, include_start=include_start)


def sweep(scenario: Scenario | str | Path, grid: Sequence[tuple[str, Sequence[float]]], options: RunOptions | None = None,
          metrics=None, **settings):
    """Run a scenario over a product grid of parameter values on Dask (emcosim.sweeps: a local cluster of worker
    processes, or `scheduler=`), returning (rows, info): one dict per run with the values, its metrics and
    'status'. `options` apply to every run (RunOptions: stop time, step, tolerance, coupling, or
    interface_type="ModelExchange"). `metrics(scenario, values, result)` gives a row's numbers: by default the
    paper's report metrics for this suite's FMUs (settling time, overshoot, ISE, ...), else the last value of
    every recorded variable (emcosim.sweeps.final_values). `settings` are the sweep's own (samples, n_samples,
    seed, workers, scheduler, stream, security, on_row, max_runs, threshold: see emcosim.sweeps.sweep). A row's
    'coupling_error' is the run's estimated coupling error; above `threshold` (default 1e-2) its status reads
    "not accepted: ..." (info["not_accepted"] counts them).

    >>> rows, info = sweep("maglev_tracking_D0_R0.82", [("controller.D_d", [-0.78, 0.0])],
    ...                    RunOptions(stop_time=1.0), workers=1, stream=None)        # doctest: +SKIP
    >>> [r["status"] for r in rows]                                                 # doctest: +SKIP
    ['ok', 'ok']
    """
    from . import sweeps

    scenario = _scenario(scenario)
    if metrics is None and _of_this_suite(scenario):
        from .paper.sweep import metrics_of as metrics
    points = [(n, [float(v) for v in values]) for n, values in grid]
    return sweeps.sweep(scenario, points, options=options, metrics=metrics, **settings)


# ---- linearization for python-control (issue 41) ---------------------------------------------------

def linearization(scenario: Scenario | str | Path, t: float = 0.0, at="reference", inputs: Sequence[str] = (),
                  outputs: Sequence[str] | None = None, start_values: Mapping[str, str | float] | None = None):
    """The closed loop's linearization x' = A x + B w, z = C x + D w at time t [s] (engine.linearization:
    A, B, C, D, the state and time it was taken at, the names and units), from the FMUs' directional
    derivatives. `at`: "reference" (the state where the loop sits on its reference at t: eta*(t), or eta_d for
    regulation; paper.linearization.reference_state), "start" (the scenario's initial state) or a mapping
    {"plant.q": value, ...} (states not named keep their initial values). `inputs`: variables a disturbance w
    is added to (an input such as "plant.u", or an output such as the reference's "reference.q_star");
    `outputs`: states, outputs or inputs to observe (default: the states).

    >>> lin = linearization("maglev_regulation_prop2")
    >>> lin.states, [round(float(v), 6) for v in lin.x]
    (['plant.q', 'plant.p', 'plant.x_e'], [0.0025, 0.0, 1.029823])
    """
    from .engine.errors import ScenarioError
    from .engine.linearization import linearize as engine_linearize

    scenario = _scenario(scenario)
    if isinstance(at, str):
        if at == "reference":
            from .paper.linearization import reference_state

            state = reference_state(scenario, t)
        elif at == "start":
            state = None
        else:
            raise ScenarioError(f"at = {at!r}: expected 'reference', 'start' or a mapping of state values")
    else:
        state = {str(k): float(v) for k, v in dict(at).items()}
    return engine_linearize(scenario, t, state, list(inputs), None if outputs is None else list(outputs), start_values)


def signal_name(name: str) -> str:
    """A variable's name as a python-control signal name: '.' (reserved there for "system.signal") becomes '_'
    ("plant.u" -> "plant_u"); state names keep theirs ("plant.q").

    >>> signal_name("reference.q_star")
    'reference_q_star'
    """
    return name.replace(".", "_")


def statespace(lin, name: str = ""):
    """A linearization (`linearization`, `linearize_fmu`'s) as a control.StateSpace, its states, inputs and
    outputs named (`signal_name`).

    >>> sys = statespace(linearization("maglev_regulation_prop2", inputs=["plant.u"]))
    >>> sys.nstates, sys.input_labels
    (3, ['plant_u'])
    """
    import control as ct

    labels = {}
    for kind, names in (("input", lin.inputs), ("output", lin.outputs)):
        labels[kind] = [signal_name(n) for n in names]
        if len(set(labels[kind])) != len(names):
            raise ValueError(f"{kind} names {names} are not distinct as python-control signal names {labels[kind]}")
    return ct.ss(lin.A, lin.B, lin.C, lin.D, states=list(lin.states), inputs=labels["input"],
                 outputs=labels["output"], name=signal_name(name) or None)


def linearize(scenario: Scenario | str | Path, t: float = 0.0, at="reference", inputs: Sequence[str] = (),
              outputs: Sequence[str] | None = None, start_values: Mapping[str, str | float] | None = None):
    """The closed loop as a control.StateSpace at time t and state `at` (arguments: `linearization`): poles,
    Bode plots, margins with python-control.

    >>> import control as ct
    >>> sys = linearize("maglev_tracking_D-1_R0.82", inputs=["plant.u"], outputs=["plant.q"])
    >>> sys.state_labels, sys.input_labels, sys.output_labels
    (['plant.q', 'plant.p', 'plant.x_e'], ['plant_u'], ['plant_q'])
    >>> bool(all(sys.poles().real < 0))                  # on the reference the loop is exponentially stable
    True
    """
    scenario = _scenario(scenario)
    return statespace(linearization(scenario, t, at, inputs, outputs, start_values), scenario.name)


def linearize_fmu(path: str | Path, at: Mapping[str, float] | None = None, inputs: Sequence[str] | None = None,
                  outputs: Sequence[str] | None = None, t: float = 0.0,
                  parameters: Mapping[str, str | float] | None = None):
    """One FMU (a plant) alone at an operating point as a control.StateSpace: `at` gives state and input values
    by variable name ({"q": ..., "u": ...}; the rest keep their start values), `parameters` override parameters;
    `inputs` default to every Real input, `outputs` to every Real output.

    >>> sys = linearize_fmu(paper_fmu_dir() / "Maglev.fmu", at={"q": 0.0025, "x_e": 1.029823}, outputs=["q"])
    >>> sys.input_labels, sorted(round(float(s.real), 3) for s in sys.poles())   # open loop: one unstable pole
    (['u'], [-2.053, -2.053, 4.097])
    """
    from .engine.linearization import linearize_fmu as engine_linearize_fmu

    return statespace(engine_linearize_fmu(path, at, inputs, outputs, t, parameters), Path(path).stem)


def _examples() -> Path:
    """The checkout's examples/ (for the doctests; an installed wheel has none)."""
    return Path(__file__).resolve().parents[1] / "examples"


def _doctest_globals(tmp: Path) -> dict:
    """What the docstrings' examples use beside this module's names: EXAMPLES, tmp (a scratch folder)."""
    return {"EXAMPLES": _examples(), "tmp": tmp}

