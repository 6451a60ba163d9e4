"""A minimal C host for the FMUs (tests/fixtures/c_host.c): compile it, run an FMU in it.
Used by tests/test_c_host.py and benchmarks/bench_fmus.py."""
from __future__ import annotations

import math
import shutil
import subprocess
import zipfile
from pathlib import Path

from fmpy import read_model_description

SOURCE = Path(__file__).parent / "fixtures" / "c_host.c"
LOOP_SOURCE = Path(__file__).parent / "fixtures" / "c_loop.c"
CALLS_SOURCE = Path(__file__).parent / "fixtures" / "c_calls.c"
THREADS_SOURCE = Path(__file__).parent / "fixtures" / "c_threads.c"
GUARD_SOURCE = Path(__file__).parent / "fixtures" / "c_guard.c"
# AddressSanitizer and UndefinedBehaviorSanitizer (gcc's libasan and libubsan: Debian's gcc 12 has them)
SANITIZE = ["-fsanitize=address,undefined", "-fno-omit-frame-pointer", "-g"]
TOYS = Path(__file__).parent / "fixtures" / "emcosim_toy_derivatives.py"
_TOYS: dict[str, Path] = {}


def toy_fmus(folder: Path) -> dict[str, Path]:
    """The FMUs of tests/fixtures/emcosim_toy_derivatives.py (known derivatives), built once per test
    session with fmus.build.build_fmus into `folder` (the first caller's)."""
    if not _TOYS:
        from fmus.build import build_fmus
        _TOYS.update(build_fmus({"DerivativeIntegrator": TOYS, "DerivativeGain": TOYS}, folder))
    return dict(_TOYS)


def compile_c_host(exe: Path, source: Path = SOURCE, sanitize: bool = False) -> str | None:
    """Compile the C host (or another C master of tests/fixtures) to `exe`: plain C, linked with libdl and
    libm only (no libpython: the FMU's loader starts Python itself); with `sanitize`, under `SANITIZE`. None,
    or why it cannot be built here."""
    if shutil.which("gcc") is None:
        return "needs gcc"
    import fmpy

    flags = SANITIZE + ["-O1"] if sanitize else ["-O2"]
    run = subprocess.run(["gcc", *flags, "-Wall", "-Wextra", "-Werror", "-I", str(Path(fmpy.__file__).parent / "c-code"),
                          str(source), "-o", str(exe), "-ldl", "-lm", "-lpthread"], capture_output=True, text=True)
    if run.returncode != 0 and sanitize:
        return f"gcc cannot build with {' '.join(SANITIZE)} here: {run.stderr[-500:]}"
    run.check_returncode()
    return None


def compile_test_loader(so: Path, flags: list[str], cc: str = "gcc") -> str | None:
    """The FMU loader (fmus/emcosim_fmu_loader.c) compiled to `so` as fmus/build.py compiles it (compile_loader:
    -Wall -Wextra -Werror, the SONAME), with `flags` (e.g. SANITIZE, -std=c99) and the compiler `cc`; None, or
    why it cannot be built here (no such compiler; a warning or error: its text)."""
    import sysconfig

    import fmpy

    from fmus.build import LOADER, LOADER_SONAME

    if shutil.which(cc) is None:
        return f"needs {cc}"
    gcc_only = ["-Wno-format-truncation"] if cc == "gcc" else []       # build.py's: messages are cut on purpose
    run = subprocess.run([cc, "-std=gnu11", *flags, "-fPIC", "-shared", "-fvisibility=hidden", "-Wall", "-Wextra",
                          *gcc_only, "-Werror", f'-DLOADER_SONAME="{LOADER_SONAME}"', f"-Wl,-soname,{LOADER_SONAME}",
                          "-I", str(Path(fmpy.__file__).parent / "c-code"), "-I", sysconfig.get_paths()["include"],
                          str(LOADER), "-o", str(so), "-ldl"], capture_output=True, text=True)
    if run.returncode != 0:
        return f"the loader does not compile with {cc} {' '.join(flags)}: {run.stderr[-1500:]}"
    return None


def run_in_c_host(exe: Path, fmu: Path, workdir: Path, inputs: dict[str, float], outputs: list[str], h: float,
                  n: int, unload: bool = False, env: dict[str, str] | None = None
                  ) -> tuple[subprocess.CompletedProcess, list[float]]:
    """Run the C host on an FMU (extracted into `workdir`); returns the process and the values it printed:
    median ns of set + doStep + get, median ns of doStep alone, then the outputs of the last step."""
    identifier, folder, vr = _extracted(fmu, workdir)
    args = [str(exe), str(folder / "binaries" / "linux64" / f"{identifier}.so"), identifier,
            (folder / "resources").as_uri(), repr(h), str(n), str(len(inputs)), *(str(vr[k]) for k in inputs),
            str(len(outputs)), *(str(vr[k]) for k in outputs), *(repr(v) for v in inputs.values())]
    guid = read_model_description(str(folder / "modelDescription.xml")).guid
    return _run(args, unload, {"C_HOST_GUID": guid, **(env or {})})


def _run(args: list[str], unload: bool = False, env: dict[str, str] | None = None
         ) -> tuple[subprocess.CompletedProcess, list[float]]:
    """Run a C master with an empty environment (`env -i`: no PYTHONHOME, PYTHONPATH or preload; the FMUs
    find their Python themselves), plus `env`; the values it printed (empty if it failed)."""
    env = dict(env or {})
    if unload:
        env["C_HOST_UNLOAD"] = "1"
    command = ["env", "-i", *(f"{k}={v}" for k, v in env.items()), *args]
    run = subprocess.run(command, capture_output=True, text=True, timeout=300)
    return run, ([float(x) for x in run.stdout.split()] if run.returncode == 0 else [])


def _extracted(fmu: Path, workdir: Path) -> tuple[str, Path, dict[str, int]]:
    md = read_model_description(str(fmu))
    identifier = md.coSimulation.modelIdentifier
    folder = workdir / identifier
    if not folder.exists():
        with zipfile.ZipFile(fmu) as z:
            z.extractall(folder)
    return identifier, folder, {v.name: v.valueReference for v in md.modelVariables}


def run_loop_in_c_host(exe: Path, plant_fmu: Path, controller_fmu: Path, workdir: Path, h: float,
                       n: int) -> tuple[subprocess.CompletedProcess, list[float]]:
    """Plant and controller in closed loop in the C master of tests/fixtures/c_loop.c; returns the
    process and (q, p, x_e) at t = n h and the last u."""
    args = [str(exe)]
    vrs = []
    for fmu in (plant_fmu, controller_fmu):
        identifier, folder, vr = _extracted(fmu, workdir)
        args += [str(folder / "binaries" / "linux64" / f"{identifier}.so"), identifier, (folder / "resources").as_uri()]
        vrs.append(vr)
    args += ([repr(h), str(n)] + [str(vrs[0][k]) for k in ("u", "q", "p", "x_e")]
             + [str(vrs[1][k]) for k in ("q", "p", "x_e", "u")])
    return _run(args)


def run_calls(exe: Path, folder: Path, calls: list[str], env: dict[str, str] | None = None
              ) -> tuple[subprocess.CompletedProcess, list[list[str]]]:
    """Run the C host of tests/fixtures/c_calls.c on an extracted FMU (`folder`, see `extract`) with an
    empty environment plus `env`; returns the process and its output lines split into words."""
    md = read_model_description(str(folder / "modelDescription.xml"))
    identifier = md.coSimulation.modelIdentifier
    args = [str(exe), str(folder / "binaries" / "linux64" / f"{identifier}.so"), identifier,
            (folder / "resources").as_uri(), md.guid, *calls]
    env = dict(env or {})
    run = subprocess.run(["env", "-i", *(f"{k}={v}" for k, v in env.items()), *args], capture_output=True,
                         text=True, timeout=300)
    return run, [line.split() for line in run.stdout.splitlines()]


def extract(fmu: Path, workdir: Path) -> tuple[Path, dict[str, int]]:
    """Unzip an FMU into workdir/<model identifier>; (folder, variable name -> value reference)."""
    _, folder, vr = _extracted(fmu, workdir)
    return folder, vr


def last_inputs(start: dict[str, float], n: int) -> list[float]:
    """The inputs c_host.c sets at its last step of the first pass."""
    return [x * (1.0 + 0.01 * math.sin(0.1 * (n - 1) + i)) for i, x in enumerate(start.values())]


CONTROLLER_INPUTS = {
    "MEMS_Proposition1": {"q": 1.5e-5, "p": 1e-12, "x_e": 4e-11},
    "MEMS_Theorem2": {"q": 1.5e-5, "p": 1e-12, "x_e": 4e-11, "q_star": 3e-5, "q_star_dot": 1e-3,
                      "q_star_ddot": -0.3, "q_star_dddot": 10.0},
    "Maglev_Proposition2": {"q": 0.002, "p": 1e-3, "x_e": 0.9},
    "Maglev_Theorem3": {"q": 0.002, "p": 1e-3, "x_e": 0.9, "q_star": 0.0025, "q_star_dot": 0.01,
                        "q_star_ddot": -0.3, "q_star_dddot": 2.0},
}


def threads_command(exe: Path, folders: list[Path], outputs: list[str], rounds: int) -> list[str]:
    """The command line of the C host of tests/fixtures/c_threads.c (two FMUs instantiated at once from two
    threads, `rounds` times) for two extracted FMUs (`extract`) and the output read from each, under an
    empty environment."""
    args = ["env", "-i", str(exe), str(rounds)]
    for folder, output in zip(folders, outputs):
        md = read_model_description(str(folder / "modelDescription.xml"))
        identifier = md.coSimulation.modelIdentifier
        vr = {v.name: v.valueReference for v in md.modelVariables}
        args += [str(folder / "binaries" / "linux64" / f"{identifier}.so"), identifier, (folder / "resources").as_uri(),
                 md.guid, str(vr[output])]
    return args


def run_guard(exe: Path, folder: Path, mode: str, env: dict[str, str] | None = None
              ) -> tuple[subprocess.CompletedProcess, list[list[str]]]:
    """Run the C host of tests/fixtures/c_guard.c in `mode` (guard, illegal, oob) on an extracted FMU
    (`extract`) with an empty environment plus `env`: its counts (states, event indicators, Real and Integer
    variables), a Real output and a Real input come from the FMU's modelDescription.xml. The process and
    its output lines split into words."""
    md = read_model_description(str(folder / "modelDescription.xml"))
    identifier = md.coSimulation.modelIdentifier
    reals = [v for v in md.modelVariables if v.type == "Real"]
    integers = [v for v in md.modelVariables if v.type == "Integer"]
    output = next(v for v in reals if v.causality == "output")
    inputs = [v for v in reals if v.causality == "input"] or [v for v in reals if v.causality == "parameter"]
    args = [str(exe), str(folder / "binaries" / "linux64" / f"{identifier}.so"), identifier,
            (folder / "resources").as_uri(), md.guid, mode, str(len(md.derivatives)),
            str(md.numberOfEventIndicators or 0), str(len(reals)), str(len(integers)), str(output.valueReference),
            str(inputs[0].valueReference)]
    run = subprocess.run(["env", "-i", *(f"{k}={v}" for k, v in (env or {}).items()), *args], capture_output=True,
                         text=True, timeout=300)
    return run, [line.split() for line in run.stdout.splitlines()]
