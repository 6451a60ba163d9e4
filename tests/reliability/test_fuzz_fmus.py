"""Fuzzed inputs: hypothesis draws parameter values, step sizes and input sequences for every FMU
(zeros, negatives, huge and tiny magnitudes, NaN, inf, and ordinary values). Every FMU call runs in
the worker subprocess. Each case must end in

- a correct result: every step returns fmi2OK with outputs that pass a physical sanity check: for a
  plant, a finite state inside the domain, H equal to components' H of that state and the energy
  balance H(t+h) - H(t) = int (-p^2 R_m/m^2 - x_e Psi R_e Psi x_e + y u) dt over each step (y = G_e Psi
  x_e, the passive output; the integral from an independent Radau integration in the worker);
  for a controller, u equal to components' u for the inputs; for the reference, components' jet; or
- a clean error: initialization refused (fmi2Error), a step size that is not finite and positive
  refused (fmi2Error), a step discarded (fmi2Discard), or an output that is not finite read with
  fmi2Error (never with fmi2OK), each with a log message and the state left unchanged, exactly when
  components (the mathematics) refuses the same parameters or inputs.

Anything else (a crash or hang of the worker, a wrong status, a silently wrong or non-finite number)
fails the test with the case. Counts go to the tally (docs/reliability.md).
"""
from __future__ import annotations

import ctypes
import math

import numpy as np
import pytest
from hypothesis import HealthCheck, Phase, given, settings
from hypothesis import strategies as st

from components import catalog, certificates, maglev, mems
from components.ph_plant import Jet
from components.plant_step import PlantStepper

from .harness import DISCARD, ERROR, OK

pytestmark = pytest.mark.reliability

# no shrinking: a failing case is reported as drawn (the time budget of CI stays bounded)
SETTINGS = dict(deadline=None, derandomize=True, database=None, phases=(Phase.explicit, Phase.generate),
                suppress_health_check=[HealthCheck.too_slow, HealthCheck.function_scoped_fixture,
                                       HealthCheck.data_too_large])
PLANT_MODULES = {"MEMS": mems, "Maglev": maglev}
SPECIAL = [0.0, -0.0, 1e300, -1e300, 1e-300, -1e-300, 5e-324, math.nan, math.inf, -math.inf]
FACTORS = [1e-3, 0.1, 0.5, 0.9, 1.1, 2.0, 10.0, 1e3, -1.0]
# a magnitude for parameters whose default is 0
SCALE = {"MEMS": {"p_0": 1e-10, "x_e_0": 3e-11, "R_m": 5e-7},
         "Maglev": {"p_0": 1e-3, "x_e_0": 1.0, "R_m": 0.1}}
STEPS = {"MEMS": [1e-8, 1e-7, 1e-6, 1e-5], "Maglev": [1e-4, 1e-3, 1e-2, 5e-2]}
U_RANGE = {"MEMS": (-40.0, 60.0), "Maglev": (-5.0, 10.0)}
# energy balance tolerance relative to the energy flows: max(1e-6, 1000 rtol) for the FMU's rtol (measured
# worst cases: about 1e-12 at the default rtol 1e-8, 4e-5 at rtol 1e-6)
ENERGY_RTOL_MIN, ENERGY_RTOL_FACTOR = 1e-6, 1e3


def value(default: float, scale: float | None = None) -> st.SearchStrategy:
    base = default if default != 0 else (scale or 1.0)
    scaled = st.sampled_from([base * f for f in FACTORS])
    return st.one_of(st.just(default), scaled, scaled, st.sampled_from(SPECIAL), st.floats(allow_nan=True, allow_infinity=True))


# Integer parameters (a controller's `strict`) take integers: 0, 1, others and the 32-bit extremes
INTEGER_PARAMETERS = {"strict"}
INTEGER_VALUES = st.one_of(st.sampled_from([0, 1, 2, -1, 2**31 - 1, -2**31]), st.integers(-2**31, 2**31 - 1))


def overrides(defaults: dict[str, float], scales: dict[str, float] = {}, max_size: int = 3) -> st.SearchStrategy:
    names = sorted(defaults)
    return st.lists(st.sampled_from(names), max_size=max_size, unique=True).flatmap(
        lambda keys: st.fixed_dictionaries({k: INTEGER_VALUES if k in INTEGER_PARAMETERS else
                                            value(defaults[k], scales.get(k)) for k in keys}))


def step_size(identifier: str) -> st.SearchStrategy:
    return st.one_of(st.sampled_from(STEPS[identifier]),
                     st.sampled_from([0.0, -1e-6, math.nan, math.inf, 1e-300, 1.0]))


def _fmu_defaults(path) -> dict[str, float]:
    from fmpy import read_model_description
    return {v.name: float(v.start) for v in read_model_description(str(path)).modelVariables
            if v.causality == "parameter"}


def _message_for(r: dict) -> None:
    assert r["errors"].strip(), f"error status without a log message: {r}"


# ---- plants -----------------------------------------------------------------------------------------
def _components_accepts_plant(identifier: str, values: dict) -> bool:
    params = {k: v for k, v in values.items() if k in PLANT_MODULES[identifier].PARAMETERS}
    try:
        np.seterr(all="ignore")
        plant = catalog.plant(identifier, params)
        PlantStepper(plant, rtol=values.get("rtol", 1e-8))
        eta = [values.get(f"{n}_0") for n in ("q", "p", "x_e")]
        plant.check_state(np.array(eta, dtype=float))
    except Exception:                           # noqa: BLE001 - ValueError, or e.g. ZeroDivisionError for m = 1e-300
        return False
    return True


def judge_plant(identifier: str, values: dict, h: float, inputs: list[float], r: dict) -> str:
    """'correct' or 'clean_error'; AssertionError otherwise."""
    full = dict(_DEFAULTS[identifier], **values)
    accepted = _components_accepts_plant(identifier, full)
    if r["init"] == ERROR:
        _message_for(r)
        assert not accepted, f"initialization refused parameters components accepts: {r['errors']}"
        assert "initialization failed" in r["errors"]
        return "clean_error"
    assert r["init"] == OK, f"initialization returned status {r['init']}"
    assert accepted, f"initialization accepted parameters components refuses: {values}"
    params = {k: v for k, v in full.items() if k in PLANT_MODULES[identifier].PARAMETERS}
    plant = catalog.plant(identifier, params)
    for k, (entry, u) in enumerate(zip(r["steps"], inputs)):
        before = entry["mid"]
        after = entry["after"]
        if not (math.isfinite(h) and h > 0):                   # FMI: the step must be > 0
            assert entry["status"] == ERROR and "the step > 0" in r["errors"], (entry["status"], r["errors"])
            assert after == before, f"a refused step changed the outputs: {before} -> {after}"
            return "clean_error"
        if entry["status"] == DISCARD:
            _message_for(r)
            assert after == before, f"a discarded step changed the outputs: {before} -> {after}"
            assert "doStep" in r["errors"]
            return "clean_error"
        assert entry["status"] == OK, f"doStep returned status {entry['status']}"
        assert entry["after_status"] == OK, f"fmi2GetReal returned status {entry['after_status']}: {r['errors']}"
        eta = np.array([after["q"], after["p"], after["x_e"]])
        assert np.all(np.isfinite(eta)) and math.isfinite(after["H"]), f"non-finite result {after}"
        plant.check_state(eta)                                   # inside the domain (raises otherwise)
        with np.errstate(all="ignore"):
            assert after["H"] == pytest.approx(float(plant.H(eta)), rel=1e-12, abs=0.0)
        e = entry["energy"]
        if not e["ok"]:
            # extreme parameters (e.g. R_m = 1e300) where the independent reference itself cannot integrate
            # (non-finite right-hand side, more than 20000 evaluations): finite, in the domain, H consistent
            _ENERGY_UNCHECKED.append((identifier, values, h, u, e["reason"]))
            continue
        flows = e["dissipated"] + e["supplied_abs"]
        balance = e["supplied"] - e["dissipated"]
        dH = after["H"] - before["H"]
        tol = (max(ENERGY_RTOL_MIN, ENERGY_RTOL_FACTOR * full["rtol"]) * flows
               + 1e-12 * (abs(after["H"]) + abs(before["H"])) + 1e-300)
        assert abs(dH - balance) <= tol, (f"energy balance violated at step {k}: H(t+h) - H(t) = {dH:.17g}, "
                                          f"int P dt = {balance:.17g} (flows {flows:.3g}, tol {tol:.3g})")
        _ENERGY_ERRORS.append((abs(dH - balance) / (flows + 1e-300), abs(dH - balance) / tol, values, h, u))
    return "correct"


_DEFAULTS: dict[str, dict[str, float]] = {}
_ENERGY_ERRORS: list[float] = []
_ENERGY_UNCHECKED: list[tuple] = []
_REFERENCE_NONFINITE: list[tuple] = []


def plant_case(identifier: str):
    module = PLANT_MODULES[identifier]
    defaults = {p.name: p.default for p in module.PARAMETERS.values()}
    initial = {"MEMS": {"q_0": 15e-6, "p_0": 0.0, "x_e_0": 0.0},
               "Maglev": {"q_0": 0.0025, "p_0": 0.0, "x_e_0": 1.0}}[identifier]
    u_lo, u_hi = U_RANGE[identifier]
    u = st.one_of(st.floats(u_lo, u_hi), st.sampled_from(SPECIAL))
    return st.tuples(overrides(dict(defaults, **initial), SCALE[identifier]),
                     st.one_of(st.just({}), st.sampled_from([{"rtol": 1e-6}, {"rtol": 1e-10}, {"rtol": 0.5},
                                                             {"rtol": 0.0}, {"rtol": math.nan}])),
                     step_size(identifier), st.lists(u, min_size=1, max_size=3))


@pytest.mark.parametrize("identifier, examples", [("MEMS", 120), ("Maglev", 150)])
def test_fuzzed_plant(reliability_fmus, worker, tally, identifier, examples):
    path = str(reliability_fmus[identifier])
    _DEFAULTS[identifier] = _fmu_defaults(path)

    @settings(max_examples=examples, **SETTINGS)
    @given(case=plant_case(identifier))
    def check(case):
        values, rtol, h, inputs = case
        values = dict(values, **rtol)
        r = worker.call({"cmd": "case", "fmu": path, "values": values, "h": h, "steps": [{"u": u} for u in inputs],
                         "energy": {"plant": identifier, "params": {k: v for k, v in dict(_DEFAULTS[identifier], **values).items()
                                                                    if k in PLANT_MODULES[identifier].PARAMETERS}}})
        tally.add("fuzz", identifier, judge_plant(identifier, values, h, inputs, r))

    try:
        check()
    finally:
        tally.measurements["energy_balance"][identifier] = {
            "steps_checked": len(_ENERGY_ERRORS),
            "max_relative_error": max((e[0] for e in _ENERGY_ERRORS), default=None),
            "max_error_over_tolerance": max((e[1] for e in _ENERGY_ERRORS), default=None),
            "worst": repr(max(_ENERGY_ERRORS, key=lambda e: e[0], default=None)),
            "steps_unchecked": len(_ENERGY_UNCHECKED),
            "unchecked_examples": [repr(c) for c in _ENERGY_UNCHECKED[:5]]}
        _ENERGY_ERRORS.clear()
        _ENERGY_UNCHECKED.clear()


# ---- controllers ------------------------------------------------------------------------------------
NOMINAL_INPUTS = {
    "MEMS": {"q": 2.5e-5, "p": 1e-10, "x_e": 4e-11, "q_star": 3e-5, "q_star_dot": 0.01, "q_star_ddot": -3.0,
             "q_star_dddot": 100.0},
    "Maglev": {"q": 0.002, "p": 0.001, "x_e": 0.9, "q_star": 0.0025, "q_star_dot": 0.01, "q_star_ddot": -0.3,
               "q_star_dddot": 2.0},
}


def _components_u(identifier: str, values: dict, inputs: dict) -> tuple[bool, float]:
    """(components accepts the parameters, u or nan)."""
    plant_params = PLANT_MODULES[catalog.CONTROLLER_PLANT[identifier]].PARAMETERS
    names = list(plant_params) + list(catalog.GAINS[identifier])
    try:
        with np.errstate(all="ignore"):
            controller = catalog.controller(identifier, {n: values[n] for n in names})
    except Exception:                                          # noqa: BLE001 - ValueError, OverflowError, ...
        return False, math.nan
    try:                                                       # the FMU's own Integer parameter, as the worker
        strict = ctypes.c_int(int(values.get("strict", 0))).value    # sets it (fmi2Integer: 32 bits, wraps)
    except (OverflowError, ValueError):
        return False, math.nan
    if strict not in (0, 1):
        return False, math.nan
    if strict == 1 and any(c.verdict == certificates.FAILS for c in certificates.design_checks(controller)):
        return False, math.nan                                 # strict: a violated condition refuses
    if not all(math.isfinite(v) for v in inputs.values()):
        return True, math.nan
    try:
        with np.errstate(all="ignore"):
            jet = (Jet(*(np.array([inputs[n]]) for n in ("q_star", "q_star_dot", "q_star_ddot", "q_star_dddot")))
                   if catalog.TRACKING[identifier] else None)
            u = float(controller.u(np.array([inputs["q"], inputs["p"], inputs["x_e"]]), jet)[0])
    except Exception:                                          # noqa: BLE001 - the FMU reports these as NaN
        return True, math.nan
    return True, u if math.isfinite(u) else math.nan


def judge_controller(identifier: str, values: dict, steps: list[dict], r: dict) -> str:
    full = dict(_DEFAULTS[identifier], **values)
    accepted, _ = _components_u(identifier, full, dict(steps[0]))
    if r["init"] == ERROR:
        _message_for(r)
        assert not accepted, f"initialization refused parameters components accepts: {r['errors']}"
        return "clean_error"
    assert r["init"] == OK, f"initialization returned status {r['init']}"
    assert accepted, f"initialization accepted parameters components refuses: {values}"
    for entry, inputs in zip(r["steps"], steps):
        _, expected = _components_u(identifier, full, inputs)
        u = entry["mid"]["u"]
        if math.isnan(expected):
            assert entry["mid_status"] == ERROR and "u = nan is not finite" in r["errors"], \
                f"u read with status {entry['mid_status']} where components gives no finite u for {inputs}"
            assert math.isnan(u), f"u = {u} where components gives no finite u for {inputs}"
            assert entry["status"] == DISCARD, f"doStep status {entry['status']} with no finite u"
            return "clean_error"
        assert entry["mid_status"] == OK and u == expected, f"u = {u!r}, components: {expected!r} for {inputs}"
        assert entry["status"] == OK and entry["after"]["u"] == expected
    return "correct"


def controller_case(identifier: str, defaults: dict):
    plant = catalog.CONTROLLER_PLANT[identifier]
    names = list(NOMINAL_INPUTS[plant]) if catalog.TRACKING[identifier] else ["q", "p", "x_e"]
    one = st.fixed_dictionaries({n: st.one_of(st.just(NOMINAL_INPUTS[plant][n]),
                                              st.sampled_from([NOMINAL_INPUTS[plant][n] * f for f in FACTORS]),
                                              st.sampled_from(SPECIAL)) for n in names})
    return st.tuples(overrides(defaults, {"D_d": 1e-5 if plant == "MEMS" else 0.5}),
                     st.lists(one, min_size=1, max_size=3))


@pytest.mark.parametrize("identifier", ["MEMS_Proposition1", "MEMS_Theorem2", "Maglev_Proposition2", "Maglev_Theorem3"])
def test_fuzzed_controller(reliability_fmus, worker, tally, identifier):
    path = str(reliability_fmus[identifier])
    _DEFAULTS[identifier] = _fmu_defaults(path)

    @settings(max_examples=100, **SETTINGS)
    @given(case=controller_case(identifier, _DEFAULTS[identifier]))
    def check(case):
        values, steps = case
        r = worker.call({"cmd": "case", "fmu": path, "values": values,
                         "h": 1e-6 if identifier.startswith("MEMS") else 1e-3, "steps": steps})
        tally.add("fuzz", identifier, judge_controller(identifier, values, steps, r))

    check()


# ---- reference --------------------------------------------------------------------------------------
def judge_reference(values: dict, h: float, t0: float, n: int, r: dict) -> str:
    full = dict(_DEFAULTS["Reference"], **values)
    kind = int(full["kind"])
    try:
        reference = catalog.reference(kind, {k: full[k] for k in catalog.REFERENCE_PARAMETERS})
    except Exception:                                          # noqa: BLE001
        reference = None
    if r["init"] == ERROR:
        _message_for(r)
        assert reference is None, f"initialization refused parameters components accepts: {r['errors']}"
        return "clean_error"
    assert r["init"] == OK and reference is not None, (r["init"], values)
    t = t0
    jets = [r["outputs0"]] + [e["after"] for e in r["steps"]]
    statuses = [OK] + [e["status"] for e in r["steps"]]
    get_statuses = [r["outputs0_status"]] + [e["after_status"] for e in r["steps"]]
    for k, (jet, status, get_status) in enumerate(zip(jets, statuses, get_statuses)):
        if status == DISCARD:
            _message_for(r)
            return "clean_error"
        assert status == OK, status
        got = [jet["q_star"], jet["q_star_dot"], jet["q_star_ddot"], jet["q_star_dddot"]]
        try:
            with np.errstate(all="ignore"):
                j = reference.jet(t)
            expected = [float(j.q[0]), float(j.qd[0]), float(j.qdd[0]), float(j.qddd[0])]
        except ArithmeticError:                              # e.g. duration = 1e-300: components cannot evaluate
            expected = None
        if expected is None or not all(math.isfinite(x) for x in expected):
            # no finite jet exists: the FMU must not invent one, and must say so (fmi2Error and its log)
            assert not all(math.isfinite(x) for x in got), f"finite jet {got} where components has none"
            assert get_status == ERROR and "is not finite" in r["errors"], (get_status, r["errors"])
            _REFERENCE_NONFINITE.append((values, t, got, status))
            return "clean_error"
        assert get_status == OK and all(math.isfinite(x) for x in got), (
            f"the Reference FMU returned the jet {got} at t = {t} with status {get_status} (parameters {values})")
        assert got == expected, (got, expected)
        t = (t0 + k * h) + h                       # the FMU's time: currentCommunicationPoint + stepSize
    return "correct"


@settings(max_examples=150, **SETTINGS)
@given(case=st.tuples(
    st.one_of(st.sampled_from([0, 1, 2]), st.sampled_from([-1, 3, 2**31 - 1, -2**31])),
    overrides({p: x.default for p, x in catalog.REFERENCE_PARAMETERS.items()}, {"phase": 1.0, "t_start": 1e-3}, 3),
    st.sampled_from([1e-6, 1e-3, 0.1]), st.sampled_from([0.0, 0.5, 1e6]), st.integers(1, 3)))
def test_fuzzed_reference(reliability_fmus, worker, tally, case):
    kind, values, h, t0, n = case
    values = dict(values, kind=kind)
    path = str(reliability_fmus["Reference"])
    _DEFAULTS.setdefault("Reference", _fmu_defaults(path))
    r = worker.call({"cmd": "case", "fmu": path, "values": values, "h": h, "t0": t0, "steps": [{}] * n})
    tally.add("fuzz", "Reference", judge_reference(values, h, t0, n, r))
    tally.measurements["reference_nonfinite_jet"] = {
        "cases": len(_REFERENCE_NONFINITE), "examples": [repr(c) for c in _REFERENCE_NONFINITE[:5]]}
