"""Subprocess worker of the reliability suite: every FMU call of the suite happens here, never in the
pytest process, so that a crash (segfault, abort) or a hang of an FMU shows up as a failed test.

Protocol: one JSON request per line on stdin, one JSON answer per line on stdout (the last line
starting with RESULT_PREFIX; anything the FMUs print goes to stderr). A request is
{"cmd": name, ...}; see the `cmd_*` functions. Run `python fmu_worker.py` (serve) or
`python fmu_worker.py lifecycle '{"fmu": ..., "n": 1000}'` (one command, then exit).

The FMUs are driven through fmpy's FMU2Slave with raw status handling (no exception ends a case).
"""
from __future__ import annotations

import base64
import json
import math
import os
import resource
import sys
import time
import traceback
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]
if str(ROOT) not in sys.path:
    sys.path.insert(0, str(ROOT))

import numpy as np  # noqa: E402
from fmpy import calloc, extract, free, read_model_description  # noqa: E402
from fmpy.fmi1 import FMICallException  # noqa: E402
from fmpy.fmi2 import (  # noqa: E402
    FMU2Slave,
    fmi2CallbackAllocateMemoryTYPE,
    fmi2CallbackFreeMemoryTYPE,
    fmi2CallbackFunctions,
    fmi2CallbackLoggerTYPE,
    fmi2Integer,
    fmi2Real,
    fmi2ValueReference,
)

RESULT_PREFIX = "@@RESULT "
OK, WARNING, DISCARD, ERROR, FATAL = 0, 1, 2, 3, 4
PAGE = os.sysconf("SC_PAGE_SIZE")


def rss_bytes() -> int:
    """Current resident set size (second field of /proc/self/statm, in pages)."""
    with open("/proc/self/statm") as f:
        return int(f.read().split()[1]) * PAGE


# ---- FMUs -----------------------------------------------------------------------------------------
class Model:
    """An FMU extracted once; instances are created with `new`."""

    cache: dict[str, "Model"] = {}

    def __init__(self, path: str):
        self.path = path
        self.md = read_model_description(path)
        self.unzipdir = extract(path)
        self.vr = {v.name: v.valueReference for v in self.md.modelVariables}
        self.var = {v.name: v for v in self.md.modelVariables}
        self.integer = {v.name for v in self.md.modelVariables if v.type == "Integer"}
        self.outputs = [v.name for v in self.md.modelVariables if v.causality == "output"]
        self.inputs = [v.name for v in self.md.modelVariables if v.causality == "input"]
        self.identifier = self.md.coSimulation.modelIdentifier
        self.library = None            # one FMU2Slave (one loaded library) reused by every instance

    @classmethod
    def get(cls, path: str) -> "Model":
        if path not in cls.cache:
            cls.cache[path] = Model(path)
        return cls.cache[path]

    def new(self, name: str = "instance") -> "Instance":
        return Instance(self, name)


class Instance:
    """One FMU instance with its log captured; every call returns an FMI status, never raises."""

    def __init__(self, model: Model, name: str):
        self.model = model
        self.messages: list[tuple[int, str]] = []
        cb = fmi2CallbackFunctions()
        cb.logger = fmi2CallbackLoggerTYPE(
            lambda env, inst, status, cat, msg: self.messages.append((status, msg.decode("utf-8", "replace"))))
        cb.allocateMemory = fmi2CallbackAllocateMemoryTYPE(calloc)
        cb.freeMemory = fmi2CallbackFreeMemoryTYPE(free)
        self.callbacks = cb
        if model.library is None:
            model.library = FMU2Slave(guid=model.md.guid, unzipDirectory=model.unzipdir,
                                      modelIdentifier=model.identifier, instanceName=name)
        self.fmu = model.library
        self.fmu.instantiate(callbacks=cb, loggingOn=True)
        self.component = self.fmu.component
        self.freed = False

    def call(self, function, *args) -> int:
        self.fmu.component = self.component
        try:
            status = function(*args)
            return OK if status is None else status
        except FMICallException as exc:
            return exc.status

    def init(self, values: dict, start_time: float = 0.0) -> int:
        f = self.fmu
        status = self.call(f.fmi2SetupExperiment, self.component, 0, 0.0, start_time, 0, 0.0)
        if status > WARNING:
            return status
        status = self.call(f.fmi2EnterInitializationMode, self.component)
        if status > WARNING:
            return status
        status = self.set(values)
        if status > WARNING:
            return status
        return self.call(f.fmi2ExitInitializationMode, self.component)

    def set(self, values: dict) -> int:
        worst = OK
        for name, value in values.items():
            vr = (fmi2ValueReference * 1)(self.model.vr[name])
            if name in self.model.integer:
                arr = (fmi2Integer * 1)(int(value))
                worst = max(worst, self.call(self.fmu.fmi2SetInteger, self.component, vr, 1, arr))
            else:
                arr = (fmi2Real * 1)(float(value))
                worst = max(worst, self.call(self.fmu.fmi2SetReal, self.component, vr, 1, arr))
        return worst

    def get(self, names) -> list[float]:
        status, values = self.get_with_status(names)
        if status > WARNING:
            raise RuntimeError(f"fmi2GetReal returned status {status}")
        return values

    def get_with_status(self, names) -> tuple[int, list[float]]:
        """fmi2GetReal's status and the values it wrote (with fmi2Error too: e.g. NaN, named in the log)."""
        n = len(names)
        vr = (fmi2ValueReference * n)(*[self.model.vr[x] for x in names])
        arr = (fmi2Real * n)(*([math.nan] * n))
        status = self.call(self.fmu.fmi2GetReal, self.component, vr, n, arr)
        return status, list(arr)

    def step(self, t: float, h: float) -> int:
        return self.call(self.fmu.fmi2DoStep, self.component, t, h, 1)

    def reset(self) -> int:
        return self.call(self.fmu.fmi2Reset, self.component)

    def get_state(self):
        self.fmu.component = self.component
        return self.fmu.getFMUstate()

    def set_state(self, state) -> int:
        return self.call(self.fmu.fmi2SetFMUstate, self.component, state)

    def free_state(self, state) -> None:
        self.fmu.component = self.component
        self.fmu.freeFMUstate(state)

    def serialize(self, state) -> bytes:
        self.fmu.component = self.component
        return self.fmu.serializeFMUstate(state)

    def deserialize(self, data: bytes):
        self.fmu.component = self.component
        return self.fmu.deSerializeFMUstate(data)

    def errors(self) -> str:
        return "\n".join(m for s, m in self.messages if s >= WARNING)

    def free(self) -> None:
        if not self.freed:
            self.call(self.fmu.fmi2Terminate, self.component)
            self.fmu.component = self.component
            self.fmu.fmi2FreeInstance(self.component)
            self.freed = True


# ---- commands -------------------------------------------------------------------------------------
def cmd_lifecycle(req: dict) -> dict:
    """n x (instantiate, initialize, 3 steps, terminate, free) of one FMU; RSS sampled every `every`."""
    model = Model.get(req["fmu"])
    n, h, every = int(req["n"]), float(req["h"]), int(req.get("every", 10))
    values = req.get("values", {})
    inputs = req.get("inputs", {})
    warmup = int(req.get("warmup", 20))
    samples = []
    outputs_first = None
    tic = time.perf_counter()
    rss0 = None
    for i in range(warmup + n):
        if i == warmup:
            rss0 = rss_bytes()
            tic = time.perf_counter()
        inst = model.new(f"life{i}")
        status = inst.init(values)
        if status != OK:
            return {"ok": False, "reason": f"init status {status} at iteration {i}: {inst.errors()}"}
        for k in range(3):
            inst.set(inputs)
            status = inst.step(k * h, h)
            if status != OK:
                return {"ok": False, "reason": f"doStep status {status} at iteration {i}: {inst.errors()}"}
        out = inst.get(model.outputs)
        if outputs_first is None:
            outputs_first = out
        elif out != outputs_first:
            return {"ok": False, "reason": f"iteration {i} gave {out}, the first gave {outputs_first}"}
        inst.free()
        if i >= warmup and (i - warmup) % every == 0:
            samples.append((i - warmup, rss_bytes()))
    elapsed = time.perf_counter() - tic
    rss1 = rss_bytes()
    samples.append((n, rss1))
    return {"ok": True, "n": n, "rss_before": rss0, "rss_after": rss1, "growth": rss1 - rss0,
            "maxrss_kb": resource.getrusage(resource.RUSAGE_SELF).ru_maxrss, "seconds": elapsed,
            "samples": samples, "outputs": outputs_first}


def run_sequence(inst: Instance, model: Model, h: float, steps: list[dict], t0: float = 0.0) -> list:
    """Set inputs, step, read every output, for each entry of `steps`; [(status, outputs)]."""
    out = []
    for k, inputs in enumerate(steps):
        inst.set(inputs)
        status = inst.step(t0 + k * h, h)
        out.append((status, inst.get(model.outputs)))
        if status > WARNING:
            break
    return out


def cmd_reset(req: dict) -> dict:
    """A run on a fresh instance, then fmi2Reset and the same run on the same instance."""
    model = Model.get(req["fmu"])
    h, steps, values = float(req["h"]), req["steps"], req.get("values", {})
    fresh = model.new("fresh")
    s_fresh = fresh.init(values)
    a = run_sequence(fresh, model, h, steps)
    fresh.free()
    inst = model.new("reused")
    other = req.get("first_values", {})
    inst.init(other)
    run_sequence(inst, model, h, req.get("first_steps", steps))
    status_reset = inst.reset()
    s_again = inst.init(values)
    b = run_sequence(inst, model, h, steps)
    errors = inst.errors()
    inst.free()
    return {"fresh": [s_fresh, a], "reset_status": status_reset, "after_reset": [s_again, b], "errors": errors}


def cmd_rollback(req: dict) -> dict:
    """Straight run vs. a run with FMU-state saves and restores at the positions of `ops`.

    ops: list of ["step"] | ["save"] | ["restore", j] (j-th saved state, modulo) | ["serial", j]
    (restore the j-th saved state through serialize/deserialize) | ["free", j]. After every step
    the outputs are compared with the straight run at the same step index."""
    model = Model.get(req["fmu"])
    h, steps, values = float(req["h"]), req["steps"], req.get("values", {})
    straight_inst = model.new("straight")
    straight_inst.init(values)
    straight = run_sequence(straight_inst, model, h, steps)
    straight_inst.free()
    if any(s != OK for s, _ in straight):
        return {"ok": False, "reason": f"straight run failed: {straight_inst.errors()}"}
    inst = model.new("rolled")
    inst.init(values)
    saved: list = []           # (step index, state or None if freed)
    k = 0
    counts = {"step": 0, "save": 0, "restore": 0, "serial": 0, "free": 0, "compared": 0}
    for op in req["ops"]:
        kind = op[0]
        if kind == "step":
            if k >= len(steps):
                continue
            inst.set(steps[k])
            status = inst.step(k * h, h)
            out = inst.get(model.outputs)
            counts["step"] += 1
            if status != OK or out != straight[k][1]:
                return {"ok": False, "reason": f"step {k} after {counts}: status {status}, outputs {out} "
                                               f"!= straight {straight[k][1]}", "errors": inst.errors()}
            counts["compared"] += 1
            k += 1
        elif kind == "save":
            saved.append([k, inst.get_state()])
            counts["save"] += 1
        elif kind in ("restore", "serial") and saved:
            live = [s for s in saved if s[1] is not None]
            if not live:
                continue
            k_saved, state = live[op[1] % len(live)]
            if kind == "serial":
                data = inst.serialize(state)
                state2 = inst.deserialize(data)
                status = inst.set_state(state2)
                inst.free_state(state2)
            else:
                status = inst.set_state(state)
            if status != OK:
                return {"ok": False, "reason": f"setFMUstate status {status}", "errors": inst.errors()}
            k = k_saved
            counts[kind] += 1
            # outputs right after the restore equal the straight run's at that point
            expect = straight[k - 1][1] if k > 0 else None
            if expect is not None:
                out = inst.get(model.outputs)
                if out != expect:
                    return {"ok": False, "reason": f"after {kind} to step {k}: {out} != {expect}"}
                counts["compared"] += 1
        elif kind == "free" and saved:
            live = [s for s in saved if s[1] is not None]
            if live:
                s = live[op[1] % len(live)]
                inst.free_state(s[1])
                s[1] = None
                counts["free"] += 1
    for s in saved:
        if s[1] is not None:
            inst.free_state(s[1])
    errors = inst.errors()
    inst.free()
    return {"ok": errors == "", "reason": errors, "counts": counts}


def cmd_case(req: dict) -> dict:
    """One fuzzed case: initialize with `values`, then steps with `steps` (inputs per step) and step
    size h. Returns the statuses, the outputs before and after each step, and the log."""
    model = Model.get(req["fmu"])
    inst = model.new("fuzz")
    values, h, t0 = req["values"], req["h"], req.get("t0", 0.0)
    status = inst.init(values, t0)
    result = {"init": status, "outputs0": None, "steps": []}
    energy = req.get("energy")
    names = model.outputs
    if status <= WARNING:
        result["outputs0_status"], values = inst.get_with_status(names)
        result["outputs0"] = dict(zip(names, values))
        before = result["outputs0"]
        for k, inputs in enumerate(req["steps"]):
            set_status = inst.set(inputs)
            mid_status, values = inst.get_with_status(names)   # after setting (a controller's u is computed here)
            mid = dict(zip(names, values))
            status = inst.step(t0 + k * h, h)
            after_status, values = inst.get_with_status(names)
            after = dict(zip(names, values))
            entry = {"set": set_status, "mid": mid, "mid_status": mid_status, "status": status, "after": after,
                     "after_status": after_status}
            if energy is not None and status <= WARNING:
                entry["energy"] = energy_reference(energy["plant"], energy["params"],
                                                   [before["q"], before["p"], before["x_e"]], inputs["u"], h)
            result["steps"].append(entry)
            before = after
            if status > WARNING:
                break
    result["errors"] = inst.errors()
    inst.free()
    return result


class ReferenceUnavailable(Exception):
    pass


def energy_reference(identifier: str, params: dict, eta0, u: float, h: float, rtol: float = 1e-8,
                     max_evaluations: int = 20000) -> dict:
    """Independent integration (scipy Radau, analytic Jacobian) of the plant over one step with the
    input u held, augmented with the energy flows: the dissipated energy int (R_m (p/m)^2 +
    R_e (Psi x_e)^2) dt and the supplied energy int y u dt with the passive output y = G_e Psi(q) x_e
    (grad_xe H = Psi x_e). The right-hand side is written here from the pH form (n_m = n_e = 1,
    constant mass, J_e = 0) with components' V', V'', Psi, Psi', Psi''; it is checked against
    components' f at the start. Time is scaled to [0, 1], states by components' nominal scale.
    {"ok": False, "reason": ...} when the reference itself cannot integrate (extreme parameters)."""
    try:
        return _energy_reference(identifier, params, eta0, u, h, rtol, max_evaluations)
    except (ReferenceUnavailable, ValueError, ArithmeticError, np.linalg.LinAlgError) as exc:
        return {"ok": False, "reason": f"{type(exc).__name__}: {exc}"}


def _energy_reference(identifier, params, eta0, u, h, rtol, max_evaluations):
    from scipy.integrate import solve_ivp

    from components import catalog
    from components.plant_step import nominal_scale

    plant = catalog.plant(identifier, params)
    scale = np.asarray(nominal_scale(plant), float)
    m_inv = float(plant.M_inv(np.zeros(1))[0, 0])
    R_m, R_e, G_e = float(plant.R_m[0, 0]), float(plant.R_e[0, 0]), float(plant.G_e[0, 0])
    dV, d2V = plant.dV, plant.d2V
    Psi, dPsi, d2Psi = plant.psi, plant.dpsi, plant.d2psi
    u = float(u)
    eta0 = [float(v) for v in eta0]
    H0 = float(plant.H(np.array(eta0)))

    def flows(q, p, x):
        y = G_e * Psi(q) * x
        return R_m * (m_inv * p) ** 2, R_e * (Psi(q) * x) ** 2, y * u

    def f(q, p, x):
        return (m_inv * p, -(dV(q) + 0.5 * x * x * dPsi(q)) - R_m * m_inv * p, -R_e * Psi(q) * x + G_e * u)

    with np.errstate(all="ignore"):
        check = np.array(f(*eta0))
        d0 = flows(*eta0)
    expected = plant.f(np.array(eta0), np.array([u]))
    q, p, x = eta0
    terms = np.array([abs(m_inv * p), abs(dV(q)) + abs(0.5 * x * x * dPsi(q)) + abs(R_m * m_inv * p),
                      abs(R_e * Psi(q) * x) + abs(G_e * u)])
    if not np.all(np.abs(check - expected) <= 1e-12 * terms):
        return {"ok": False, "reason": f"reference right-hand side {check} != components' f {expected}"}
    Es = (abs(d0[0]) + abs(d0[1]) + abs(d0[2])) * h + abs(H0) + 1e-300
    calls = [0]

    def rhs(t, y):
        calls[0] += 1
        if calls[0] > max_evaluations:
            raise ReferenceUnavailable(f"more than {max_evaluations} evaluations")
        q, p, x = y[0] * scale[0], y[1] * scale[1], y[2] * scale[2]
        fq, fp, fx = f(q, p, x)
        dm, de, s = flows(q, p, x)
        return [h * fq / scale[0], h * fp / scale[1], h * fx / scale[2],
                h * dm / Es, h * de / Es, h * s / Es, h * abs(s) / Es]

    def jac(t, y):
        q, p, x = y[0] * scale[0], y[1] * scale[1], y[2] * scale[2]
        P, dP, d2P = Psi(q), dPsi(q), d2Psi(q)
        J = np.zeros((7, 7))
        J[0, 1] = m_inv
        J[1, 0], J[1, 1], J[1, 2] = -(d2V(q) + 0.5 * x * x * d2P), -R_m * m_inv, -x * dP
        J[2, 0], J[2, 2] = -R_e * dP * x, -R_e * P
        J[:3, :3] *= h * scale[None, :] / scale[:, None]
        s = G_e * P * x * u
        rows = np.array([[0.0, 2 * R_m * m_inv ** 2 * p, 0.0],
                         [2 * R_e * P * x * x * dP, 0.0, 2 * R_e * P * P * x],
                         [G_e * dP * x * u, 0.0, G_e * P * u]])
        J[3:6, :3] = rows * scale[None, :] * h / Es
        J[6, :3] = math.copysign(1.0, s) * J[5, :3]
        return J

    if not all(math.isfinite(v) for v in list(check) + list(d0) + [Es]):
        return {"ok": False, "reason": f"non-finite right-hand side {check} or flows {d0} at the start"}
    try:
        with np.errstate(all="ignore"):
            sol = solve_ivp(rhs, (0.0, 1.0), [eta0[0] / scale[0], eta0[1] / scale[1], eta0[2] / scale[2], 0, 0, 0, 0],
                            method="Radau", rtol=rtol, atol=rtol, jac=jac)
    except (ReferenceUnavailable, ValueError, ArithmeticError, np.linalg.LinAlgError) as exc:
        return {"ok": False, "reason": f"{type(exc).__name__}: {exc}"}
    if not sol.success:
        return {"ok": False, "reason": sol.message}
    y = sol.y[:, -1].copy()
    y[3:] *= Es
    eta1 = y[:3] * scale
    return {"ok": True, "H0": H0, "H1_ref": float(plant.H(eta1)), "eta1_ref": list(eta1),
            "dissipated": float(y[3] + y[4]), "supplied": float(y[5]), "supplied_abs": float(y[6]),
            "evaluations": calls[0]}


def cmd_energy(req: dict) -> dict:
    return energy_reference(req["plant"], req["params"], req["eta0"], req["u"], req["h"])


def cmd_calls(req: dict) -> dict:
    """Raw FMI calls, in order, on instances of the FMUs `fmus` (key -> path), statuses never raising.

    calls: ["inst", key] (a new instance, the current one from now on) | ["use", i] | ["init", {values}] |
    ["setr" | "seti", name or value reference, value] | ["getr" | "geti", name or value reference] |
    ["step", t, h] | ["term"] | ["reset"] | ["free"] (fmi2FreeInstance, also a second time) |
    ["sget", slot] | ["sset", slot] | ["sfree", slot] | ["ser", slot] (into the byte buffer) |
    ["deser", slot] (from the byte buffer) | ["bytes", b"..."] | ["flip", i] | ["cut", n] |
    ["sbogus"] (fmi2SetFMUstate with a pointer no FMU gave out) | ["nullstep"] (fmi2DoStep on NULL).
    Returns [[call, status, value]] and the current instance's log messages per call."""
    import ctypes

    models = {key: Model.get(path) for key, path in req["fmus"].items()}
    instances: list[Instance] = []
    inst = None
    states: dict = {}
    buffer = b""
    bogus = ctypes.create_string_buffer(b"Z" * 64)
    out = []

    def vr_of(x):
        return x if isinstance(x, int) else inst.model.vr[x]

    for call in req["calls"]:
        name, args = call[0], call[1:]
        status, value = None, None
        if inst is not None:
            inst.messages.clear()
        if name == "inst":
            model = models[args[0]]
            try:
                inst = model.new(f"calls{len(instances)}")
                instances.append(inst)
                status = OK
            except Exception:                                             # noqa: BLE001 - NULL from fmi2Instantiate
                status = None
        elif name == "use":
            inst = instances[args[0]]
            continue
        elif name == "init":
            status = inst.init(args[0] if args else {})
        elif name in ("setr", "seti"):
            vr = (fmi2ValueReference * 1)(vr_of(args[0]))
            arr = (fmi2Real if name == "setr" else fmi2Integer) * 1
            function = inst.fmu.fmi2SetReal if name == "setr" else inst.fmu.fmi2SetInteger
            status = inst.call(function, inst.component, vr, 1, arr(args[1]))
        elif name in ("getr", "geti"):
            vr = (fmi2ValueReference * 1)(vr_of(args[0]))
            arr = ((fmi2Real if name == "getr" else fmi2Integer) * 1)()
            function = inst.fmu.fmi2GetReal if name == "getr" else inst.fmu.fmi2GetInteger
            status = inst.call(function, inst.component, vr, 1, arr)
            value = arr[0]
        elif name == "step":
            status = inst.step(args[0], args[1])
        elif name == "term":
            status = inst.call(inst.fmu.fmi2Terminate, inst.component)
        elif name == "reset":
            status = inst.reset()
        elif name == "free":
            inst.fmu.fmi2FreeInstance(inst.component)
            inst.freed = True
        elif name == "sget":
            state = ctypes.c_void_p()
            status = inst.call(inst.fmu.fmi2GetFMUstate, inst.component, ctypes.byref(state))
            states[args[0]] = state
        elif name == "sset":
            status = inst.call(inst.fmu.fmi2SetFMUstate, inst.component, states[args[0]])
        elif name == "sbogus":
            status = inst.call(inst.fmu.fmi2SetFMUstate, inst.component, ctypes.c_void_p(ctypes.addressof(bogus)))
        elif name == "sfree":
            status = inst.call(inst.fmu.fmi2FreeFMUstate, inst.component, ctypes.byref(states[args[0]]))
        elif name == "ser":
            size = ctypes.c_size_t()
            status = inst.call(inst.fmu.fmi2SerializedFMUstateSize, inst.component, states[args[0]], ctypes.byref(size))
            if status <= WARNING:
                data = ctypes.create_string_buffer(size.value)
                status = inst.call(inst.fmu.fmi2SerializeFMUstate, inst.component, states[args[0]], data, size)
                buffer = data.raw
            value = len(buffer)
        elif name == "deser":
            state = ctypes.c_void_p()
            data = ctypes.create_string_buffer(buffer, len(buffer))
            status = inst.call(inst.fmu.fmi2DeSerializeFMUstate, inst.component, data, len(buffer), ctypes.byref(state))
            states[args[0]] = state
        elif name == "bytes":
            buffer = args[0]
            continue
        elif name == "flip":
            buffer = buffer[:args[0]] + bytes([buffer[args[0]] ^ 0xFF]) + buffer[args[0] + 1:]
            continue
        elif name == "cut":
            buffer = buffer[:args[0]]
            continue
        elif name == "nullstep":
            status = inst.call(inst.fmu.fmi2DoStep, None, 0.0, 1e-6, 1)
        else:
            raise ValueError(f"unknown call {name}")
        out.append([name, status, value, [m for m in (inst.messages if inst else [])]])
    for inst in instances:
        if not inst.freed:
            inst.free()
    return {"calls": out}


def cmd_crash(req: dict) -> dict:
    """Self-test of the harness: die like a crashing FMU would."""
    import ctypes
    if req.get("how") == "hang":
        time.sleep(3600)
    ctypes.string_at(0)
    return {}


def cmd_ping(req: dict) -> dict:
    return {"pid": os.getpid(), "rss": rss_bytes()}


COMMANDS = {name[4:]: f for name, f in globals().items() if name.startswith("cmd_")}


def _encode(obj):
    if isinstance(obj, float) and not math.isfinite(obj):
        return {"__float__": repr(obj)}
    if isinstance(obj, bytes):
        return {"__bytes__": base64.b64encode(obj).decode()}
    if isinstance(obj, dict):
        return {k: _encode(v) for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return [_encode(v) for v in obj]
    return obj


def _decode(obj):
    if isinstance(obj, dict):
        if "__float__" in obj:
            return float(obj["__float__"])
        if "__bytes__" in obj:
            return base64.b64decode(obj["__bytes__"])
        return {k: _decode(v) for k, v in obj.items()}
    if isinstance(obj, list):
        return [_decode(v) for v in obj]
    return obj


def dumps(obj) -> str:
    return json.dumps(_encode(obj), allow_nan=False)


def loads(text: str):
    return _decode(json.loads(text))


def handle(req: dict) -> dict:
    try:
        return {"answer": COMMANDS[req["cmd"]](req)}
    except Exception:                                                   # noqa: BLE001 - a harness error, reported
        return {"harness_error": traceback.format_exc()}


def main() -> None:
    out = sys.stdout
    sys.stdout = sys.stderr                       # the FMUs' prints must not corrupt the protocol
    if len(sys.argv) > 1:
        req = loads(sys.argv[2]) if len(sys.argv) > 2 else {}
        req["cmd"] = sys.argv[1]
        out.write(RESULT_PREFIX + dumps(handle(req)) + "\n")
        out.flush()
        return
    for line in sys.stdin:
        if not line.strip():
            continue
        out.write(RESULT_PREFIX + dumps(handle(loads(line))) + "\n")
        out.flush()


if __name__ == "__main__":
    main()
