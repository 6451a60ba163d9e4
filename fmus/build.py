"""Build the emcosim FMUs (`python build.py`, or `python -m fmus.build`; `build()` from Python).

An FMU holds (docs/fmus.md, "The loader"):
  binaries/linux64/<id>.so                the loader (fmus/emcosim_fmu_loader.c, compiled here with gcc)
  binaries/linux64/libpythonfmu-export.so pythonfmu 0.7.0's export library, which the loader forwards to
  resources/emcosim_fmu.txt               which Python runs the FMU: this interpreter (its environment has
                                          numpy and scipy), its libpython and version; the build tag
  resources/emcosim_fmu_<tag>/            the bundle package: the fmus package, components/ and pythonfmu's
                                          Python package as its subpackages, under a name unique to the
                                          build (all Python FMUs of a process share one interpreter and its
                                          module names); imports of components, fmus and pythonfmu are
                                          rewritten to the bundle's (`rewrite_imports`)
  resources/emcosim_fmu_<tag>_<id>.py     the script pythonfmu runs (generated: binds the slave class)
  modelDescription.xml                    from the slave class (fmus/model_description.py)
The tag is the start of the build fingerprint (every input: sources, pythonfmu, the loader, the
compiler, the Python recorded). Archives are written with fixed timestamps and order, the loader is
compiled deterministically and the GUID is derived from the content, so the same inputs give
byte-identical FMUs. A stamp file records the fingerprint: when nothing changed, nothing is rebuilt.

This module is part of the installed package (its sources are found beside it), so an installed wheel
builds FMUs too: `python -m fmus.build --dest DIR`.
"""
from __future__ import annotations

import argparse
import hashlib
import importlib
import importlib.metadata
import itertools
import json
import os
import re
import shutil
import subprocess
import sys
import sysconfig
import tempfile
import zipfile
from pathlib import Path
from typing import Sequence
from xml.dom.minidom import parseString
from xml.etree.ElementTree import tostring

import components

from .models import MODELS

FMU_SOURCES = Path(__file__).resolve().parent                  # the fmus package
COMPONENTS = Path(components.__file__).resolve().parent
LOADER = FMU_SOURCES / "emcosim_fmu_loader.c"
CHECKOUT = FMU_SOURCES.parent                                   # the repository, when run from one
STAMP = ".build-stamp.json"
RECORD = "emcosim_fmu.txt"                     # read by the loader
PYTHONFMU_LIBRARY = "libpythonfmu-export.so"   # the name the loader looks for beside itself
# the SONAME of every FMU's loader: the copies loaded into one process find the first one by it and share
# its lock around starting Python (fmus/emcosim_fmu_loader.c, "state of the process")
LOADER_SONAME = "libemcosim_fmu_loader.so.1"
OVERRIDE_VARIABLE = "EMCOSIM_FMU_PYTHON"
DESCRIPTION_RESOURCE = "resources/emcosim_description.toml"   # a device FMU's description file

FMUS = list(MODELS)                             # the model identifiers of the suite's FMUs
IMPORT_ROOTS = ("components", "fmus", "pythonfmu")  # packages that the bundle holds under its own name
OPTIONS = {"canGetAndSetFMUstate": True, "canSerializeFMUstate": True}
# pythonfmu's Python files that are bundled (as pythonfmu's own builder does, without the two that import
# pythonfmu by its absolute name: the bundle holds it as a subpackage)
PYTHONFMU_SKIPPED = {"__main__.py", "csvbuilder.py"}


_ALIASES = itertools.count()


def default_dest() -> Path:
    """build/fmus of the repository when this package runs from a checkout (the scenarios' .ssd files
    point there), else of the current folder."""
    if (CHECKOUT / "pyproject.toml").is_file() and (CHECKOUT / "scenarios").is_dir():
        return CHECKOUT / "build" / "fmus"
    return Path.cwd() / "build" / "fmus"


class BuildError(RuntimeError):
    """Something build.py needs is missing on this machine (the message says what and how to get it)."""


# ---- the tool chain: gcc, Python headers, libpython ------------------------------------------------
def python_record() -> dict[str, str]:
    """The Python the FMUs will use in hosts without Python: this interpreter, its libpython and version."""
    version = ".".join(map(str, sys.version_info[:3]))
    libdir = Path(sysconfig.get_config_var("LIBDIR") or "")
    soname = sysconfig.get_config_var("INSTSONAME") or sysconfig.get_config_var("LDLIBRARY") or ""
    multiarch = sysconfig.get_config_var("MULTIARCH") or ""
    candidates = [libdir / soname, libdir / multiarch / soname] if soname.endswith(".so.1.0") else []
    library = next((c for c in candidates if c.is_file()), None)
    if library is None:
        minor = "{}.{}".format(*sys.version_info[:2])
        raise BuildError(
            f"build.py: this Python ({sys.executable}, {version}) has no shared library libpython{minor}.so.1.0 "
            f"(looked in {libdir}); the FMUs load it in hosts that have no Python. Install it (Debian/Ubuntu: "
            f"apt-get install libpython{minor}; pyenv: env PYTHON_CONFIGURE_OPTS=--enable-shared pyenv install "
            f"{version}) or build with a Python that has it.")
    return {"python_executable": str(Path(sys.executable).absolute()), "python_library": str(library),
            "python_version": version, "multiarch": multiarch}


def _compiler() -> tuple[str, str]:
    """gcc (or $CC) and the Python headers' folder; BuildError saying how to get what is missing."""
    cc = os.environ.get("CC", "gcc")
    if shutil.which(cc) is None:
        raise BuildError(f"build.py: the C compiler {cc!r} is not installed; the FMU loader "
                         f"({LOADER.name}) is compiled at build time. Install gcc (Debian/Ubuntu: "
                         f"apt-get install gcc) or set CC.")
    include = Path(sysconfig.get_paths()["include"])
    if not (include / "Python.h").is_file():
        minor = "{}.{}".format(*sys.version_info[:2])
        raise BuildError(f"build.py: the Python headers are missing ({include}/Python.h); the FMU loader needs "
                         f"them. Install them (Debian/Ubuntu: apt-get install python{minor}-dev; pyenv and "
                         f"python.org builds include them).")
    return cc, str(include)


def _fmi_headers() -> Path:
    import fmpy  # the FMI 2.0 headers shipped with fmpy
    return Path(fmpy.__file__).parent / "c-code"


def _compiler_version(cc: str) -> str:
    return subprocess.run([cc, "--version"], capture_output=True, text=True).stdout.splitlines()[0]


def compile_loader(work: Path) -> Path:
    """Compile the loader into work/loader.so (deterministic: no debug information, relative paths) and
    check that it needs no Python symbol at load time."""
    cc, include = _compiler()
    shutil.copy2(LOADER, work / LOADER.name)
    for header in ("fmi2Functions.h", "fmi2FunctionTypes.h", "fmi2TypesPlatform.h"):
        shutil.copy2(_fmi_headers() / header, work / header)
    # -Wno-format-truncation: messages are cut at MESSAGE_SIZE on purpose
    command = [cc, "-std=gnu11", "-O2", "-fPIC", "-shared", "-fvisibility=hidden", "-Wall", "-Wextra",
               "-Wno-format-truncation", "-Werror", f'-DLOADER_SONAME="{LOADER_SONAME}"', f"-Wl,-soname,{LOADER_SONAME}",
               "-I", ".", "-I", include, LOADER.name, "-o", "loader.so", "-ldl"]
    # gcc's own temporary files go into `work` too (a killed build leaves nothing outside its folder)
    run = subprocess.run(command, cwd=work, capture_output=True, text=True, env={**os.environ, "TMPDIR": str(work)})
    if run.returncode != 0:
        raise BuildError(f"build.py: compiling {LOADER} failed:\n{' '.join(command)}\n{run.stderr}")
    undefined = subprocess.run(["nm", "-D", "--undefined-only", "loader.so"], cwd=work, capture_output=True, text=True)
    python_symbols = [line.split()[-1] for line in undefined.stdout.splitlines() if line.split()[-1].startswith(("Py", "_Py"))]
    if undefined.returncode != 0 or python_symbols:
        raise BuildError(f"build.py: the loader must not link Python (found {python_symbols or undefined.stderr})")
    return work / "loader.so"


# ---- fingerprint -----------------------------------------------------------------------------------
def _sources(models: dict[str, Path | None], extra: Sequence[Path] = ()) -> list[Path]:
    files = ([LOADER] + sorted(FMU_SOURCES.glob("*.py")) + sorted(COMPONENTS.rglob("*.py"))
             + sorted({m for m in models.values() if m is not None}) + sorted(set(extra)))
    return [f for f in dict.fromkeys(files) if "__pycache__" not in f.parts]


def fingerprint(models: dict[str, Path | None] | None = None, extra: Sequence[Path] = ()) -> str:
    """sha256 over every input of the build: sources (and the `extra` files: device modules, description
    files), pythonfmu (code and library), the FMI headers, the compiler, and the Python the FMUs record."""
    models = _models() if models is None else models
    try:
        record, compiler = python_record(), _compiler_version(_compiler()[0])
    except BuildError as exc:                       # reported by build(); the fingerprint just differs
        record, compiler = {"missing": str(exc)}, ""
    digest = hashlib.sha256(json.dumps([record, compiler, sorted((k, v.name if v else "") for k, v in models.items())]).encode())
    inputs = (_sources(models, extra) + sorted(_pythonfmu_dir().glob("*.py")) + [_pythonfmu_library()]
              + sorted(_fmi_headers().glob("fmi2*.h")))
    for f in inputs:
        digest.update(f.name.encode() + b"\0" + f.read_bytes())
    return digest.hexdigest()


def _models() -> dict[str, Path | None]:
    """The suite's FMUs: each is a row of fmus/models.py (no module of its own)."""
    return {identifier: None for identifier in FMUS}


def _pythonfmu_dir() -> Path:
    """The installed pythonfmu package. Not `pythonfmu.__file__`: a pythonfmu FMU of another project run in
    this process before its first `import pythonfmu` puts its own copy (in the FMU's unzip folder, deleted
    after the run) into sys.modules; the build then read files that were gone (seen in the test suite when
    tests running foreign toy FMUs came before the build fixture)."""
    return Path(importlib.metadata.distribution("pythonfmu").locate_file("pythonfmu"))


def _pythonfmu_library() -> Path:
    return _pythonfmu_dir() / "resources" / "binaries" / "linux64" / PYTHONFMU_LIBRARY


def package_name(build_fingerprint: str) -> str:
    """The bundle package of a build: unique to this project and build."""
    return f"emcosim_fmu_{build_fingerprint[:12]}"


# ---- the FMU ----------------------------------------------------------------------------------------
def rewrite_imports(text: str, depth: int, where: str) -> str:
    """`from components...`, `from fmus...` and `from pythonfmu...` as relative imports of the bundle's
    subpackages (`from ..components...` in a module `depth` packages below the bundle's root): the one
    mapping between the source tree and the bundle, which then imports under any name (the build imports
    it under a name of its own). `import X` of those roots is refused (it would bind another name)."""
    dots = "." * (depth + 1)
    out = []
    for number, line in enumerate(text.splitlines(keepends=True), start=1):
        match = re.match(r"(\s*)(from|import)\s+(" + "|".join(IMPORT_ROOTS) + r")\b", line)
        if match:
            if match.group(2) == "import":
                raise ValueError(f"{where}:{number}: write `from {match.group(3)} import ...` (the build maps that form)")
            line = f"{match.group(1)}from {dots}{line[match.end(1) + len('from '):].lstrip()}"
        out.append(line)
    return "".join(out)


def _copy_package(source: Path, target: Path, skip: tuple[str, ...] = ()) -> None:
    """Copy the package `source` to `target`, a subpackage of the bundle's root."""
    for f in sorted(source.rglob("*.py")):
        if "__pycache__" in f.parts or f.name in skip:
            continue
        dest = target / f.relative_to(source)
        dest.parent.mkdir(parents=True, exist_ok=True)
        depth = len(f.relative_to(source).parts)                   # 1 for a module of the subpackage itself
        dest.write_text(rewrite_imports(f.read_text(), depth, str(f)))


def _bundle(work: Path, package: str, build_fingerprint: str, models: dict[str, Path | None],
            extra_modules: Sequence[Path] = ()) -> Path:
    """work/resources/<package>: the fmus package, components/ and pythonfmu's Python package as its
    subpackages, and the model modules of `models` and `extra_modules` beside them."""
    resources = work / "resources"
    target = resources / package
    target.mkdir(parents=True)
    (target / "__init__.py").write_text(BUNDLE_INIT.replace("<BUILD>", build_fingerprint))
    _copy_package(FMU_SOURCES, target / "fmus", skip=("build.py",))   # the build is not part of an FMU
    init = target / "fmus" / "__init__.py"
    init.write_text(re.sub(r'(?m)^BUILD = .*$', f'BUILD = "{build_fingerprint}"', init.read_text()))
    _copy_package(COMPONENTS, target / "components")
    (target / "pythonfmu").mkdir()
    for source in sorted(_pythonfmu_dir().glob("*.py")):
        if source.name not in PYTHONFMU_SKIPPED:
            shutil.copy2(source, target / "pythonfmu" / source.name)
    for source in sorted({m for m in models.values() if m is not None} | set(extra_modules)):
        if (target / source.name).exists() or source.stem in IMPORT_ROOTS:
            raise ValueError(f"model module {source} is named like a package of the bundle")
        (target / source.name).write_text(rewrite_imports(source.read_text(), 0, str(source)))
    return resources


BUNDLE_INIT = '''"""emcosim FMU bundle of build <BUILD> (generated by fmus/build.py): the fmus package, components/
and pythonfmu's Python package, under a name unique to the build."""
import os
import sys

BUILD = "<BUILD>"


def add_folder(folder: str) -> None:
    """Let this package and its subpackages already loaded also find modules in `folder`, the copy of this
    package in another FMU of the build (called by the loader at fmi2Instantiate). The folder the package
    was first imported from may be gone (hosts delete an FMU's unzip folder after a run); a module not
    imported yet is then found in the FMU being instantiated."""
    for name, module in list(sys.modules.items()):
        path = getattr(module, "__path__", None)
        if path is not None and (name == __name__ or name.startswith(__name__ + ".")):
            folder_of_name = os.path.join(folder, *name.split(".")[1:])
            if folder_of_name not in path:
                path.append(folder_of_name)
'''


def _script(package: str, module: str | None, identifier: str, build_fingerprint: str) -> str:
    if module is None:                                          # a row of fmus/models.py
        binding = f"from {package}.fmus.models import slave_class\n\n{identifier} = slave_class({identifier!r})\n"
    else:
        binding = f"from {package}.{module} import {identifier}\n\n"
    return (f'"""emcosim FMU {identifier} (generated by fmus/build.py). pythonfmu runs this script at every\n'
            f'fmi2Instantiate and takes its one slave class, {identifier}."""\n'
            f"from {package}.fmus.pythonfmu_workarounds import hold_script_globals\n"
            + binding +
            f'BUILD = "{build_fingerprint}"\n'
            "hold_script_globals(globals())\n")


def _model_description(alias: str, module: str | None, identifier: str, resources: Path) -> tuple[str, bytes]:
    """(GUID, modelDescription.xml) from the slave class of the bundle, imported as package `alias`."""
    if module is None:
        cls = importlib.import_module(f"{alias}.fmus.models").slave_class(identifier)
    else:
        cls = getattr(importlib.import_module(f"{alias}.{module}"), identifier)
    slave = cls(instance_name="build", resources=str(resources))
    root = slave.to_xml(OPTIONS)
    if root.find("CoSimulation").get("modelIdentifier") != identifier:
        raise ValueError(f"{module or 'fmus.models'}.{identifier} declares model identifier "
                         f"{root.find('CoSimulation').get('modelIdentifier')}")
    return root.get("guid"), parseString(tostring(root, "UTF-8")).toprettyxml(encoding="UTF-8")


def _write_fmu(target: Path, files: dict[str, bytes]) -> None:
    """A zip archive with sorted entries, fixed timestamps and permissions (reproducible), written into a new
    file beside `target` (created by this call: O_EXCL, no link followed) and renamed onto it."""
    for n in range(100):                         # a killed build with our pid may have left one
        tmp = target.with_name(f"{target.name}.tmp-{os.getpid()}" + (f"-{n}" if n else ""))
        try:
            fd = os.open(tmp, os.O_WRONLY | os.O_CREAT | os.O_EXCL | os.O_NOFOLLOW | os.O_CLOEXEC, 0o666)
            break
        except FileExistsError:
            continue
    else:
        raise FileExistsError(f"too many {target.name}.tmp-{os.getpid()} files beside {target}")
    try:
        with os.fdopen(fd, "wb") as f, zipfile.ZipFile(f, "w") as zout:
            for name in sorted(files):
                info = zipfile.ZipInfo(name, date_time=(1980, 1, 1, 0, 0, 0))
                info.compress_type = zipfile.ZIP_DEFLATED
                info.external_attr = (0o755 if name.startswith("binaries/") else 0o644) << 16
                zout.writestr(info, files[name])
        tmp.replace(target)
    except BaseException:                        # an error or Ctrl-C: no half-written archive is left
        tmp.unlink(missing_ok=True)
        raise


def repack(src: Path, dest: Path) -> None:
    """Rewrite a zip archive with sorted entries, fixed timestamps and permissions (reproducible)."""
    with zipfile.ZipFile(src) as zin:
        files = {i.filename: zin.read(i.filename) for i in zin.infolist() if not i.is_dir()}
    _write_fmu(dest, files)


def build_fmus(models: dict[str, Path | None], dest: Path | str, build_fingerprint: str | None = None,
               extra_modules: Sequence[Path] = (), resource_files: Sequence[Path] = (),
               temp_root: Path | None = None) -> dict[str, Path]:
    """Build one FMU per entry of `models` into `dest`, all with one bundle: model identifier -> None for
    a row of fmus/models.py, or the Python module that defines the slave class of that name (an EMSlave,
    `from fmus.slave import EMSlave`, like the tests' toy FMUs). `extra_modules`: more modules of the bundle
    (beside the model modules, imported by them: a device module); `resource_files`: files copied into every
    FMU's resources/ under their names (a plant description); `temp_root`: the folder the build's temporary
    folders are made in (default: the system's; `emcosim plant build` gives a marked one, engine/tempdirs.py).
    Returns model identifier -> FMU path."""
    dest = Path(dest)
    dest.mkdir(parents=True, exist_ok=True)
    build_fingerprint = build_fingerprint or fingerprint(models, [*extra_modules, *resource_files])
    record = python_record()
    package = package_name(build_fingerprint)
    paths = {}
    with tempfile.TemporaryDirectory(prefix="emcosim_build_", dir=temp_root) as tmp:
        work = Path(tmp)
        loader = compile_loader(work).read_bytes()
        resources = _bundle(work, package, build_fingerprint, models, extra_modules)
        bundle_files = {f"resources/{f.relative_to(resources).as_posix()}": f.read_bytes()
                        for f in sorted(resources.rglob("*")) if f.is_file() and "__pycache__" not in f.parts}
        # the bundle is imported under a name of its own for the build (its modules import each other
        # relatively) and forgotten after: the build's process keeps no module of the FMUs' names, whose
        # folder would be gone (an FMU instantiated later in this process imports its own copy)
        alias = f"_emcosim_build_{os.getpid()}_{next(_ALIASES)}"
        (work / "import").mkdir()
        (work / "import" / alias).symlink_to(resources / package, target_is_directory=True)
        sys.path.insert(0, str(work / "import"))
        try:
            descriptions = {identifier: _model_description(alias, None if source is None else source.stem, identifier,
                                                           resources)
                            for identifier, source in models.items()}
        finally:
            sys.path.remove(str(work / "import"))
            for name in [m for m in sys.modules if m == alias or m.startswith(alias + ".")]:
                del sys.modules[name]
        for identifier, source in models.items():
            module = None if source is None else source.stem
            script = f"{package}_{identifier}"
            guid, description = descriptions[identifier]
            lines = {**record, "package": package, "script": script, "build": build_fingerprint, "guid": guid}
            files = dict(bundle_files)
            files["modelDescription.xml"] = description
            for extra in resource_files:
                files[f"resources/{extra.name}"] = extra.read_bytes()
            files["resources/slavemodule.txt"] = script.encode()
            files[f"resources/{script}.py"] = _script(package, module, identifier, build_fingerprint).encode()
            files[f"resources/{RECORD}"] = (
                "# emcosim FMU: the Python that runs it in a host without Python (written by build.py, read by\n"
                f"# binaries/linux64/{identifier}.so). {OVERRIDE_VARIABLE}=<a Python {record['python_version'][:4]} "
                "executable whose environment has\n# numpy and scipy> overrides python_executable.\n"
                + "".join(f"{k} = {v}\n" for k, v in lines.items())).encode()
            files[f"binaries/linux64/{identifier}.so"] = loader
            files[f"binaries/linux64/{PYTHONFMU_LIBRARY}"] = _pythonfmu_library().read_bytes()
            paths[identifier] = dest / f"{identifier}.fmu"
            _write_fmu(paths[identifier], files)
    return paths


IDENTIFIER = re.compile(r"[A-Za-z][A-Za-z0-9]*")
BINDING = """{doc}
from fmus.models import device_slave_classes

from . import {stem} as _device_module

globals().update(device_slave_classes(_device_module, [{designs}], __name__, model={model}))
"""


def _binding(source: Path, name: str, designs: Sequence[str], model: str, controllers: str) -> str:
    """The module that binds a device's slave classes (BINDING): only checked names and the sha256 pass into it,
    through components.source_text (issue 40: no file name or text in generated source)."""
    from components.source_text import py_docstring, py_string
    stem = source.stem
    if not (stem.isascii() and stem.isidentifier()) or source.suffix != ".py":
        raise ValueError(f"{source}: a device module's file name must be a Python identifier [A-Za-z_][A-Za-z0-9_]* "
                         "with .py (it is imported by that name)")
    doc = py_docstring(f"Slave classes of the device {name} (generated by fmus.build.build_device): the plant {name} "
                       f"and the controllers {controllers}, bound to the device module {stem} beside this one.")
    return BINDING.format(doc=doc, stem=stem, designs=", ".join(py_string(d) for d in designs), model=py_string(model))


def load_device_module(path: Path):
    """Import a device module (Python source that defines DEVICE) from its file, under a name of its own."""
    import importlib.util

    name = f"_emcosim_device_{os.getpid()}_{next(_ALIASES)}_{path.stem}"
    spec = importlib.util.spec_from_file_location(name, path)
    if spec is None or spec.loader is None:
        raise ValueError(f"{path}: not a Python module")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def build_device(device_module: Path | str, device_name: str | None, designs: Sequence[str] | None,
                 dest: Path | str, description: Path | str | None = None,
                 temp_root: Path | None = None) -> dict[str, Path]:
    """Build the FMUs of a device into `dest`: the plant `<name>.fmu` and one `<name>_<Design>.fmu` per design.

    device_module  Python source that defines DEVICE (a components.device.Device, or a function returning one)
                   or device(designs) (components.codegen's generated modules), optionally INITIAL_STATE and
                   EXPERIMENT (fmus.models.device_slave_classes); it may import numpy, scipy, the standard
                   library and components
    device_name    the name DEVICE must have (the FMUs' identifier stem), or None for any
    designs        the designs to build (each must be one of the device's), or None for all of them
    description    the plant description file, copied into every FMU's resources/ (or None)
    temp_root      the folder the build's temporary folders are made in (None: the system's)

    Each FMU's bundle carries the device module and a generated module that binds the slave classes
    (PlantSlave, ControllerSlave with `device`); no sympy is needed at run time. The plant and the controllers
    declare one device identity (fmus.model_description.DeviceIdentity): the device's name and the sha256 of
    the description file (without one: of the device module). ValueError for a module
    without DEVICE, a name that is not [A-Za-z][A-Za-z0-9]* or not `device_name`, an unknown design.
    Returns model identifier -> FMU path."""
    from .models import device_slave_classes, module_device

    source = Path(device_module).resolve()
    module = load_device_module(source)
    device = module_device(module, designs)
    if not IDENTIFIER.fullmatch(device.name):
        raise ValueError(f"{source}: device name {device.name!r} is not an identifier [A-Za-z][A-Za-z0-9]*")
    if device_name is not None and device.name != device_name:
        raise ValueError(f"{source}: DEVICE is named {device.name!r}, not {device_name!r}")
    chosen = list(device.designs) if designs is None else list(designs)
    classes = device_slave_classes(module, chosen)             # checks designs and the initial state at once
    extras = [Path(description).resolve()] if description is not None else []
    model = hashlib.sha256((extras[0] if extras else source).read_bytes()).hexdigest()
    with tempfile.TemporaryDirectory(prefix="emcosim_device_", dir=temp_root) as tmp:
        binding = Path(tmp) / f"emcosim_device_{device.name}.py"
        binding.write_text(_binding(source, device.name, chosen, model,
                                    ", ".join(c for c in classes if c != device.name) or "none"))
        return build_fmus({identifier: binding for identifier in classes}, dest,
                          extra_modules=[source], resource_files=extras, temp_root=temp_root)


def build_description(description: Path | str, dest: Path | str, designs: Sequence[str] | None = None,
                      temp_root: Path | None = None) -> dict[str, Path]:
    """The FMUs of a plant description file (TOML, issue 25): components.codegen writes its model module
    (`<stem>_model.py`, in a temporary folder), then `build_device` builds the plant and a
    controller per design of `designs` (None: the designs whose Assumptions hold, components.plant_check),
    with the description file in resources/ as DESCRIPTION_RESOURCE (where emcosim.devices.registry finds the
    device of an FMU; temp_root: as build_device's). A DescriptionError (components.description) names a wrong
    entry; nothing is built."""
    from components import codegen, plant_check  # sympy: imported only when a description is built
    from components.description import load

    description = Path(description).resolve()
    desc = load(description)
    if designs is None:
        designs = plant_check.check(desc).designs
    with tempfile.TemporaryDirectory(prefix="emcosim_description_", dir=temp_root) as tmp:
        module = Path(tmp) / f"{desc.name.lower()}_model.py"    # a checked identifier, not the file's name
        module.write_text(codegen.module_source(desc, description.name))
        resource = Path(tmp) / Path(DESCRIPTION_RESOURCE).name
        shutil.copyfile(description, resource)
        return build_device(module, desc.name, designs, dest, description=resource, temp_root=temp_root)


def up_to_date(dest: Path | str | None = None, current: str | None = None) -> bool:
    """True when every FMU in `dest` (default: `default_dest()`) was built from the current sources (stamp
    fingerprint and hashes)."""
    dest = default_dest() if dest is None else Path(dest)
    try:
        stamp = json.loads((dest / STAMP).read_text())
    except (OSError, ValueError):
        return False
    paths = {identifier: dest / f"{identifier}.fmu" for identifier in FMUS}
    return (stamp.get("fingerprint") == (current or fingerprint())
            and all(p.exists() and hashlib.sha256(p.read_bytes()).hexdigest() == stamp.get("fmus", {}).get(i)
                    for i, p in paths.items()))


def build(dest: Path | str | None = None, force: bool = False, verbose: bool = True) -> dict[str, Path]:
    """Build every FMU into `dest` (default: `default_dest()`), skipped when the stamp says the inputs are
    unchanged. Returns model identifier -> FMU path."""
    dest = default_dest() if dest is None else Path(dest)
    dest.mkdir(parents=True, exist_ok=True)
    paths = {identifier: dest / f"{identifier}.fmu" for identifier in FMUS}
    stamp_file = dest / STAMP
    current = fingerprint()
    if not force and up_to_date(dest, current):
        if verbose:
            for identifier, path in paths.items():
                print(f"up to date  {path}")
        return paths
    paths = build_fmus(_models(), dest, current)
    hashes = {identifier: hashlib.sha256(path.read_bytes()).hexdigest() for identifier, path in paths.items()}
    if verbose:
        for identifier, path in paths.items():
            print(f"built       {path}  ({path.stat().st_size / 1024:.0f} kB, sha256 {hashes[identifier][:12]})")
    stamp_file.write_text(json.dumps({"fingerprint": current, "fmus": hashes}, indent=1))
    return paths


# ---- documentation ------------------------------------------------------------------------------
def variables_markdown(paths: dict[str, Path]) -> str:
    """One Markdown table per FMU, from its modelDescription.xml."""
    from fmpy import read_model_description

    parts = []
    for identifier, path in paths.items():
        md = read_model_description(str(path))
        deps = {u.variable.name: u.dependencies for u in md.outputs}
        parts.append(f"### {identifier}\n\n{md.description}\n\n"
                     f"Default experiment: {md.defaultExperiment.startTime} s to {md.defaultExperiment.stopTime} s, "
                     f"step {md.defaultExperiment.stepSize} s.\n")
        parts.append("| name | causality | start | unit | description |\n|---|---|---|---|---|")
        for v in md.modelVariables:
            start = v.start if v.start is not None else ""
            extra = ""
            if v.name in deps:
                extra = " (depends on: " + (", ".join(d.name for d in deps[v.name]) or "nothing") + ")"
            parts.append(f"| {v.name} | {v.causality} | {start} | {_cell(v.unit or '')} | {_cell(v.description)}{extra} |")
        parts.append("")
    return "\n".join(parts)


def _cell(text: str | None) -> str:
    """Text as one Markdown table cell: | escaped, no line breaks."""
    return " ".join(str(text or "").replace("|", "\\|").split())


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m fmus.build", description=__doc__.splitlines()[0])
    parser.add_argument("--dest", help="output folder (default: build/fmus of the checkout, else of the current folder)")
    parser.add_argument("--force", action="store_true", help="rebuild even if the inputs are unchanged")
    args = parser.parse_args(argv)
    try:
        build(args.dest, force=args.force)
    except BuildError as exc:
        print(exc, file=sys.stderr)
        return 2
    return 0


if __name__ == "__main__":
    sys.exit(main())
