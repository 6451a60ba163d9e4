"""Cost of the controllers' real-valued law u (what a controller FMU computes every communication step),
before and after a change of components/, side by side in one run; and the cost of the exact derivative
of u along one direction (Controller.u_derivative: one complex-step evaluation) relative to u.

    .venv/bin/python benchmarks/bench_laws.py [--before REV] [-n 20000] [--repeat 7]

Then the plants' model functions (what PlantStepper and the laws call): the hand-written MEMS and maglev
(tests/hand_written_plants.py, components/ before issue 25) against the ones generated from
components/plants/*.toml, side by side.

"before" is components/ as committed at git revision REV (default 1dda5db), imported as a separate
package beside the working tree's. Both are timed alternately `--repeat` times on the same inputs near
each controller's target (timeit loops of n calls); the fastest pass of each counts.
"""
from __future__ import annotations

import argparse
import importlib
import subprocess
import sys
import tarfile
import tempfile
import timeit
from io import BytesIO
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from components import catalog, maglev, mems  # noqa: E402
from tests.hand_written_plants import HandMaglev, HandMEMS  # noqa: E402

# controller, gains, inputs (q, p, x_e[, q*, q*', q*'', q*'''])
CASES = [("MEMS_Proposition1", {}, (2e-5, 1e-10, 3e-11)),
         ("MEMS_Theorem2", {"D_d": -0.4}, (0.06, 2.8e-9, 2.9e-6, 0.06, 1.2, -30.0, -1000.0)),
         ("Maglev_Proposition2", {}, (0.0025, 0.001, 0.2)),
         ("Maglev_Theorem3", {"R_e_bar": 0.82}, (0.0025, 4e-5, 0.2, 0.0025, 0.0005, 0.0, -0.0005))]


def load_before(rev: str):
    """The package components/ at git revision `rev`, imported as `components_before`."""
    archive = subprocess.run(["git", "archive", rev, "components"], cwd=ROOT, check=True, capture_output=True).stdout
    folder = Path(tempfile.mkdtemp(prefix="emcosim_before_"))
    with tarfile.open(fileobj=BytesIO(archive)) as tar:
        tar.extractall(folder)
    (folder / "components").rename(folder / "components_before")
    for module in (folder / "components_before").rglob("*.py"):       # generated modules import `components.`
        text = module.read_text(encoding="utf-8")
        module.write_text(text.replace("from components.", "from components_before."), encoding="utf-8")
    sys.path.insert(0, str(folder))
    return importlib.import_module("components_before.catalog")


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--before", default="1dda5db")
    ap.add_argument("-n", type=int, default=20000)
    ap.add_argument("--repeat", type=int, default=7)
    args = ap.parse_args(argv)
    before = load_before(args.before)
    print(f"u_scalar: components/ at {args.before} (before) and the working tree (after); best of {args.repeat} "
          f"alternating passes of {args.n} calls.\n")
    print("(FMU's call: what fmus/controller.py evaluates, u_scalar before and Controller.scalars(*inputs), the\n"
          "generated law, after.)\n")
    print(f"{'controller':20s} {'before us':>10s} {'after us':>10s} {'after/before':>13s} {'FMU call us':>12s} "
          f"{'FMU/before':>11s} | {'du along v us':>13s} {'du / u':>7s} {'du after/before':>16s}")
    for name, gains, x in CASES:
        old, new = before.controller(name, gains), catalog.controller(name, gains)
        jet = tuple(x[3:]) if new.tracking else None
        v = [1.0] * len(x)
        calls = {"before": lambda: old.u_scalar(x[0], x[1], x[2], jet),
                 "after": lambda: new.u_scalar(x[0], x[1], x[2], jet),
                 "after, FMU's call": lambda: new.scalars(*x),
                 "derivative before": (lambda: old.u_derivative(x, v)) if hasattr(old, "u_derivative") else None,
                 "derivative": lambda: new.u_derivative(x, v)}
        if getattr(new, "scalars", None) is None or not callable(new.scalars):   # before the generated laws
            del calls["after, FMU's call"]
        calls = {k: c for k, c in calls.items() if c is not None}      # --before may predate u_derivative
        best = {"derivative before": float("nan"), "after, FMU's call": float("nan")} | {k: float("inf") for k in calls}
        for _ in range(args.repeat):
            for key, call in calls.items():
                best[key] = min(best[key], timeit.timeit(call, number=args.n) / args.n * 1e6)
        fmu = best["after, FMU's call"]
        print(f"{name:20s} {best['before']:10.2f} {best['after']:10.2f} {best['after'] / best['before']:12.2f}x "
              f"{fmu:12.2f} {fmu / best['before']:10.2f}x | "
              f"{best['derivative']:13.2f} {best['derivative'] / best['after']:6.1f}x "
              f"{best['derivative'] / best['derivative before']:15.2f}x")
    plant_functions(args.n, args.repeat)


def plant_functions(n: int, repeat: int) -> None:
    """Hand-written vs generated model functions, best of `repeat` alternating passes of n calls."""
    print(f"\nplant model functions: hand-written (before) vs generated from the description (after), "
          f"best of {repeat} passes of {n} calls.\n")
    print(f"{'plant.function':20s} {'hand us':>10s} {'generated us':>13s} {'ratio':>7s}")
    for label, hand, gen, eta in (("MEMS", HandMEMS(), mems.MEMS(), (2e-5, 1e-10, 3e-11)),
                                  ("Maglev", HandMaglev(), maglev.Maglev(), (0.0025, 0.001, 0.2))):
        q = eta[0]
        state = __import__("numpy").array(eta)
        jet = (q, 0.01 * q, 0.0, 0.0)
        for fn, call in (("V_s", lambda P: P.V_s(q)), ("dV", lambda P: P.dV(q)), ("psi", lambda P: P.psi(q)),
                         ("dpsi", lambda P: P.dpsi(q)), ("d2psi", lambda P: P.d2psi(q)), ("H", lambda P: P.H(state)),
                         ("feasible_scalar", lambda P: P.feasible_scalar(*jet)),
                         ("check_state", lambda P: P.check_state(state)), ("jacobian", lambda P: P.jacobian(state))):
            best = {"hand": float("inf"), "gen": float("inf")}
            for _ in range(repeat):
                for key, P in (("hand", hand), ("gen", gen)):
                    best[key] = min(best[key], timeit.timeit(lambda: call(P), number=n) / n * 1e6)
            print(f"{label + '.' + fn:20s} {best['hand']:10.3f} {best['gen']:13.3f} {best['gen'] / best['hand']:6.2f}x")


if __name__ == "__main__":
    main()
