"""Native (self-contained) plant FMUs: C generated from the plant's description, compiled with gcc.

    python -m fmus.native_build [--dest build/native] [IDENTIFIER ...]     # default: MEMS Maglev

A native FMU has the model identifier, variables, value references, units, descriptions, parameters, start
values, ModelStructure and DefaultExperiment of its pythonfmu twin (the modelDescription is written by
fmus/model_description.py from the twin's slave class, with `Native`: needsExecutionTool="false", the
generator's name, <SourceFiles>), and carries
    sources/       emc_fmi2.c, emc_fmi2.h (fmus/native/: the framework), emc_plant.c, emc_framework.h (the
                   plant kind; emc_controller.c, emc_controller.h, emc_design.c, emc_design.h for a controller;
                   emc_reference.c,
                   emc_reference.h for the Reference), model.c, emc_model.h (components.c_codegen: the model
                   functions), config.c, emc_config.h (from the twin's variables: the value references), the
                   FMI 2.0 headers
    binaries/linux64/<identifier>.so   compiled from sources/ (-std=c99 -Wall -Wextra -Werror; no libpython)
    binaries/win64/<identifier>.dll    cross-compiled with mingw-w64 where it is installed (imports only
                                       KERNEL32.dll and msvcrt.dll)
Model Exchange and Co-Simulation in one binary (docs/native-fmus.md; it says what is missing).
"""
from __future__ import annotations

import argparse
import hashlib
import shutil
import subprocess
import sys
import tempfile
import zipfile
from pathlib import Path
from typing import Sequence
from xml.dom.minidom import parseString
from xml.etree.ElementTree import tostring

from components.c_codegen import MODEL_HEADER, design_checks_available, model_c_source
from components.description import Description, load
from components.source_text import c_comment as _c_comment
from components.source_text import c_string as _c_string

from .model_description import Native, model_description

NATIVE = Path(__file__).resolve().parent / "native"
PLANTS = Path(__file__).resolve().parents[1] / "components" / "plants"
GENERATOR = "emcosim native C generator (components.c_codegen, fmus/native)"
COMMON = ("emc_fmi2.c", "emc_fmi2.h")      # the framework: the FMI functions of every kind (fmus/native)
FRAMEWORK = (*COMMON, "emc_plant.c", "emc_framework.h")
FMI_HEADERS = ("fmi2Functions.h", "fmi2FunctionTypes.h", "fmi2TypesPlatform.h")
SOURCE_FILES = ("emc_fmi2.c", "emc_plant.c", "model.c", "config.c")          # compiled together (<SourceFiles>)
CFLAGS = ("-std=c99", "-Wall", "-Wextra", "-Werror", "-O2", "-fPIC", "-shared")
# win64: Debian's gcc-mingw-w64-x86-64; mingw's own printf (msvcrt's knows no %zu), no PE timestamp and stripped
# and a fixed image base (reproducible: the same bytes from any build folder; auto-image-base hashes the path),
# libgcc linked in: the DLL imports KERNEL32.dll and msvcrt.dll alone (checked with objdump)
MINGW = "x86_64-w64-mingw32-gcc"
MINGW_FLAGS = ("-std=c99", "-Wall", "-Wextra", "-Werror", "-O2", "-shared", "-D__USE_MINGW_ANSI_STDIO=1",
               "-static-libgcc", "-Wl,--no-insert-timestamp", "-Wl,--disable-auto-image-base", "-s")
WIN64_IMPORTS = {"kernel32.dll", "msvcrt.dll"}
OPTIONS = {"canGetAndSetFMUstate": True, "canSerializeFMUstate": True}   # as the twin (fmus/build.py)
PAPER_PLANTS = {"MEMS": PLANTS / "mems.toml", "Maglev": PLANTS / "maglev.toml"}
PAPER_FMUS = ("MEMS", "Maglev", "MEMS_Proposition1", "MEMS_Theorem2", "Maglev_Proposition2", "Maglev_Theorem3",
              "Reference")


class NativeBuildError(RuntimeError):
    """A native FMU cannot be built (the message says why and what to do)."""


def _twin(identifier: str):
    """The twin's slave (fmus.models), declared, and its modelDescription options."""
    from .models import slave_class
    with tempfile.TemporaryDirectory() as resources:
        return slave_class(identifier)(instance_name="native-build", resources=resources)


def config_sources(slave, desc: Description, guid: str) -> tuple[str, str]:
    """(emc_config.h, config.c): the twin's variables by value reference, the start values."""
    states = [v.name for v in (*desc.q, *desc.p, *desc.x_e)]
    inputs = [v.name for v in desc.u]
    parameters = list(desc.parameters)
    rows, initial, input_start = [], [0.0] * len(states), [0.0] * len(inputs)
    for v in slave.variables:
        if v.causality == "parameter" and v.name in parameters:
            kind, index = "EMC_PARAMETER", parameters.index(v.name)
        elif v.causality == "parameter" and v.name.endswith("_0") and v.name[:-2] in states:
            kind, index = "EMC_INITIAL", states.index(v.name[:-2])
            initial[index] = float(v.start)
        elif v.causality == "parameter" and v.name == "rtol":
            kind, index, rtol = "EMC_TOLERANCE", 0, float(v.start)
        elif v.causality == "input" and v.name in inputs:
            kind, index = "EMC_INPUT", inputs.index(v.name)
            input_start[index] = float(v.start)
        elif v.causality == "output" and v.name in states:
            kind, index = "EMC_STATE", states.index(v.name)
        elif v.causality == "output" and v.name == "H":
            kind, index = "EMC_ENERGY", 0
        elif v.derivative_of in states:
            kind, index = "EMC_DERIVATIVE", states.index(v.derivative_of)
        else:
            raise NativeBuildError(f"{slave.model_identifier}: variable {v.name} ({v.causality}) has no native form")
        rows.append(f"    {{{kind}, {index}, {_c_string(v.name)}}},")
    header = "\n".join([
        _c_comment(f"Generated by fmus/native_build.py for {slave.model_identifier}; do not edit."),
        "#ifndef EMC_CONFIG_H", "#define EMC_CONFIG_H",
        f"#define EMC_MODEL_IDENTIFIER {_c_string(slave.model_identifier)}",
        f"#define EMC_GUID {_c_string(guid)}",
        f"#define EMC_N_M {desc.n_m}",
        f"#define EMC_N_PARAMETERS {len(parameters)}",
        f"#define EMC_N_STATES {len(states)}",
        f"#define EMC_N_INPUTS {len(inputs)}",
        f"#define EMC_N_VARIABLES {len(rows)}",
        "#endif", ""])

    def doubles(values) -> str:
        return ", ".join(repr(float(x)) for x in values)

    def strings(values) -> str:
        return ", ".join(_c_string(x) for x in values)
    conditions = {"> 0": "> 0", ">= 0": ">= 0", "any": "finite"}
    source = "\n".join([
        _c_comment(f"Generated by fmus/native_build.py for {slave.model_identifier}; do not edit."),
        '#include "emc_framework.h"', "",
        "const emc_variable EMC_VARIABLES[EMC_N_VARIABLES] = {   /* by value reference */", *rows, "};",
        f"const double EMC_PARAMETER_START[EMC_N_PARAMETERS] = {{{doubles(slave.values[p] for p in parameters)}}};",
        f"const char *const EMC_PARAMETER_NAMES[EMC_N_PARAMETERS] = {{{strings(parameters)}}};",
        "const char *const EMC_PARAMETER_CONDITIONS[EMC_N_PARAMETERS] = "
        f"{{{strings(conditions[p.condition] for p in desc.parameters.values())}}};",
        f"const double EMC_INITIAL_START[EMC_N_STATES] = {{{doubles(initial)}}};",
        f"const char *const EMC_STATE_NAMES[EMC_N_STATES] = {{{strings(states)}}};",
        f"const double EMC_INPUT_START[EMC_N_INPUTS] = {{{doubles(input_start)}}};",
        f"const double EMC_RTOL_START = {rtol!r};", ""])
    return header, source


def _fmi_headers() -> Path:
    import fmpy  # the FMI 2.0 headers shipped with fmpy
    return Path(fmpy.__file__).parent / "c-code"


def compile_sources(sources: Path, library: Path, cc: str = "gcc", extra: tuple[str, ...] = (),
                    files: tuple[str, ...] = SOURCE_FILES) -> None:
    """Compile `files` of sources/ into `library` (NativeBuildError with the compiler's message)."""
    if shutil.which(cc) is None:
        raise NativeBuildError(f"native FMUs: the C compiler {cc!r} is not installed (Debian/Ubuntu: apt-get install gcc)")
    command = [cc, *CFLAGS, *extra, "-I", str(sources), *(str(sources / f) for f in files), "-o", str(library), "-lm"]
    run = subprocess.run(command, capture_output=True, text=True)
    if run.returncode != 0:
        raise NativeBuildError(f"native FMUs: compiling failed:\n{' '.join(command)}\n{run.stderr}")


def build_native(identifier: str, dest: Path | str, cc: str = "gcc") -> Path:
    """Build the native form of the paper's plant FMU `identifier` (MEMS, Maglev) into dest/<identifier>.fmu."""
    toml = PAPER_PLANTS.get(identifier)
    if toml is None:
        raise NativeBuildError(f"native FMUs: {identifier} is not one of the paper's plant FMUs "
                               f"({', '.join(PAPER_PLANTS)}); native controllers and the Reference are not generated yet")
    return _build(_twin(identifier), load(toml), dest, cc)


def _build(slave, desc: Description, dest: Path | str, cc: str) -> Path:
    """The native FMU of the twin `slave` (a declared PlantSlave) and its description `desc`."""
    if not desc.constant_mass and desc.n_m > 3:
        raise NativeBuildError(f"native FMUs: {desc.name}: M depends on q with n_m = {desc.n_m} > 3 (no symbolic "
                               "inverse is generated)")
    model_c = model_c_source(desc)
    generated = {"model.c": model_c, "emc_model.h": MODEL_HEADER}
    return _package(slave, FRAMEWORK, generated, SOURCE_FILES, lambda guid: config_sources(slave, desc, guid), dest, cc)


def win64_available() -> bool:
    """Is the mingw-w64 cross compiler (and its objdump) installed?"""
    return shutil.which(MINGW) is not None and shutil.which("x86_64-w64-mingw32-objdump") is not None


def compile_win64(sources: Path, library: Path, files: tuple[str, ...]) -> None:
    """Cross-compile `files` of sources/ into the win64 DLL `library` and check that it imports only system
    libraries (WIN64_IMPORTS); NativeBuildError otherwise."""
    command = [MINGW, *MINGW_FLAGS, "-I", ".", *files, "-o", str(library.resolve())]
    run = subprocess.run(command, cwd=sources, capture_output=True, text=True)     # relative paths: reproducible
    if run.returncode != 0:
        raise NativeBuildError(f"native FMUs: cross-compiling for win64 failed:\n{' '.join(command)}\n{run.stderr}")
    dump = subprocess.run(["x86_64-w64-mingw32-objdump", "-p", str(library)], capture_output=True, text=True)
    imports = {line.split(":", 1)[1].strip().lower() for line in dump.stdout.splitlines() if "DLL Name:" in line}
    if dump.returncode != 0 or not imports or not imports <= WIN64_IMPORTS:
        raise NativeBuildError(f"native FMUs: {library.name} imports {sorted(imports)}, not only {sorted(WIN64_IMPORTS)}")


def _package(slave, framework: tuple[str, ...], generated: dict[str, str], source_files: tuple[str, ...],
             config, dest: Path | str, cc: str) -> Path:
    """Write dest/<identifier>.fmu: the modelDescription of `slave` (the twin) in its native form, sources/
    (the framework files of fmus/native, the generated files, the config that `config(guid)` gives as
    (emc_config.h, config.c), the FMI headers) and binaries/linux64 compiled from `source_files`."""
    identifier = slave.model_identifier
    native = Native(GENERATOR, source_files, co_simulation=True)
    text = "".join((NATIVE / f).read_text() for f in framework) + "".join(generated[k] for k in sorted(generated))
    root = model_description(slave, text, OPTIONS, native)
    header, config_c = config(root.get("guid"))
    files: dict[str, bytes] = {"modelDescription.xml": parseString(tostring(root, "UTF-8")).toprettyxml(encoding="UTF-8")}
    with tempfile.TemporaryDirectory() as work:
        sources = Path(work) / "sources"
        sources.mkdir()
        for name in framework:
            shutil.copy2(NATIVE / name, sources / name)
        for name in FMI_HEADERS:
            shutil.copy2(_fmi_headers() / name, sources / name)
        for name, content in {**generated, "emc_config.h": header, "config.c": config_c}.items():
            (sources / name).write_text(content)
        library = Path(work) / f"{identifier}.so"
        compile_sources(sources, library, cc, files=source_files)
        for path in sorted(sources.iterdir()):
            files[f"sources/{path.name}"] = path.read_bytes()
        files[f"binaries/linux64/{identifier}.so"] = library.read_bytes()
        if win64_available():                  # a binary for Windows where the cross compiler is installed
            dll = Path(work) / f"{identifier}.dll"
            compile_win64(sources, dll, source_files)
            files[f"binaries/win64/{identifier}.dll"] = dll.read_bytes()
    dest = Path(dest)
    dest.mkdir(parents=True, exist_ok=True)
    target = dest / f"{identifier}.fmu"
    with zipfile.ZipFile(target, "w", zipfile.ZIP_DEFLATED) as z:
        for name in sorted(files):
            info = zipfile.ZipInfo(name, date_time=(2020, 1, 1, 0, 0, 0))
            info.external_attr = 0o644 << 16
            info.compress_type = zipfile.ZIP_DEFLATED
            z.writestr(info, files[name])
    return target


# ---- controllers ------------------------------------------------------------------------------------
CONTROLLER_FRAMEWORK = (*COMMON, "emc_controller.c", "emc_controller.h", "emc_design.c", "emc_design.h")
CONTROLLER_SOURCE_FILES = ("emc_fmi2.c", "emc_controller.c", "emc_design.c", "controller.c", "model.c", "config.c")


def controller_config(slave, desc: Description, design, guid: str) -> tuple[str, str]:
    """(emc_config.h, config.c) of a controller FMU: the twin's variables by value reference, the starts."""
    parameters, gains = list(desc.parameters), list(design.gains)
    inputs = list(slave.input_names)
    outputs = [v.name for v in desc.u]
    rows = []
    for v in slave.variables:
        if v.causality == "parameter" and v.name in parameters:
            kind, index = "EMC_C_PARAMETER", parameters.index(v.name)
        elif v.causality == "parameter" and v.name in gains:
            kind, index = "EMC_C_GAIN", gains.index(v.name)
        elif v.causality == "parameter" and v.name == "strict":
            kind, index = "EMC_C_STRICT", 0
        elif v.causality == "input" and v.name in inputs:
            kind, index = "EMC_C_INPUT", inputs.index(v.name)
        elif v.causality == "output" and v.name in outputs:
            kind, index = "EMC_C_OUTPUT", outputs.index(v.name)
        else:
            raise NativeBuildError(f"{slave.model_identifier}: variable {v.name} ({v.causality}) has no native form")
        rows.append(f"    {{{kind}, {index}, {_c_string(v.name)}}},")
    header = "\n".join([
        _c_comment(f"Generated by fmus/native_build.py for {slave.model_identifier}; do not edit."),
        "#ifndef EMC_CONFIG_H", "#define EMC_CONFIG_H",
        f"#define EMC_MODEL_IDENTIFIER {_c_string(slave.model_identifier)}",
        f"#define EMC_GUID {_c_string(guid)}",
        f"#define EMC_N_PARAMETERS {len(parameters)}",
        f"#define EMC_N_GAINS {len(gains)}",
        f"#define EMC_N_CONTROLLER_INPUTS {len(inputs)}",
        f"#define EMC_N_OUTPUTS {len(outputs)}",
        f"#define EMC_N_VARIABLES {len(rows)}",
        f"#define EMC_N_STATES {2 * desc.n_m + desc.n_e}",
        # controller.c has emc_ctrl_design (components.c_codegen.design_checks_c_source): strict as the twin's
        f"#define EMC_DESIGN_CHECKED {int(design_checks_available(desc))}",
        f"#define EMC_TRACKING {int(design.tracking)}",
        "#endif", ""])
    conditions = {"> 0": "> 0", ">= 0": ">= 0", "any": "finite"}

    def doubles(values) -> str:
        return ", ".join(repr(float(x)) for x in values)

    def strings(values) -> str:
        return ", ".join(_c_string(x) for x in values)
    source = "\n".join([
        _c_comment(f"Generated by fmus/native_build.py for {slave.model_identifier}; do not edit."),
        '#include "emc_controller.h"', "",
        "const emc_c_variable EMC_VARIABLES[EMC_N_VARIABLES] = {   /* by value reference */", *rows, "};",
        f"const double EMC_PARAMETER_START[EMC_N_PARAMETERS] = {{{doubles(slave.values[p] for p in parameters)}}};",
        f"const char *const EMC_PARAMETER_NAMES[EMC_N_PARAMETERS] = {{{strings(parameters)}}};",
        "const char *const EMC_PARAMETER_CONDITIONS[EMC_N_PARAMETERS] = "
        f"{{{strings(conditions[p.condition] for p in desc.parameters.values())}}};",
        f"const double EMC_GAIN_START[EMC_N_GAINS] = {{{doubles(slave.values[g] for g in gains)}}};",
        f"const char *const EMC_GAIN_NAMES[EMC_N_GAINS] = {{{strings(gains)}}};",
        "const char *const EMC_GAIN_CONDITIONS[EMC_N_GAINS] = "
        f"{{{strings(conditions[p.condition] for p in design.gains.values())}}};",
        f"const double EMC_INPUT_START[EMC_N_CONTROLLER_INPUTS] = {{{doubles(slave.values[i] for i in inputs)}}};",
        f"const char *const EMC_INPUT_NAMES[EMC_N_CONTROLLER_INPUTS] = {{{strings(inputs)}}};", ""])
    return header, source


def build_native_controller(identifier: str, dest: Path | str, cc: str = "gcc") -> Path:
    """Build the native form of the paper's controller FMU `identifier` (MEMS_Proposition1, MEMS_Theorem2,
    Maglev_Proposition2, Maglev_Theorem3) into dest/<identifier>.fmu."""
    plant, _, design_name = identifier.partition("_")
    toml = PAPER_PLANTS.get(plant)
    if toml is None or not design_name:
        raise NativeBuildError(f"native FMUs: {identifier} is not one of the paper's controller FMUs")
    return _build_controller(_twin(identifier), load(toml), design_name, dest, cc)


def _build_controller(slave, desc: Description, design_name: str, dest: Path | str, cc: str) -> Path:
    """The native controller FMU of the twin `slave` (a declared ControllerSlave) of design `design_name`."""
    from components.c_codegen import controller_c_source

    if not desc.constant_mass and desc.n_m > 3:
        raise NativeBuildError(f"native FMUs: {desc.name}: M depends on q with n_m = {desc.n_m} > 3 (no symbolic "
                               "inverse is generated)")
    design = slave.device.designs[design_name]
    try:
        law = controller_c_source(desc, design_name, list(design.gains.values()))
    except ValueError as exc:
        raise NativeBuildError(f"native FMUs: {slave.model_identifier}: {exc} (docs/native-fmus.md)") from None
    generated = {"controller.c": law, "model.c": model_c_source(desc), "emc_model.h": MODEL_HEADER}
    return _package(slave, CONTROLLER_FRAMEWORK, generated, CONTROLLER_SOURCE_FILES,
                    lambda guid: controller_config(slave, desc, design, guid), dest, cc)


# ---- the Reference ---------------------------------------------------------------------------------
REFERENCE_FRAMEWORK = (*COMMON, "emc_reference.c", "emc_reference.h")
REFERENCE_SOURCE_FILES = ("emc_fmi2.c", "emc_reference.c", "config.c")


def reference_config(slave, guid: str) -> tuple[str, str]:
    """(emc_config.h, config.c) of the Reference FMU from its twin's variables."""
    from components import catalog, references

    owner = {p: code for code, name in catalog.REFERENCE_KINDS.items() for p in references.KINDS[name].PARAMETERS}
    specs = {p.name: p for name in catalog.REFERENCE_KINDS.values() for p in references.KINDS[name].PARAMETERS.values()}
    parameters = [v.name for v in slave.variables if v.causality == "parameter" and v.name in owner]
    jet = [name for name, _, _ in references.JET_VARIABLES]
    rows = []
    for v in slave.variables:
        if v.causality == "parameter" and v.name == "kind":
            kind, index, kind_start = "EMC_R_KIND", 0, int(v.start)
        elif v.causality == "parameter" and v.name in owner:
            kind, index = "EMC_R_PARAMETER", parameters.index(v.name)
        elif v.causality == "output" and v.name in jet:
            kind, index = "EMC_R_OUTPUT", jet.index(v.name)
        elif v.causality == "independent":
            kind, index = "EMC_R_TIME", 0
        else:
            raise NativeBuildError(f"Reference: variable {v.name} ({v.causality}) has no native form")
        rows.append(f"    {{{kind}, {index}, {_c_string(v.name)}}},")
    header = "\n".join([
        "/* Generated by fmus/native_build.py for Reference; do not edit. */",
        "#ifndef EMC_CONFIG_H", "#define EMC_CONFIG_H",
        f"#define EMC_MODEL_IDENTIFIER {_c_string(slave.model_identifier)}",
        f"#define EMC_GUID {_c_string(guid)}",
        f"#define EMC_N_PARAMETERS {len(parameters)}",
        f"#define EMC_N_VARIABLES {len(rows)}",
        f"#define EMC_KIND_START {kind_start}",
        *(f"#define EMC_P_{name} {i}" for i, name in enumerate(parameters)),
        "#endif", ""])
    source = "\n".join([
        "/* Generated by fmus/native_build.py for Reference; do not edit. */",
        '#include "emc_reference.h"', "",
        "const emc_r_variable EMC_VARIABLES[EMC_N_VARIABLES] = {   /* by value reference */", *rows, "};",
        "const double EMC_PARAMETER_START[EMC_N_PARAMETERS] = {"
        + ", ".join(repr(float(slave.values[p])) for p in parameters) + "};",
        "const char *const EMC_PARAMETER_NAMES[EMC_N_PARAMETERS] = {" + ", ".join(_c_string(p) for p in parameters) + "};",
        "const char *const EMC_PARAMETER_CONDITIONS[EMC_N_PARAMETERS] = {"
        + ", ".join(_c_string(specs[p].condition) for p in parameters) + "};",
        "const int EMC_PARAMETER_KIND[EMC_N_PARAMETERS] = {" + ", ".join(str(owner[p]) for p in parameters) + "};", ""])
    return header, source


def build_native_reference(dest: Path | str, cc: str = "gcc") -> Path:
    """Build the native Reference FMU (fmus/native/emc_reference.c) into dest/Reference.fmu."""
    slave = _twin("Reference")
    return _package(slave, REFERENCE_FRAMEWORK, {}, REFERENCE_SOURCE_FILES, lambda guid: reference_config(slave, guid),
                    dest, cc)


def build_native_description_fmus(description: Path | str, designs: Sequence[str], dest: Path | str,
                                  cc: str = "gcc") -> dict[str, Path]:
    """The native plant FMU of a plant description file and a native controller FMU per design of `designs` (any
    n_m, n_e; NativeBuildError for a feasible reference with no native form: n_e < n_m, or coupled coils with
    n_e > n_m): model identifier -> path. The twins are the FMUs
    `emcosim plant build` makes (the slave classes of fmus.models.device_slave_classes)."""
    from components import codegen

    from .build import load_device_module
    from .models import device_slave_classes

    description = Path(description).resolve()
    desc = load(description)
    with tempfile.TemporaryDirectory(prefix="emcosim_native_") as tmp:
        module = Path(tmp) / f"{desc.name.lower()}_model.py"    # a checked identifier, not the file's name
        module.write_text(codegen.module_source(desc, description.name))
        # the device identity of the pythonfmu twins (fmus.build.build_description): the digest of the file
        model = hashlib.sha256(description.read_bytes()).hexdigest()
        classes = device_slave_classes(load_device_module(module), list(designs), model=model)
        with tempfile.TemporaryDirectory() as resources:
            slaves = {name: cls(instance_name="native-build", resources=resources) for name, cls in classes.items()}
    out = {desc.name: _build(slaves.pop(desc.name), desc, dest, cc)}
    for identifier, slave in slaves.items():
        out[identifier] = _build_controller(slave, desc, slave.design, dest, cc)
    return out


def build_native_description(description: Path | str, dest: Path | str, cc: str = "gcc") -> Path:
    """The native plant FMU of a plant description file (TOML) into dest/<name>.fmu (its twin: the plant FMU
    `emcosim plant build` makes)."""
    paths = build_native_description_fmus(description, [], dest, cc)
    return next(iter(paths.values()))


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description="Build native (self-contained) FMUs: the paper's plants and controllers.")
    ap.add_argument("identifiers", nargs="*", default=list(PAPER_FMUS), help=f"FMUs (default: {' '.join(PAPER_FMUS)})")
    ap.add_argument("--dest", default="build/native", help="output folder (default build/native)")
    args = ap.parse_args(argv)
    try:
        for identifier in args.identifiers:
            if identifier == "Reference":
                path = build_native_reference(args.dest)
            else:
                path = (build_native_controller if "_" in identifier else build_native)(identifier, args.dest)
            print(f"built       {path}")
    except NativeBuildError as exc:
        print(f"emcosim: error: {exc}", file=sys.stderr)
        return 1
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
