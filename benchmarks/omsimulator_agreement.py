"""Run every .ssp archive of a folder in OMSimulator as Co-Simulation and measure how far its results are
from emcosim's own master on the same archive (docs/ssp-engines.md, "OMSimulator").

    python benchmarks/omsimulator_agreement.py OMSIMULATOR ARCHIVES [--input-extrapolation]
        [--tolerance TOL | --lua] [--match COUPLING] [--json FILE] [--only NAME ...]

e.g. `python benchmarks/omsimulator_agreement.py /work/tools/OMSimulator/install/bin/OMSimulator build/ssp`.

Each archive runs in its own scratch directory (OMSimulator unpacks into the current directory) with an
empty environment (`env -i`), `--stopTime=T` (the archive's stopTime: OMSimulator's command line default
of 1 s would replace it) and a .mat result file (every digit). Without `--tolerance` OMSimulator uses its
default (1e-4), which replaces the archive's tolerance; `--lua` imports the archive in a Lua script
instead, so the archive's own `relativeTolerance` is what the FMUs get in fmi2SetupExperiment.

emcosim runs the same archive (`emcosim.engine.master.simulate`) with each coupling of COUPLINGS below.
The quantity, per state (plant q, p, x_e and controller u): max over the common time points of
|OMSimulator - emcosim| divided by the state's range (max - min over the emcosim run). OMSimulator
writes every communication point twice (before and after it updates the inputs): the last row at each
time is taken, matched to emcosim's rows by nearest time (a time further than 1e-6 h away is reported,
not matched). The table shows, per archive, the exit status, whether the rows reach the stop time,
the error and warning lines of OMSimulator's log, both wall times, the four states against `--match`
(default: order0 without, implicit with --input-extrapolation) and the largest of the four against
every other coupling. Nothing is skipped silently: a run without a result file, or with no rows, is a
row of the table saying so. Needs no network; OMSimulator is not needed to import this file.
"""
from __future__ import annotations

import argparse
import json
import re
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
if str(ROOT) not in sys.path:
    sys.path.insert(0, str(ROOT))

STATES = ("plant.q", "plant.p", "plant.x_e", "controller.u")   # the paper's archives; others: states_of


def states_of(scenario) -> tuple[str, ...]:
    """What is compared: the plant's outputs but H (its states, by their names: a device's z, theta, ...) and
    the controller's outputs (u, or u_1, u_2, ...); the paper's STATES for the paper's archives."""
    by_name = {c.name: c for c in scenario.components}
    out = [f"{name}.{k.name}" for name in ("plant", "controller") if name in by_name
           for k in by_name[name].connectors if k.kind == "output" and k.name != "H"]
    return tuple(out) or STATES
# emcosim's couplings compared: name -> keyword arguments of master.simulate
COUPLINGS: dict[str, dict[str, Any]] = {
    "default": {},
    "order0": {"coupling_order": 0},
    "order1": {"coupling_order": 1},
    "order2": {"coupling_order": 2},
    "implicit": {"coupling": "implicit"},
}
LUA = """oms_setCommandLineOption("--suppressPath=true")
{extrapolation}local model = oms_importFile("{archive}")
oms_setResultFile(model, "{result}")
oms_setStopTime(model, {stop!r})
oms_instantiate(model)
oms_initialize(model)
oms_simulate(model)
oms_terminate(model)
oms_delete(model)
"""


def read_oms_mat(path: Path) -> dict[str, np.ndarray]:
    """OMSimulator's result file (Dymola's binTrans format, read with scipy.io.loadmat): name -> values."""
    import scipy.io

    m = scipy.io.loadmat(str(path), chars_as_strings=False)
    name, info = m["name"], m["dataInfo"]
    if name.shape[0] != info.shape[1]:
        name = name.T
    names = ["".join(row).rstrip("\x00 ") for row in name]
    if info.shape[0] != 4:
        info = info.T
    out: dict[str, np.ndarray] = {}
    for j, n in enumerate(names):
        which, col = int(info[0, j]), int(info[1, j])
        data = m["data_1"] if which == 1 else m["data_2"]
        out[n] = np.sign(col) * data[abs(col) - 1]
    return out


def _column(result: dict[str, np.ndarray], name: str) -> np.ndarray | None:
    """The column `MODEL.SYSTEM.name` (OMSimulator prefixes the model's and the root System's names)."""
    for key, values in result.items():
        if key.split(".", 2)[-1] == name and key.count(".") == name.count(".") + 2:
            return values
    return None


def run_omsimulator(binary: Path, archive: Path, stop_time: float, *, tolerance: float | None,
                    extrapolation: bool, lua: bool, keep: Path | None = None,
                    timeout: float | None = None) -> dict[str, Any]:
    """One OMSimulator run of `archive` in a scratch directory: exit status, log, wall time, result."""
    work = Path(tempfile.mkdtemp(prefix=f"oms-{archive.stem}-", dir="/tmp"))
    result = work / "result.mat"
    if lua:
        if tolerance is not None:
            raise ValueError("--lua keeps the archive's tolerance: give no --tolerance with it")
        ext = 'oms_setCommandLineOption("--inputExtrapolation=true")\n' if extrapolation else ""
        script = work / "run.lua"
        script.write_text(LUA.format(extrapolation=ext, archive=archive.resolve(), result=result, stop=stop_time))
        cmd = [str(binary), str(script)]
    else:
        cmd = [str(binary), f"--stopTime={stop_time!r}", f"--resultFile={result}"]
        if tolerance is not None:
            cmd.append(f"--tolerance={tolerance!r}")
        if extrapolation:
            cmd.append("--inputExtrapolation=true")
        cmd.append(str(archive.resolve()))
    t0 = time.perf_counter()
    try:
        proc = subprocess.run(cmd, cwd=work, env={}, capture_output=True, text=True, timeout=timeout)
        rc: int | str = proc.returncode
        log = proc.stdout + proc.stderr
    except subprocess.TimeoutExpired as exc:      # killed: reported in the table, not skipped
        rc = f"killed after {timeout:g} s"
        log = "".join(x.decode(errors="replace") if isinstance(x, bytes) else (x or "") for x in (exc.stdout, exc.stderr))
    wall = time.perf_counter() - t0
    lines = log.splitlines()
    run: dict[str, Any] = {
        "cmd": " ".join(["env", "-i", *cmd]), "rc": rc, "wall": wall,
        "errors": [x for x in lines if re.match(r"\s*error\b", x, re.I)],
        "warnings": [x for x in lines if re.match(r"\s*warning\b", x, re.I)],
        "result": read_oms_mat(result) if result.is_file() and isinstance(rc, int) else None,
    }
    if keep is not None:
        keep.mkdir(parents=True, exist_ok=True)
        (keep / f"{archive.stem}.log").write_text(run["cmd"] + "\n" + log)
        if result.is_file():
            shutil.copy(result, keep / f"{archive.stem}.mat")
    shutil.rmtree(work, ignore_errors=True)
    return run


def run_emcosim(archive: Path, couplings: list[str]) -> tuple[Any, dict[str, tuple[np.ndarray, dict, float]],
                                                           dict[str, str]]:
    """emcosim's master on the archive, once per coupling: (time, {state: values}, wall time), and the
    couplings whose run failed (with the error; such a run is compared over the rows it made)."""
    from emcosim.engine.errors import SimulationError
    from emcosim.engine.master import simulate
    from emcosim.engine.ssd import read_scenario

    scenario = read_scenario(archive)
    states = states_of(scenario)
    runs, failed = {}, {}
    for name in couplings:
        t0 = time.perf_counter()
        try:
            r = simulate(scenario, record=list(states), **COUPLINGS[name])
        except SimulationError as exc:
            failed[name] = str(exc).splitlines()[0][:200]
            r = exc.result
        wall = time.perf_counter() - t0
        if r is None or r.n_rows == 0:
            runs[name] = (np.zeros(0), {s: np.zeros(0) for s in states}, wall)
        else:
            runs[name] = (np.asarray(r.time), {s: np.asarray(r[s]) for s in states}, wall)
    return scenario, runs, failed


def distances(oms: dict[str, np.ndarray], em_time: np.ndarray, em: dict[str, np.ndarray],
              step: float) -> tuple[dict[str, float], int, float]:
    """Per state: max |oms - em| / range(em) over emcosim's time points that OMSimulator's rows reach
    (the last OMSimulator row at each time, the nearest one). Also the number of points compared and
    the largest time mismatch."""
    t = np.asarray(oms["time"], dtype=float)
    last = np.r_[t[1:] != t[:-1], True]              # the last row of each time written twice
    t_last = t[last]
    idx_all = np.flatnonzero(last)
    use = em_time <= t_last[-1] + 1e-6 * step
    te = em_time[use]
    k = np.clip(np.searchsorted(t_last, te), 1, len(t_last) - 1) if len(t_last) > 1 else np.zeros(len(te), int)
    if len(t_last) > 1:
        k = np.where(np.abs(t_last[k - 1] - te) <= np.abs(t_last[k] - te), k - 1, k)
    dt = float(np.max(np.abs(t_last[k] - te))) if len(te) else float("nan")
    out = {}
    for s in em:
        col = _column(oms, s)
        if col is None:
            out[s] = float("nan")
            continue
        x = np.asarray(col, dtype=float)[idx_all[k]]
        ref = em[s][use]
        span = float(np.max(em[s]) - np.min(em[s])) or float(np.max(np.abs(em[s]))) or 1.0
        out[s] = float(np.max(np.abs(x - ref)) / span) if len(ref) else float("nan")
    return out, int(len(te)), dt


def measure(binary: Path, archive: Path, args: argparse.Namespace) -> dict[str, Any]:
    couplings = args.couplings
    scenario, em, failed = run_emcosim(archive, couplings)
    T = float(scenario.stop_time)
    h = float(scenario.step_size)
    oms = run_omsimulator(binary, archive, T, tolerance=args.tolerance, extrapolation=args.input_extrapolation,
                          lua=args.lua, keep=args.keep, timeout=args.oms_timeout)
    row: dict[str, Any] = {"name": archive.stem, "T": T, "h": h, "cmd": oms["cmd"], "rc": oms["rc"],
                           "oms_wall": oms["wall"], "errors": len(oms["errors"]), "warnings": len(oms["warnings"]),
                           "first_messages": (oms["errors"] + oms["warnings"])[:3],
                           "em_wall": {c: em[c][2] for c in couplings}, "em_failed": failed}
    res = oms["result"]
    if res is None or len(res.get("time", [])) == 0:
        row["problem"] = "no result file" if res is None else "no rows"
        row["to_stop"] = False
        return row
    t = np.asarray(res["time"], dtype=float)
    row["rows"] = int(len(t))
    row["t_end"] = float(t[-1])
    row["to_stop"] = bool(abs(t[-1] - T) <= 1e-6 * h)
    dup = np.flatnonzero(t[1:] == t[:-1])
    u = _column(res, "controller.u")
    row["u_differs_in_duplicate_rows"] = float(np.max(np.abs(u[dup + 1] - u[dup]))) if u is not None and len(dup) else 0.0
    row["vs"] = {}
    row["states"] = list(states_of(scenario))
    row["points"], row["dt"] = 0, 0.0
    for c in couplings:
        if len(em[c][0]) == 0:
            row["vs"][c] = {s: float("nan") for s in row["states"]}
            continue
        d, n, dt = distances(res, em[c][0], em[c][1], h)
        row["vs"][c] = d
        row["points"], row["dt"] = n, dt
    if row["dt"] > 1e-6 * h:
        row["problem"] = f"time points differ by up to {row['dt']:g} s (more than 1e-6 h)"
    return row


def table(rows: list[dict[str, Any]], match: str, couplings: list[str]) -> str:
    others = [c for c in couplings if c != match]
    states = list(dict.fromkeys(s for r in rows for s in r.get("states", STATES)))   # every archive's, in order
    head = (["archive", "T [s]", "rc", "rows to T", "errors/warnings", "OMSimulator [s]", f"emcosim {match} [s]"]
            + [f"{s} vs {match}" for s in states] + [f"max vs {c}" for c in others])
    lines = ["| " + " | ".join(head) + " |", "|" + "---|" * len(head)]
    for r in rows:
        cells = [r["name"], f"{r['T']:g}", str(r["rc"]), "yes" if r["to_stop"] else f"no ({r.get('t_end', '-')})",
                 f"{r['errors']}/{r['warnings']}", f"{r['oms_wall']:.2f}", f"{r['em_wall'][match]:.2f}"]
        if "vs" in r:
            cells += [f"{r['vs'][match][s]:.1e}" if s in r["vs"][match] else "" for s in states]
            cells += [f"{max(r['vs'][c].values()):.1e}" for c in others]
        else:
            cells += [r["problem"]] + [""] * (len(head) - len(cells) - 1)
        lines.append("| " + " | ".join(cells) + " |")
    notes = [f"{r['name']}: {r['problem']}" for r in rows if "problem" in r and "vs" in r]
    notes += [f"{r['name']}: emcosim {c} failed: {e}" for r in rows for c, e in r["em_failed"].items()]
    notes += [f"{r['name']}: {m}" for r in rows for m in r["first_messages"]]
    return "\n".join(lines + ([""] + notes if notes else []))


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("omsimulator", type=Path, help="the OMSimulator executable")
    p.add_argument("archives", type=Path, help="a folder of .ssp archives (or one .ssp)")
    p.add_argument("--input-extrapolation", action="store_true", help="pass --inputExtrapolation=true")
    p.add_argument("--tolerance", type=float, default=None,
                   help="pass --tolerance=TOL (default: none, i.e. OMSimulator's 1e-4 replaces the archive's)")
    p.add_argument("--lua", action="store_true",
                   help="import the archive in a Lua script (no --tolerance: the archive's relativeTolerance applies)")
    p.add_argument("--match", choices=list(COUPLINGS), default=None,
                   help="the emcosim coupling shown per state (default: order0, implicit with --input-extrapolation)")
    p.add_argument("--couplings", default=",".join(COUPLINGS),
                   help=f"emcosim couplings to compare, comma-separated (default: all of {', '.join(COUPLINGS)})")
    p.add_argument("--oms-timeout", type=float, default=None, metavar="S",
                   help="kill an OMSimulator run after S seconds (reported as such; default: no limit)")
    p.add_argument("--only", nargs="*", default=None, help="archive names (without .ssp) to run")
    p.add_argument("--json", type=Path, default=None, help="also write every number to this file")
    p.add_argument("--keep", type=Path, default=None, help="keep OMSimulator's logs and .mat results in this folder")
    args = p.parse_args(argv)
    if args.lua and args.tolerance is not None:
        p.error("--lua keeps the archive's tolerance: give no --tolerance with it")
    if not args.omsimulator.is_file():
        p.error(f"{args.omsimulator}: no such file (OMSimulator's executable)")
    archives = sorted(args.archives.glob("*.ssp")) if args.archives.is_dir() else [args.archives]
    if args.only is not None:
        archives = [a for a in archives if a.stem in args.only]
    if not archives:
        p.error(f"{args.archives}: no .ssp archive")
    match = args.match or ("implicit" if args.input_extrapolation else "order0")
    args.couplings = [c.strip() for c in args.couplings.split(",") if c.strip()]
    unknown = [c for c in args.couplings if c not in COUPLINGS]
    if unknown or match not in args.couplings:
        p.error(f"--couplings: {', '.join(unknown) or match + ' (the --match) missing'}; known: {', '.join(COUPLINGS)}")
    rows = []
    for archive in archives:
        row = measure(args.omsimulator, archive, args)
        rows.append(row)
        print(json.dumps({k: v for k, v in row.items() if k != "first_messages"}), file=sys.stderr, flush=True)
    print(f"OMSimulator: {args.omsimulator}; input extrapolation {'on' if args.input_extrapolation else 'off'}; "
          f"tolerance {'archive (Lua import)' if args.lua else args.tolerance or 'default (1e-4)'}")
    print(table(rows, match, args.couplings))
    if args.json:
        args.json.write_text(json.dumps(rows, indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())
