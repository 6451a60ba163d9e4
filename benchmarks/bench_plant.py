"""Cost and accuracy of one plant communication step, before and after a change of components/plant_step.py,
side by side in one run.

    .venv/bin/python benchmarks/bench_plant.py [--before REV] [-n 300] [--repeat 5] [--check 4] [--profile]

"before" is PlantStepper as committed at git revision REV (default: 1dda5db, the held-input stepper whose
MEMS tracking step cost ~240 us), loaded beside the working tree's ("after"). For each row a closed loop
of components/ (the scenario's plant, controller and reference, parameters from its .ssv files; the
master's Gauss-Seidel order: u_k from the plant state at t_k) is recorded over n communication steps
with the after stepper; both steppers then replay exactly those (state, input) pairs, step by step
alternately, `--repeat` times (the machine is shared: each step's fastest time counts, and the table shows
their mean). Per step: time, RODAS4
substeps (accepted + rejected), rejected substeps, share of steps whose electrical layer was taken in
closed form. Accuracy: `--check` of the steps against scipy's Radau with the same input (rtol 1e-12),
as max |error_i| / (rtol (s_i + |eta_i|)) (<= 1: within the stepper's tolerance).

"held": u constant over the step (what a master without derivatives does). "1st order": the input
u + u' tau with u' = du/dt of the controller along the loop (controller.u_derivative with the plant's
eta' and the reference's derivatives), what a master that passes derivatives does; the before stepper
cannot take u', so its column holds u (marked *).

`--general`: "before" is the working tree's GeneralStepper (numpy arrays, any n_m, n_e; given u' too) on the
same rows: what merging the two steppers into one would cost the paper's one-DOF plants.
"""
from __future__ import annotations

import argparse
import cProfile
import importlib.util
import pstats
import subprocess
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from components import catalog  # noqa: E402
from components.plant_step import GeneralStepper, PlantStepper, simulate_polynomial  # noqa: E402
from emcosim.engine.ssd import read_scenario  # noqa: E402

# scenario, start time of the recorded segment, step size, hold
ROWS = [
    ("mems_tracking_Dd-0.4", 0.0, 1e-6, "held"),          # the start: q from 15 um to the reference
    ("mems_tracking_Dd-0.4", 0.01, 1e-6, "held"),         # tracking (q ~ 0.06 m: the layer lasts ~0.2 us)
    ("mems_tracking_Dd-0.4", 0.01, 1e-6, "1st order"),
    ("mems_regulation_Dd-1", 0.0, 1e-6, "held"),         # the transient from rest
    ("mems_regulation_Dd-1", 0.0, 1e-6, "1st order"),
    ("mems_regulation_Dd-1", 0.004, 1e-6, "held"),       # at the set-point
    ("maglev_tracking_D0_R0.82", 0.0, 5e-4, "held"),
    ("maglev_tracking_D0_R0.82", 0.0, 5e-4, "1st order"),
    ("maglev_tracking_D0_R0.82", 0.0, 5e-3, "1st order"),
]
# (The MEMS loops do not allow much larger communication steps: measured from the tracking state, the
# held-input loop diverges at h = 5 us and the first-order one at 2 us, whatever the plant does.)


class GeneralAsScalar:
    """GeneralStepper (any n_m, n_e; numpy arrays) behind PlantStepper's advance(q, p, x, u, h, du), for
    `--general`: what a merged stepper would cost on the paper's one-DOF plants."""

    def __init__(self, plant, rtol: float):
        self.stepper = GeneralStepper(plant, rtol=rtol)
        self.scale = self.stepper.scale

    def advance(self, q, p, x, u, h, du=0.0):
        return tuple(float(v) for v in self.stepper.step((q, p, x), [u], h, {1: [du]} if du else None))

    n_substeps = property(lambda self: self.stepper.n_substeps)
    n_rejected = property(lambda self: self.stepper.n_rejected)
    layer_applied = 0


def load_before(rev: str):
    """components/plant_step.py at git revision `rev`, as module components.plant_step_before."""
    source = subprocess.run(["git", "show", f"{rev}:components/plant_step.py"], cwd=ROOT, check=True,
                            capture_output=True, text=True).stdout
    path = Path(f"/tmp/emcosim_plant_step_{rev}.py")
    path.write_text(source)
    spec = importlib.util.spec_from_file_location("components.plant_step_before", path)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def scenario_objects(name: str):
    """(plant, controller, reference, eta0, rtol) from the scenario's parameter files."""
    scenario = read_scenario(ROOT / "scenarios" / name / "SystemStructure.ssd")
    comps = {c.name: c for c in scenario.components}
    values = {n: {k: p.value for k, p in comps[n].parameters.items()} for n in comps}
    plant_name = comps["plant"].source.stem
    plant_params = {k: v for k, v in values["plant"].items() if k in catalog.PLANTS[plant_name][1]}
    plant = catalog.plant(plant_name, plant_params)
    controller = catalog.controller(comps["controller"].source.stem, values["controller"])
    reference = None
    if "reference" in comps:
        ref_values = dict(values["reference"])
        reference = catalog.reference(ref_values.pop("kind"), ref_values)
    eta0 = tuple(float(values["plant"][f"{x}_0"]) for x in ("q", "p", "x_e"))
    return plant, controller, reference, eta0, float(values["plant"]["rtol"])


def record(name: str, t0: float, h: float, hold: str, n: int):
    """The closed loop of components/ over n steps from t0: [(eta_k, u_k, du_k)] and the objects."""
    plant, controller, reference, eta0, rtol = scenario_objects(name)
    stepper = PlantStepper(plant, rtol=rtol)
    eta = eta0
    if t0 > 0:                                       # start on the reference (tracking, or at the set-point)
        eta = tuple(float(v) for v in plant.feasible_state(reference.jet(t0))[0])   # floats, as in the FMU
    steps = []
    for k in range(n):
        t = t0 + k * h
        jet = reference.values(t) if controller.tracking else None
        u = float(controller.u_scalar(*eta, jet))
        du = 0.0
        if hold == "1st order":
            rates = list(plant.f(np.array(eta), np.array([u])))
            if controller.tracking:
                rates += list(reference.derivatives(t, 4)[1:])
            du = float(controller.u_derivative(list(eta) + (list(jet) if jet else []), rates))
        steps.append((eta, u, du))
        eta = stepper.advance(*eta, u, h, du)
    return plant, rtol, steps


def replay(old, new, steps, h: float, derivative: bool, repeat: int, both_derivative: bool = False):
    """Both steppers on the recorded steps, step by step alternately, `repeat` times: per stepper, the mean
    over the steps of each step's fastest time (s), and the mean substeps, rejected substeps and layer
    share per step."""
    best = {"old": [float("inf")] * len(steps), "new": [float("inf")] * len(steps)}
    stats = {}
    for _ in range(repeat):
        counts = {"old": [0, 0, 0], "new": [0, 0, 0]}
        for k, (eta, u, du) in enumerate(steps):
            for key, stepper in (("old", old), ("new", new)):
                tic = time.perf_counter()
                if derivative and (key == "new" or both_derivative):
                    stepper.advance(*eta, u, h, du)
                else:
                    stepper.advance(*eta, u, h)
                best[key][k] = min(best[key][k], time.perf_counter() - tic)
                c = counts[key]
                c[0] += stepper.n_substeps + stepper.n_rejected
                c[1] += stepper.n_rejected
                c[2] += stepper.layer_applied
        stats = counts
    n = len(steps)
    return {key: (sum(best[key]) / n, *(c / n for c in stats[key])) for key in best}


def accuracy(plant, stepper_class, rtol, steps, h, derivative, n_check):
    """max over n_check steps of max_i |error_i| / (rtol (s_i + |eta_i|)) against Radau."""
    worst = 0.0
    picks = np.linspace(0, len(steps) - 1, n_check).astype(int) if n_check else []
    for k in picks:
        eta, u, du = steps[k]
        stepper = stepper_class(plant, rtol=rtol)
        y = stepper.advance(*eta, u, h, du) if derivative else stepper.advance(*eta, u, h)
        ref = simulate_polynomial(plant, eta, h, [(u, du if derivative else 0.0)], rtol=1e-12)[-1]
        scale = np.array(stepper.scale)
        worst = max(worst, float(np.max(np.abs(np.array(y) - ref) / (rtol * (scale + np.abs(ref))))))
    return worst


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--before", default="1dda5db", help="git revision of the stepper to compare with")
    ap.add_argument("-n", type=int, default=300, help="communication steps per row")
    ap.add_argument("--repeat", type=int, default=5, help="alternating passes of before and after")
    ap.add_argument("--check", type=int, default=4, help="steps per row checked against Radau (0: none)")
    ap.add_argument("--profile", action="store_true", help="cProfile of the after stepper on each row")
    ap.add_argument("--general", action="store_true", help="before: the working tree's GeneralStepper (numpy, any "
                    "n) instead of PlantStepper at --before: the cost of one stepper for all plants")
    args = ap.parse_args(argv)
    if args.general:
        before = type("GeneralModule", (), {"PlantStepper": GeneralAsScalar})
        print(f"before: GeneralStepper of the working tree (with the input derivative too); after: PlantStepper. "
              f"{args.n} steps per row, each the fastest of {args.repeat} alternating runs.\n")
    else:
        before = load_before(args.before)
        print(f"before: components/plant_step.py at {args.before}; after: the working tree. "
              f"{args.n} steps per row, each the fastest of {args.repeat} alternating runs.\n")
    head = (f"{'scenario':26s} {'t0':>5s} {'h':>6s} {'input':9s} | {'us/step':>8s} {'substeps':>8s} {'rejected':>8s} "
            f"{'layer':>5s} {'err/tol':>7s} | {'us/step':>8s} {'substeps':>8s} {'rejected':>8s} {'layer':>5s} "
            f"{'err/tol':>7s} | {'before/after':>12s}")
    print(f"{'':51s} | {'before':^40s}   | {'after':^40s} |")
    print(head)
    print("-" * len(head))
    for name, t0, h, hold in ROWS:
        plant, rtol, steps = record(name, t0, h, hold, args.n)
        derivative = hold == "1st order"
        old, new = before.PlantStepper(plant, rtol=rtol), PlantStepper(plant, rtol=rtol)
        result = replay(old, new, steps, h, derivative, args.repeat, args.general)
        b, a = result["old"], result["new"]
        b_err = (accuracy(plant, before.PlantStepper, rtol, steps, h, derivative, args.check)
                 if args.general or not derivative else None)
        a_err = accuracy(plant, PlantStepper, rtol, steps, h, derivative, args.check)
        mark = "*" if derivative and not args.general else " "
        b_err_text = f"{b_err:7.3f}" if b_err is not None else f"{'-':>7s}"
        print(f"{name:26s} {t0 * 1e3:3.0f}ms {h:6.0e} {hold:9s} | {b[0] * 1e6:7.1f}{mark} {b[1]:8.2f} {b[2]:8.2f} "
              f"{b[3]:5.0%} {b_err_text} | {a[0] * 1e6:8.1f} {a[1]:8.2f} {a[2]:8.2f} {a[3]:5.0%} {a_err:7.3f} | "
              f"{b[0] / a[0]:11.1f}x", flush=True)
        if args.profile:
            profile = cProfile.Profile()
            profile.runcall(replay, new, new, steps, h, derivative, 1)
            pstats.Stats(profile).sort_stats("tottime").print_stats(8)
    if not args.general:
        print("\n* the before stepper holds u: it cannot take the input derivative.")


if __name__ == "__main__":
    main()
