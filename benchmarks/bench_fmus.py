"""Median cost of one communication step per FMU, beside the same computation calling components/.

    python benchmarks/bench_fmus.py [--fmus build/fmus] [-n 2000]

Per FMU, at the communication step h of the paper's MEMS examples (1e-6 s) or, for the maglev (the
paper gives none), its default experiment's step (1e-3 s):
  plant       doStep alone, and setReal(u) + doStep + getReal(q, p, x_e), versus PlantStepper.advance;
  controller  setReal(inputs) + doStep + getReal(u), versus controller.u_scalar(q, p, x_e, jet);
  reference   doStep + getReal(jet), versus reference.jet(t).
Python host: FMI calls go straight to the FMU's ctypes functions with pre-allocated arrays;
"fmpy" is the same through FMU2Slave's Python methods. Inputs vary from step to step like in a loop.
C host: the same loop in tests/fixtures/c_host.c (compiled on the spot with gcc) started with an empty
environment, i.e. what Simulink, OpenModelica or libcosim pay: no ctypes on the caller's side; the FMU's
loader starts Python.
The floor, measured in the same run in both hosts: the same FMI calls on a trivial slave (a static gain
with no work of its own): "floor" is tests/fixtures/emcosim_toy_floor.py built like the FMUs (the same
loader, pythonfmu library and interpreter), "raw pythonfmu" is tests/fixtures/emcosim_toy_gain.py built
by pythonfmu's own builder (C host: run the old way, libpython preloaded and PYTHONHOME/PYTHONPATH set).
Each FMU's figure is printed beside the floor; the controllers' target (issue 13): set + doStep + get
within 1.5 times the floor in the C host. C-host figures are medians over --repeats processes per FMU,
the FMUs and the floor taking turns.
Native FMUs (--native, default build/native when it holds them; `python build.py --native`): the same
C-host loop takes them in the same rotation, and a last table puts each native FMU beside its pythonfmu
twin, per communication step (CS: set + doStep + get) and per Model Exchange round trip (the plants),
from Python (benchmarks/bench_native.py's raw-ctypes loops, CPU time) and from C (c_host.c; ME:
tests/fixtures/c_me_host.c's 10000 fmi2SetContinuousStates + fmi2GetDerivatives), all under `env -i`.
"""
from __future__ import annotations

import argparse
import ctypes
import math
import os
import statistics
import subprocess
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from fmpy import extract, read_model_description  # noqa: E402
from fmpy.fmi2 import FMU2Slave  # noqa: E402

from components import maglev, mems, references  # noqa: E402
from components.plant_step import PlantStepper  # noqa: E402
from components.proposition1 import Proposition1  # noqa: E402
from components.proposition2 import Proposition2  # noqa: E402
from components.theorem2 import Theorem2  # noqa: E402
from components.theorem3 import Theorem3  # noqa: E402
from emcosim.engine.fmi import raw as raw_function  # noqa: E402

H = {"MEMS": 1e-6, "Maglev": 1e-3}             # maglev: 1e-3 s, its default experiment's step
JET = ["q_star", "q_star_dot", "q_star_ddot", "q_star_dddot"]


def median_us(samples: list[int]) -> float:
    return statistics.median(samples) / 1000.0


class Raw:
    """An initialized FMU with raw ctypes access."""

    def __init__(self, path: Path):
        self.md = read_model_description(str(path))
        self.fmu = FMU2Slave(guid=self.md.guid, unzipDirectory=extract(str(path)),
                             modelIdentifier=self.md.coSimulation.modelIdentifier, instanceName="bench")
        self.fmu.instantiate()
        self.fmu.setupExperiment(startTime=0.0)
        self.fmu.enterInitializationMode()
        self.fmu.exitInitializationMode()
        self.vr = {v.name: v.valueReference for v in self.md.modelVariables}
        self.start = {v.name: float(v.start) for v in self.md.modelVariables if v.start is not None}
        self.c = self.fmu.component
        self.do_step, self.set_real, self.get_real = (raw_function(self.fmu, name) for name in ("fmi2DoStep", "fmi2SetReal",
                                                                                       "fmi2GetReal"))

    def refs(self, names):
        return (ctypes.c_uint * len(names))(*(self.vr[n] for n in names)), (ctypes.c_double * len(names))()

    def free(self):
        self.fmu.terminate()
        self.fmu.freeInstance()


def bench_plant(path: Path, identifier: str, n: int) -> list[tuple[str, float, float]]:
    """FMU and components calls alternate, so both see the same machine load."""
    h = H[identifier]
    raw = Raw(path)
    state = raw.fmu.getFMUstate()
    u0 = raw.start["u"] if identifier == "MEMS" else 0.009045            # maglev: near its equilibrium voltage
    inputs = [float(u) for u in u0 * (1.0 + 0.01 * np.sin(np.arange(n) * 0.1))]
    vu, bu = raw.refs(["u"])
    vy, by = raw.refs(["q", "p", "x_e"])
    plant = mems.MEMS() if identifier == "MEMS" else maglev.Maglev()
    rows = []
    for label in ("doStep", "set + doStep + get", "via fmpy FMU2Slave"):
        raw.fmu.setFMUstate(state)                       # the open-loop maglev is unstable: restart each run
        stepper = PlantStepper(plant)
        eta = tuple(raw.start[f"{x}_0"] for x in ("q", "p", "x_e"))
        fmu_ns, direct_ns = [], []
        for k, u in enumerate(inputs):
            t0 = time.perf_counter_ns()
            if label == "doStep":
                bu[0] = u
                raw.set_real(raw.c, vu, 1, bu)
                t0 = time.perf_counter_ns()
                status = raw.do_step(raw.c, k * h, h, 1)
            elif label == "set + doStep + get":
                bu[0] = u
                raw.set_real(raw.c, vu, 1, bu)
                status = raw.do_step(raw.c, k * h, h, 1)
                raw.get_real(raw.c, vy, 3, by)
            else:
                raw.fmu.setReal([raw.vr["u"]], [u])
                status = raw.fmu.fmi2DoStep(raw.c, k * h, h, 1)
                raw.fmu.getReal([raw.vr["q"], raw.vr["p"], raw.vr["x_e"]])
            fmu_ns.append(time.perf_counter_ns() - t0)
            assert status == 0, status
            t0 = time.perf_counter_ns()
            eta = stepper.advance(*eta, u, h)
            direct_ns.append(time.perf_counter_ns() - t0)
        name = f"{identifier} {label}" + (f" (h = {h:g} s)" if label == "doStep" else "")
        rows.append((name, median_us(fmu_ns), median_us(direct_ns)))
    raw.fmu.freeFMUstate(state)
    raw.free()
    return rows


CONTROLLERS = {
    "MEMS_Proposition1": lambda: Proposition1(mems.MEMS(), 3e-5, mems.R_e_bar_from_rbar_e(100.0), 0.0),
    "MEMS_Theorem2": lambda: Theorem2(mems.MEMS(), mems.R_e_bar_from_rbar_e(100.0), 0.0),
    "Maglev_Proposition2": lambda: Proposition2(maglev.Maglev(), 0.0025, 2.82, 20.0, 0.0),
    "Maglev_Theorem3": lambda: Theorem3(maglev.Maglev(), 2.82, 20.0, 0.0),
}


def bench_controller(path: Path, identifier: str, n: int) -> list[tuple[str, float, float]]:
    h = H["MEMS" if identifier.startswith("MEMS") else "Maglev"]
    raw = Raw(path)
    names = [v.name for v in raw.md.modelVariables if v.causality == "input"]
    start = np.array([raw.start[x] for x in names])
    start[1] = start[1] or 1e-12                         # vary every input, also those starting at 0
    start[2] = start[2] or (4e-11 if identifier.startswith("MEMS") else 1.0)
    values = [start * (1.0 + 0.01 * np.sin(k * 0.1 + np.arange(len(names)))) for k in range(n)]
    vin, bin_ = raw.refs(names)
    vout, bout = raw.refs(["u"])
    vrs = [raw.vr[x] for x in names]
    controller = CONTROLLERS[identifier]()
    rows = []
    steps = 0                   # the FMU's time goes on across both loops (doStep from another time is refused)
    for label in ("set + doStep + get", "via fmpy FMU2Slave"):
        fmu_ns, direct_ns = [], []
        for x in values:
            t0 = time.perf_counter_ns()
            if label == "set + doStep + get":
                for i, xi in enumerate(x):
                    bin_[i] = xi
                raw.set_real(raw.c, vin, len(names), bin_)
                raw.do_step(raw.c, steps * h, h, 1)
                raw.get_real(raw.c, vout, 1, bout)
                u = bout[0]
            else:
                raw.fmu.setReal(vrs, list(x))
                raw.fmu.fmi2DoStep(raw.c, steps * h, h, 1)
                u = raw.fmu.getReal([raw.vr["u"]])[0]
            fmu_ns.append(time.perf_counter_ns() - t0)
            steps += 1
            t0 = time.perf_counter_ns()
            jet = tuple(float(xi) for xi in x[3:]) if len(x) > 3 else None       # what the FMU computes
            direct = float(controller.u_scalar(float(x[0]), float(x[1]), float(x[2]), jet))
            direct_ns.append(time.perf_counter_ns() - t0)
            assert u == direct, (u, direct)
        rows.append((f"{identifier} {label}", median_us(fmu_ns), median_us(direct_ns)))
    raw.free()
    return rows


def bench_reference(path: Path, n: int) -> list[tuple[str, float, float]]:
    h = 1e-3
    raw = Raw(path)
    vout, bout = raw.refs(JET)
    reference = references.Sinusoid()
    fmu_ns, direct_ns = [], []
    t = 0.0
    for k in range(n):
        t0 = time.perf_counter_ns()
        raw.do_step(raw.c, t, h, 1)
        raw.get_real(raw.c, vout, 4, bout)
        fmu_ns.append(time.perf_counter_ns() - t0)
        t = t + h
        t0 = time.perf_counter_ns()
        reference.jet(t)
        direct_ns.append(time.perf_counter_ns() - t0)
    raw.free()
    return [("Reference doStep + get", median_us(fmu_ns), median_us(direct_ns))]


def floor_fmus(folder: Path) -> dict[str, Path]:
    """The two floor FMUs, built into `folder`: "floor" (loader, as the FMUs) and "raw pythonfmu"."""
    from pythonfmu import FmuBuilder

    from fmus import build

    fixtures = ROOT / "tests" / "fixtures"
    floor = build.build_fmus({"FloorGain": fixtures / "emcosim_toy_floor.py"}, folder / "floor")["FloorGain"]
    raw = Path(FmuBuilder.build_FMU(fixtures / "emcosim_toy_gain.py", dest=folder / "raw"))
    return {"floor": floor, "raw pythonfmu": raw}


def bench_floor(floors: dict[str, Path], n: int) -> list[tuple[str, float, float]]:
    """The floor in the Python host: a trivial slave (y = k x), doStep alone and set + doStep + get."""
    rows = []
    for label, fmu in floors.items():
        raw = Raw(fmu)
        vx, bx = raw.refs(["x"])
        vy, by = raw.refs(["y"])
        step_ns, loop_ns = [], []
        for k in range(n):                                     # warm-up (the first run of the process)
            raw.set_real(raw.c, vx, 1, bx)
            raw.do_step(raw.c, k * 1e-3, 1e-3, 1)
            raw.get_real(raw.c, vy, 1, by)
        for k in range(n, 2 * n):
            t0 = time.perf_counter_ns()
            raw.do_step(raw.c, k * 1e-3, 1e-3, 1)
            step_ns.append(time.perf_counter_ns() - t0)
            bx[0] = float(k)
            t0 = time.perf_counter_ns()
            raw.set_real(raw.c, vx, 1, bx)
            raw.do_step(raw.c, k * 1e-3, 1e-3, 1)
            raw.get_real(raw.c, vy, 1, by)
            loop_ns.append(time.perf_counter_ns() - t0)
        raw.free()
        rows += [(f"{label}: doStep (trivial slave)", median_us(step_ns), math.nan),
                 (f"{label}: set + doStep + get", median_us(loop_ns), math.nan)]
    return rows


def bench_c_host(folder: Path, floors: dict[str, Path], n: int, repeats: int, native: Path | None = None
                 ) -> list[tuple[str, float, float, float]] | str:
    """Each FMU in the C host of tests/fixtures/c_host.c under `env -i` (no Python on the caller's side: what
    Simulink, OpenModelica or libcosim pay), each process right after one of the floor, so that the floor is
    sampled all through the run (the machine's load changes from second to second): (name, median us of
    set + doStep + get, median us of doStep alone, that median over the median of all the floor's runs),
    over `repeats` runs per FMU; or why the host cannot be built here. With `native`, the native FMUs of that
    folder take their turns too, named "native <identifier>".
    The raw pythonfmu floor runs the old way (libpython preloaded, PYTHONHOME/PYTHONPATH)."""
    import sysconfig
    import tempfile

    from tests.c_host import CONTROLLER_INPUTS, compile_c_host, run_in_c_host

    cases = {name: (path, {"x": 1.0}, ["y"], 1e-3) for name, path in floors.items()}
    cases["MEMS"] = (folder / "MEMS.fmu", {"u": 25.0}, ["q", "p", "x_e"], H["MEMS"])
    cases["Maglev"] = (folder / "Maglev.fmu", {"u": 0.009045}, ["q", "p", "x_e"], H["Maglev"])
    cases.update({i: (folder / f"{i}.fmu", x, ["u"], H["MEMS" if i.startswith("MEMS") else "Maglev"])
                  for i, x in CONTROLLER_INPUTS.items()})
    cases["Reference"] = (folder / "Reference.fmu", {}, JET, 1e-3)
    if native is not None:
        cases.update({f"native {name}": (native / case[0].name, *case[1:]) for name, case in list(cases.items())
                      if name not in floors})
    libpython = Path(sysconfig.get_config_var("LIBDIR")) / sysconfig.get_config_var("INSTSONAME")
    raw_env = {"LD_PRELOAD": str(libpython), "PYTHONHOME": sys.base_prefix,
               "PYTHONPATH": sysconfig.get_paths()["purelib"]}
    samples: dict[str, list[tuple[float, float]]] = {name: [] for name in cases}
    with tempfile.TemporaryDirectory() as tmp:
        exe = Path(tmp) / "c_host"
        reason = compile_c_host(exe)
        if reason:
            return reason

        def measure(name: str) -> tuple[float, float]:
            fmu, inputs, outputs, h = cases[name]
            steps = min(n, 500) if name.endswith("Maglev") else n      # open loop: the ball reaches the magnet at 2 s
            workdir = Path(tmp) / ("native" if name.startswith("native ") else "pythonfmu")   # unzipped by identifier
            run, values = run_in_c_host(exe, fmu, workdir, inputs, outputs, h, steps,
                                        env=raw_env if name == "raw pythonfmu" else None)
            if run.returncode != 0:
                raise RuntimeError(f"{name} in the C host: exit status {run.returncode}: {run.stderr[-500:]}")
            return values[0] / 1000.0, values[1] / 1000.0

        for _ in range(repeats):
            for name in cases:
                samples["floor"].append(measure("floor"))
                if name != "floor":
                    samples[name].append(measure(name))
    floor = statistics.median(s[0] for s in samples["floor"])
    return [(name, statistics.median(s[0] for s in v), statistics.median(s[1] for s in v),
             statistics.median(s[0] for s in v) / floor) for name, v in samples.items()]


def me_c_host(folders: dict[str, Path], repeats: int) -> dict[tuple[str, str], float] | str:
    """The plants as Model Exchange in tests/fixtures/c_me_host.c under `env -i`: median over `repeats`
    processes of its mean cost [us] of one fmi2SetContinuousStates + fmi2GetDerivatives round trip (10000 at
    the state reached), per (form, plant), the forms taking turns; or why the host cannot be built here."""
    import tempfile

    from tests.c_host import compile_c_host, extract

    samples: dict[tuple[str, str], list[float]] = {(form, p): [] for form in folders for p in H}
    with tempfile.TemporaryDirectory() as tmp:
        exe = Path(tmp) / "c_me_host"
        reason = compile_c_host(exe, ROOT / "tests" / "fixtures" / "c_me_host.c")
        if reason:
            return reason
        for _ in range(repeats):
            for (form, plant), values in samples.items():
                fmu = folders[form] / f"{plant}.fmu"
                unzipped, vr = extract(fmu, Path(tmp) / form)
                md = read_model_description(str(fmu))
                h, steps = (1e-11, 100) if plant == "MEMS" else (1e-4, 100)
                args = [str(unzipped / "binaries" / "linux64" / f"{plant}.so"), plant, (unzipped / "resources").as_uri(),
                        md.guid, repr(h), str(steps), "3", str(md.numberOfEventIndicators), str(vr["u"]),
                        "25.0" if plant == "MEMS" else "0.009045"]
                run = subprocess.run(["env", "-i", str(exe), *args], capture_output=True, text=True, timeout=300)
                if run.returncode != 0:
                    raise RuntimeError(f"{form} {plant} in the ME C host: exit status {run.returncode}: "
                                       f"{run.stderr[-500:]}")
                values.append(float(run.stdout.split()[0]) / 1000.0)
    return {key: statistics.median(v) for key, v in samples.items()}


def side_by_side(twins: Path, native: Path, c_rows: list[tuple[str, float, float, float]] | str, n: int,
                 repeats: int) -> list[tuple[str, float, float, float, float]]:
    """Per FMU and call, (name, Python host pythonfmu, Python host native, C host pythonfmu, C host native) in
    us: Python from benchmarks/bench_native.py (raw ctypes, CPU time), C from `c_rows` (bench_c_host with the
    native FMUs) and me_c_host; nan where not measured."""
    from benchmarks.bench_native import OTHERS, PLANTS, cs_cost, me_cost

    c_loop = {} if isinstance(c_rows, str) else {name: loop for name, loop, _, _ in c_rows}
    me_c = me_c_host({"pythonfmu": twins, "native": native}, repeats)
    rows = []
    for name in (*PLANTS, *OTHERS):
        rows.append((f"{name} CS set + doStep + get", cs_cost(twins / f"{name}.fmu", name, n),
                     cs_cost(native / f"{name}.fmu", name, n), c_loop.get(name, math.nan),
                     c_loop.get(f"native {name}", math.nan)))
        if name in PLANTS:
            c = (math.nan, math.nan) if isinstance(me_c, str) else (me_c[("pythonfmu", name)], me_c[("native", name)])
            rows.append((f"{name} ME round trip", me_cost(twins / f"{name}.fmu", name, n),
                         me_cost(native / f"{name}.fmu", name, n), *c))
    return rows


def machine_speed_us() -> float:
    """Median time of a fixed pure-Python workload, sum(range(1000)), measured in this run: the
    figures above scale with it from day to day on a shared machine."""
    samples = []
    for _ in range(200):
        t0 = time.perf_counter_ns()
        sum(range(1000))
        samples.append(time.perf_counter_ns() - t0)
    return median_us(samples)


def main(argv: list[str] | None = None) -> int:
    import tempfile

    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--fmus", default=str(ROOT / "build" / "fmus"), help="folder with the built FMUs")
    parser.add_argument("-n", type=int, default=2000, help="communication steps per measurement")
    parser.add_argument("--repeats", type=int, default=5, help="C host: processes per FMU (median)")
    parser.add_argument("--native", default=str(ROOT / "build" / "native"),
                        help="folder with the native FMUs (build.py --native); skipped when it does not hold all seven")
    args = parser.parse_args(argv)
    folder = Path(args.fmus)
    native: Path | None = Path(args.native)
    if not all((native / f"{name}.fmu").is_file() for name in (*H, *CONTROLLERS, "Reference")):
        print(f"no native FMUs in {native} (python build.py --native): the native column is left out")
        native = None
    load = os.getloadavg()
    from fmus import build
    build.build(folder, verbose=False)                       # a no-op when the FMUs are up to date
    speed = machine_speed_us()
    with tempfile.TemporaryDirectory() as tmp:
        floors = floor_fmus(Path(tmp))
        rows = bench_floor(floors, args.n)
        for identifier in ("MEMS", "Maglev"):
            rows += bench_plant(folder / f"{identifier}.fmu", identifier, args.n)
        for identifier in CONTROLLERS:
            rows += bench_controller(folder / f"{identifier}.fmu", identifier, args.n)
        rows += bench_reference(folder / "Reference.fmu", args.n)
        c_rows = bench_c_host(folder, floors, args.n, args.repeats, native)
    both = side_by_side(folder, native, c_rows, args.n, args.repeats) if native is not None else []
    floor_step, floor_loop = rows[0][1], rows[1][1]
    print(f"{'Python host, median per communication step':42s} {'FMU [us]':>9s} {'components [us]':>16s} "
          f"{'FMU/comp.':>9s} {'FMU/floor':>9s}")
    for name, fmu_us, direct_us in rows:
        floor = floor_step if "doStep (h" in name or name.endswith("(trivial slave)") else floor_loop
        print(f"{name:42s} {fmu_us:9.1f} {direct_us:16.1f} {fmu_us / direct_us:9.2f} {fmu_us / floor:9.2f}")
    print("floor: the same FMI calls on a trivial slave behind the same loader, measured in this run (FMU/floor = 1 "
          "means the slave's own work costs nothing)")
    print(f"machine speed in this run: sum(range(1000)) takes {speed:.1f} us; load average (1, 5, 15 min) "
          f"{load[0]:.2f} {load[1]:.2f} {load[2]:.2f} at the start, {' '.join(f'{x:.2f}' for x in os.getloadavg())} "
          f"at the end, on {os.cpu_count()} cores")
    print()
    if both:
        print_side_by_side(both)
        print()
    if isinstance(c_rows, str):
        print(f"C host: not measured ({c_rows})")
        return 0
    python_host = {name.split()[0]: fmu_us for name, fmu_us, _ in rows if "set + doStep + get" in name or
                   name == "Reference doStep + get"}
    print(f"{'C host (tests/fixtures/c_host.c, env -i)':42s} {'set+doStep+get [us]':>20s} {'doStep [us]':>12s} "
          f"{'/ floor':>8s} {'Python host / C host':>21s}")
    for name, loop_us, step_us, ratio in c_rows:
        python = python_host.get(name) if name not in ("floor", "raw pythonfmu") else None
        versus = f"{python / loop_us:21.2f}" if python else f"{'':21s}"
        print(f"{name:42s} {loop_us:20.1f} {step_us:12.1f} {ratio:8.2f} {versus}")
    print("/ floor: the FMU's median over the median of the floor's runs, which take turns with the FMUs' runs")
    print("C host: inputs set (all of them), doStep, outputs read (plants: q, p, x_e; controllers: u; reference: "
          "its jet); floor: a trivial slave behind the same loader; raw pythonfmu: the same slave as pythonfmu "
          "builds it, libpython preloaded")
    return 0


def print_side_by_side(rows: list[tuple[str, float, float, float, float]]) -> None:
    print(f"{'native beside pythonfmu, per step / round trip':44s} {'Python: pythonfmu':>17s} {'native':>8s} "
          f"{'ratio':>7s} {'C: pythonfmu':>12s} {'native':>8s} {'ratio':>7s}")
    for name, py_twin, py_native, c_twin, c_native in rows:
        print(f"{name:44s} {py_twin:17.2f} {py_native:8.2f} {py_native / py_twin:7.3f} {c_twin:12.2f} "
              f"{c_native:8.3f} {c_native / c_twin:7.3f}")
    print("[us]; Python: benchmarks/bench_native.py (raw ctypes, CPU time, median of 5 x n; ME: fmi2SetTime + "
          "fmi2SetContinuousStates + fmi2GetDerivatives); C: tests/fixtures/c_host.c (median of the repeats; wall "
          "time) and, ME, c_me_host.c's fmi2SetContinuousStates + fmi2GetDerivatives; both under env -i")


if __name__ == "__main__":
    sys.exit(main())
