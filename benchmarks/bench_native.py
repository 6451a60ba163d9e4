"""Cost per call of the native FMUs against their pythonfmu twins, side by side, from Python and from C.

    python benchmarks/bench_native.py [--native build/native] [--fmus build/fmus] [-n 2000]

Python host: the FMUs' raw ctypes functions (loaded by fmpy's FMU2Slave / FMU2Model) with pre-allocated arrays, in one
process, the two forms taking turns: per communication step set the inputs + doStep + get the outputs (CS,
every FMU at its DefaultExperiment's step), and per right-hand side fmi2SetTime + fmi2SetContinuousStates +
fmi2GetDerivatives (ME, the plants). C host: tests/native/portable_host.c's loop is not timed here; the C
numbers of docs/native-fmus.md come from a host linked with the sources.
Medians of 5 repeats of n calls, in microseconds of this process's CPU time (time.process_time: the machine
is shared, wall time would measure the neighbours); the native figures are mostly ctypes' own cost per call
(about 0.5 us each here).
"""
from __future__ import annotations

import argparse
import ctypes
import statistics
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
if str(ROOT) not in sys.path:
    sys.path.insert(0, str(ROOT))

PLANTS = ("MEMS", "Maglev")
OTHERS = ("MEMS_Proposition1", "MEMS_Theorem2", "Maglev_Proposition2", "Maglev_Theorem3", "Reference")


def _open(path: Path, name: str, me: bool):
    from fmpy import extract, read_model_description
    from fmpy.fmi2 import FMU2Model, FMU2Slave
    md = read_model_description(str(path))
    cls = FMU2Model if me else FMU2Slave
    fmu = cls(guid=md.guid, unzipDirectory=extract(str(path)), modelIdentifier=name, instanceName=name)
    fmu.instantiate()
    fmu.setupExperiment(startTime=0.0)
    fmu.enterInitializationMode()
    fmu.exitInitializationMode()
    if me:
        fmu.newDiscreteStates()
        fmu.enterContinuousTimeMode()
    return fmu, md


def cs_cost(path: Path, name: str, n: int) -> float:
    """set inputs + doStep + get outputs [us], median of 5 repeats."""
    fmu, md = _open(path, name, me=False)
    inputs = [v for v in md.modelVariables if v.causality == "input"]
    outputs = [v for v in md.modelVariables if v.causality == "output"]
    n_in, n_out = len(inputs), len(outputs)
    vin = (ctypes.c_uint * n_in)(*[v.valueReference for v in inputs])
    vout = (ctypes.c_uint * n_out)(*[v.valueReference for v in outputs])
    start = [float(v.start) for v in inputs]
    values = (ctypes.c_double * max(n_in, 1))(*start)
    out = (ctypes.c_double * n_out)()
    h = float(md.defaultExperiment.stepSize)
    comp = ctypes.c_void_p(fmu.component)
    set_real, do_step, get_real = fmu.dll.fmi2SetReal, fmu.dll.fmi2DoStep, fmu.dll.fmi2GetReal   # raw ctypes
    times, t = [], 0.0
    for _ in range(5):
        t0 = time.process_time()
        for k in range(n):
            if n_in:
                values[0] = start[0] * (1.0 + 1e-6 * (k % 3))
                set_real(comp, vin, ctypes.c_size_t(n_in), values)
            do_step(comp, ctypes.c_double(t), ctypes.c_double(h), 1)
            t += h
            get_real(comp, vout, ctypes.c_size_t(n_out), out)
        times.append((time.process_time() - t0) / n * 1e6)
    fmu.terminate()
    fmu.freeInstance()
    return statistics.median(times)


def me_cost(path: Path, name: str, n: int) -> float:
    """fmi2SetTime + fmi2SetContinuousStates + fmi2GetDerivatives [us], median of 5 repeats."""
    fmu, _ = _open(path, name, me=True)
    x = (ctypes.c_double * 3)()
    dx = (ctypes.c_double * 3)()
    fmu.dll.fmi2GetContinuousStates(ctypes.c_void_p(fmu.component), x, ctypes.c_size_t(3))
    base = list(x)
    comp = ctypes.c_void_p(fmu.component)
    set_time, set_states, get_derivatives = fmu.dll.fmi2SetTime, fmu.dll.fmi2SetContinuousStates, fmu.dll.fmi2GetDerivatives
    times = []
    for _ in range(5):
        t0 = time.process_time()
        for k in range(n):
            set_time(comp, ctypes.c_double(k * 1e-9))
            x[0] = base[0] * (1.0 + 1e-9 * (k % 5))
            set_states(comp, x, ctypes.c_size_t(3))
            get_derivatives(comp, dx, ctypes.c_size_t(3))
        times.append((time.process_time() - t0) / n * 1e6)
    fmu.terminate()
    fmu.freeInstance()
    return statistics.median(times)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--native", default=str(ROOT / "build" / "native"), help="the native FMUs (build.py --native)")
    ap.add_argument("--fmus", default=str(ROOT / "build" / "fmus"), help="the pythonfmu FMUs (build.py)")
    ap.add_argument("-n", type=int, default=2000, help="calls per repeat")
    args = ap.parse_args(argv)
    native, twins = Path(args.native), Path(args.fmus)
    print(f"{'FMU, call':44s} {'pythonfmu [us]':>15s} {'native [us]':>12s} {'ratio':>7s}")
    for name in (*PLANTS, *OTHERS):
        if not (native / f"{name}.fmu").is_file():
            print(f"{name}: no native FMU in {native}")
            continue
        rows = [("CS set + doStep + get", cs_cost)]
        if name in PLANTS:
            rows.append(("ME SetTime + SetStates + GetDerivatives", me_cost))
        for label, cost in rows:
            py, c = cost(twins / f"{name}.fmu", name, args.n), cost(native / f"{name}.fmu", name, args.n)
            print(f"{name + ', ' + label:44s} {py:15.2f} {c:12.2f} {c / py:7.3f}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
