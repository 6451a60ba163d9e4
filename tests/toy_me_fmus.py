"""Build the C Model Exchange toy FMUs of tests/fixtures/toy_me.c (Dahlquist, Gain, BouncingBall, Clock,
Faulty): one shared library compiled with gcc against fmpy's FMI headers, and per FMU a modelDescription.xml
with <ModelExchange> only (no <CoSimulation>), der(...) variables with derivative=, ModelStructure
(Outputs, Derivatives, InitialUnknowns), numberOfEventIndicators and providesDirectionalDerivative.

`fmus(folder)` builds them once per test session (a module-level cache, as tests/c_host.py does); it
returns None if gcc is missing."""
from __future__ import annotations

import shutil
import subprocess
import zipfile
from dataclasses import dataclass, field
from pathlib import Path

SOURCE = Path(__file__).parent / "fixtures" / "toy_me.c"


@dataclass(frozen=True)
class Var:
    name: str
    causality: str                      # parameter, input, output, local
    variability: str = "continuous"
    start: float | None = None          # parameters and inputs
    derivative: str | None = None       # der(x): the state's name


@dataclass(frozen=True)
class Model:
    variables: list                      # in value-reference order (tests/fixtures/toy_me.c's enums)
    outputs: dict                        # output -> the inputs it depends on
    derivatives: dict = field(default_factory=dict)   # der(x) -> the states and inputs it depends on
    indicators: int = 0
    directional: bool = True             # providesDirectionalDerivative
    step_needed: bool = False            # not completedIntegratorStepNotNeeded


def P(name: str, start: float) -> Var:
    return Var(name, "parameter", "fixed", start)


MODELS = {
    "Dahlquist": Model([P("a", -1.0), P("b", 1.0), P("x0", 1.0), P("nominal", 1.0), Var("u", "input", start=0.0),
                        Var("x", "output"), Var("der(x)", "local", derivative="x")],
                       {"x": []}, {"der(x)": ["x", "u"]}),
    "Gain": Model([P("k", 1.0), Var("u", "input", start=0.0), Var("y", "output")], {"y": ["u"]}),
    "BouncingBall": Model([P("g", 9.81), P("e", 0.7), P("h0", 1.0), P("v0", 0.0), P("v_min", 0.0),
                           Var("h", "output"), Var("der(h)", "local", derivative="h"),
                           Var("v", "output"), Var("der(v)", "local", derivative="v")],
                          {"h": [], "v": []}, {"der(h)": ["v"], "der(v)": []}, indicators=1, step_needed=True),
    "Clock": Model([P("period", 0.5), Var("count", "output", "discrete")], {"count": []}, directional=False),
    "Faulty": Model([P("a", -1.0), P("x0", 1.0), P("nan_at", 1e300), P("fail_at", 1e300), Var("x", "local"),
                     Var("der(x)", "local", derivative="x"), Var("y", "output")],
                    {"y": []}, {"der(x)": ["x"]}, directional=False),
}

_FMUS: dict[str, Path] = {}


def compile_library(dest: Path) -> Path | None:
    """The shared library (in dest), or None if gcc is missing."""
    if shutil.which("gcc") is None:
        return None
    import fmpy

    lib = dest / "toy_me.so"
    subprocess.run(["gcc", "-O2", "-Wall", "-Wextra", "-Werror", "-shared", "-fPIC", "-I",
                    str(Path(fmpy.__file__).parent / "c-code"), str(SOURCE), "-o", str(lib), "-lm"],
                   check=True, capture_output=True)
    return lib


def model_description(kind: str, identifier: str, directional: bool | None = None) -> str:
    """The modelDescription.xml of toy `kind` as FMU `identifier`; directional overrides whether it
    declares providesDirectionalDerivative (the C code provides them in any case)."""
    model = MODELS[kind]
    index = {v.name: i + 1 for i, v in enumerate(model.variables)}
    directional = model.directional if directional is None else directional
    lines = []
    for i, v in enumerate(model.variables):
        attrs = f'name="{v.name}" valueReference="{i}" causality="{v.causality}" variability="{v.variability}"'
        real = ""
        if v.causality == "parameter":
            attrs += ' initial="exact"'
        elif v.causality in ("output", "local"):
            attrs += ' initial="calculated"'
        if v.start is not None:
            real += f' start="{v.start!r}"'
        if v.derivative is not None:
            real += f' derivative="{index[v.derivative]}"'
        lines.append(f"    <ScalarVariable {attrs}><Real{real}/></ScalarVariable>")

    def unknown(name: str, deps: list | None) -> str:
        d = "" if deps is None else f' dependencies="{" ".join(str(index[n]) for n in deps)}"'
        return f'      <Unknown index="{index[name]}"{d}/>'

    states = {v.derivative for v in model.variables if v.derivative}
    derivatives = "".join(f"{unknown(o, d)}\n" for o, d in model.derivatives.items())
    if derivatives:
        derivatives = f"    <Derivatives>\n{derivatives}    </Derivatives>\n"
    initial = sorted((index[v.name], v.name) for v in model.variables
                     if v.causality == "output" or v.name in states or v.derivative)
    return f"""<?xml version="1.0" encoding="UTF-8"?>
<fmiModelDescription fmiVersion="2.0" modelName="{identifier}" guid="{{toy-me-{kind}-{identifier}}}"
  generationTool="tests/toy_me_fmus.py" variableNamingConvention="structured"
  numberOfEventIndicators="{model.indicators}">
  <ModelExchange modelIdentifier="{identifier}" providesDirectionalDerivative="{str(directional).lower()}"
    completedIntegratorStepNotNeeded="{str(not model.step_needed).lower()}" canGetAndSetFMUstate="true"/>
  <DefaultExperiment startTime="0" stopTime="1" stepSize="0.01"/>
  <ModelVariables>
{chr(10).join(lines)}
  </ModelVariables>
  <ModelStructure>
    <Outputs>
{chr(10).join(unknown(o, d) for o, d in model.outputs.items())}
    </Outputs>
{derivatives}    <InitialUnknowns>
{chr(10).join(unknown(name, None) for _, name in initial)}
    </InitialUnknowns>
  </ModelStructure>
</fmiModelDescription>
"""


def build(dest: Path, library: Path, kind: str, identifier: str | None = None, directional: bool | None = None) -> Path:
    """Write dest/<identifier>.fmu (default identifier: ToyME<kind>)."""
    identifier = identifier or f"ToyME{kind}"
    fmu = dest / f"{identifier}.fmu"
    with zipfile.ZipFile(fmu, "w") as z:
        z.writestr("modelDescription.xml", model_description(kind, identifier, directional))
        z.write(library, f"binaries/linux64/{identifier}.so")
    return fmu


def fmus(folder: Path) -> dict[str, Path] | None:
    """Every toy of MODELS as ToyME<kind>.fmu, plus ToyMEDahlquistFD (the same without
    providesDirectionalDerivative), built once per test session into `folder` (the first caller's);
    None if gcc is missing."""
    if not _FMUS:
        folder.mkdir(parents=True, exist_ok=True)
        lib = compile_library(folder)
        if lib is None:
            return None
        for kind in MODELS:
            _FMUS[kind] = build(folder, lib, kind)
        _FMUS["DahlquistFD"] = build(folder, lib, "Dahlquist", "ToyMEDahlquistFD", directional=False)
    return dict(_FMUS)
