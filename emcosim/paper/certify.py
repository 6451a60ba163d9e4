"""`emcosim certify SCENARIO`: the paper's guarantees for a scenario's controller design.

Reads the scenario's controller, plant and reference parameters, builds the same components objects
the FMUs use (components.catalog) and evaluates components.certificates over a tube around the
scenario's reference (physics-aware: not part of the master's core).

    python -m emcosim.paper.certify [--check] [docs/certificates.md]

rewrites (or checks) the section of docs/certificates.md that lists certify's output for every
scenario of scenarios/.
"""
from __future__ import annotations

import argparse
import re
import sys
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from components import catalog, certificates
from components.controller import Controller
from components.references import Constant, Reference

from ..engine.ssd import Scenario, read_scenario


@dataclass
class Design:
    controller: Controller
    controller_name: str
    reference: Reference | None
    eta0: np.ndarray | None
    horizon: float


def _values(component) -> dict:
    return {name: p.value for name, p in component.parameters.items()}


def design_from_scenario(scenario: Scenario) -> Design:
    """The controller (with its plant model), reference, initial plant state and horizon of a scenario. A
    controller FMU built from a plant description (`emcosim plant build`) is known by the description it
    carries; a device with several positions tracks one Reference FMU per position (reference_<q_i>)."""
    from ..devices.registry import register_fmu
    from ..devices.scenario import StackedReference

    ctrl = eta0 = None
    name = ""
    references: dict[str, Reference] = {}
    plant_values: dict | None = None
    for comp in scenario.components:
        model = Path(comp.source).stem
        if model not in catalog.GAINS and model not in catalog.PLANTS and model != "Reference":
            register_fmu(comp.source)                  # None for an FMU without a description
        values = _values(comp)
        if model in catalog.GAINS:
            ctrl, name = catalog.controller(model, values), model
        elif model == "Reference":
            kind = values.pop("kind", 1)
            references[comp.name] = catalog.reference(int(kind), values)
        elif model in catalog.PLANTS:
            plant_values = values
    if ctrl is None:
        raise ValueError(f"{scenario.path}: no controller FMU of this suite ({', '.join(catalog.GAINS)}) in the scenario")
    device = catalog.DEVICES[catalog.CONTROLLER_PLANT[name]]
    if plant_values is not None:
        eta0 = np.array([plant_values.get(f"{v.name}_0", np.nan) for v in device.states], dtype=float)
    ref: Reference | StackedReference | None = None
    if ctrl.tracking and device.n_m == 1 and len(references) == 1:
        ref = next(iter(references.values()))
    elif ctrl.tracking and references:
        missing = [v.name for v in device.q if f"reference_{v.name}" not in references]
        if missing:
            raise ValueError(f"{scenario.path}: {name} tracks {len(device.q)} positions; no reference_<name> "
                             f"component for {', '.join(missing)}")
        ref = StackedReference([references[f"reference_{v.name}"] for v in device.q])
    constant = isinstance(ref, Constant) or (isinstance(ref, StackedReference)
                                             and all(isinstance(r, Constant) for r in ref.generators))
    horizon = 0.0 if (ref is None or constant) else float(scenario.stop_time or 0.0)
    if ctrl.tracking and ref is None:
        raise ValueError(f"{scenario.path}: {name} tracks a reference, but the scenario has no Reference FMU")
    return Design(ctrl, name, ref, None if eta0 is None or np.any(np.isnan(eta0)) else eta0, horizon)


def certify_scenario(path: str | Path, radius: float = 0.1, include_start: bool = False,
                     scenario_dirs: list[Path] | None = None) -> certificates.Certificate:
    """Certificate of a scenario's design over a tube of relative half-width `radius` around its
    reference (over the scenario's horizon); with include_start the tube also contains eta(0)."""
    radius = certificates.check_radius(radius)
    scenario = read_scenario(path, scenario_dirs)
    d = design_from_scenario(scenario)
    cert = certificates.certify(d.controller, d.reference, d.horizon, radius=radius,
                                eta0=d.eta0 if include_start else None)
    cert.controller = f"{d.controller_name} ({d.controller.name}) in scenario {scenario.name}"
    if d.eta0 is not None:
        target0 = d.controller.target(None if d.reference is None else d.reference.jet(0.0))
        inside = bool(np.all(np.abs(d.eta0 - target0) <= np.asarray(cert.neighbourhood["half_widths"])))
        cert.neighbourhood["initial state inside"] = inside
        cert.neighbourhood["description"] += ("; the scenario's initial state is inside it" if inside else
                                              "; the scenario's initial state is OUTSIDE it (use --include-start)")
    return cert


# ---- what `emcosim certify`'s exit status tells (docs/cli.md) ------------------------------------

CERTIFIED = 0               # a rate is certified and every condition the design's result requires holds
NO_RATE = 3                 # no contraction rate certified (no constant metric exists, or none was found)
CONDITION_FAILS = 4         # a condition the design's result requires fails (takes precedence over NO_RATE)


def failed_conditions(cert: certificates.Certificate) -> list[str]:
    """The conditions of the design's own result (Proposition 1, 2 or Theorem 2, 3) that fail: the assumption
    it rests on, the pH condition where that result requires it (Propositions 1, 2; the check's note says
    "required"), and Theorem 1 (i) (F_d Hurwitz) and (ii) (hess H_d > 0 over the neighbourhood). Theorem 1
    (iii) is left out: it is only Theorem 1's sufficient condition for its own rate (eq. riccati), which
    fails on every paper design (docs/certificates.md); the rate is then Lemma 1's, whose failure is
    NO_RATE."""
    failed = []
    for c in cert.checks:
        if c.verdict != certificates.FAILS:
            continue
        required = (c.name.startswith(("Assumption", "Theorem 1 (i)", "Theorem 1 (ii)"))
                    or (c.name.startswith("pH condition") and c.note == "required"))
        if required:
            failed.append(c.name)
    return failed


def exit_status(cert: certificates.Certificate) -> tuple[int, str]:
    """certify's exit status and the line that says why (empty for CERTIFIED)."""
    failed = failed_conditions(cert)
    if failed:
        return CONDITION_FAILS, f"a condition of the design's result fails: {', '.join(failed)}"
    if cert.rate is None:
        return NO_RATE, "no contraction rate is certified over this neighbourhood"
    return CERTIFIED, ""


# ---- certify's output for every scenario, in docs/certificates.md --------------------------------

ROOT = Path(__file__).resolve().parents[2]
DOC = ROOT / "docs" / "certificates.md"
BEGIN = "<!-- certify-output:begin (generated by `python -m emcosim.paper.certify`; do not edit) -->"
END = "<!-- certify-output:end -->"
# Lines whose numbers depend on the solver's path (the optimal metric is not unique; where no metric exists,
# the best rate found and the bracket depend on the solves that failed; the number of
# solves and their statuses, the multipliers): left out when checking that the doc is current.
VOLATILE = ("optimal rate", "no constant metric is faster", "because", "Omega", "cond(Omega)", "solves",
            "infeasibility certificate", "note:")


def scenario_names(root: Path | None = None) -> list[str]:
    from ..locations import SCENARIOS

    root = SCENARIOS if root is None else root
    return sorted(p.name for p in root.iterdir() if (p / "SystemStructure.ssd").is_file())


def section(reports: dict[str, str]) -> str:
    """The doc's generated section: `emcosim certify NAME`'s output for every scenario."""
    parts = [BEGIN, ""]
    for name, text in reports.items():
        parts += [f"### {name}", "", "```", f"$ emcosim certify {name}", text, "```", ""]
    parts.append(END)
    return "\n".join(parts)


def certify_all(names: list[str] | None = None) -> dict[str, str]:
    names = scenario_names() if names is None else names
    from ..locations import SCENARIOS

    return {n: certify_scenario(SCENARIOS / n).report() for n in names}


def _comparable(text: str) -> list[tuple[str, tuple[float, ...]]]:
    """Lines of a generated section without the volatile ones, split into (words, numbers)."""
    out = []
    for line in text.splitlines():
        stripped = line.strip()
        if any(stripped.startswith(v) for v in VOLATILE):
            continue
        number = r"[-+]?(?:\d+\.?\d*|\.\d+)(?:[eE][-+]?\d+)?"
        out.append((re.sub(number, "#", stripped), tuple(float(x) for x in re.findall(number, stripped))))
    return out


ROUNDING_RESIDUAL = 1e-13     # a relative residual below this is zero to rounding (~450 eps): its digits are noise


def same_section(a: str, b: str, rtol: float = 1e-4) -> list[str]:
    """Differences between two generated sections: words exactly, numbers to rtol; [] if none. On a residual line,
    two residuals both below ROUNDING_RESIDUAL are the same (both are zero to rounding: the order of the floating-
    point operations, e.g. generated against hand-written laws, moves such a number by 1e-3 of itself)."""
    la, lb = _comparable(a), _comparable(b)
    if len(la) != len(lb):
        return [f"{len(la)} lines against {len(lb)}"]
    bad = []
    for (wa, na), (wb, nb) in zip(la, lb):
        rounding = "residual" in wa
        close = len(na) == len(nb) and all(abs(x - y) <= rtol * max(abs(x), abs(y)) + 1e-300
                                           or (rounding and max(abs(x), abs(y)) < ROUNDING_RESIDUAL)
                                           for x, y in zip(na, nb))
        if wa != wb or not close:
            bad.append(f"{wa} {na} != {wb} {nb}")
    return bad


def current_section(doc: Path = DOC) -> str:
    text = doc.read_text()
    if BEGIN not in text or END not in text:
        raise ValueError(f"{doc}: no generated section ({BEGIN!r} ... {END!r})")
    return text[text.index(BEGIN): text.index(END) + len(END)]


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description="Write (or check) certify's output for every scenario into a doc.")
    parser.add_argument("doc", nargs="?", default=str(DOC))
    parser.add_argument("--check", action="store_true", help="only check that the doc is current")
    args = parser.parse_args(argv)
    doc = Path(args.doc)
    new = section(certify_all())
    old = current_section(doc)
    if args.check:
        bad = same_section(old, new)
        for b in bad:
            print(f"stale: {b}", file=sys.stderr)
        return 1 if bad else 0
    doc.write_text(doc.read_text().replace(old, new))
    print(f"wrote certify's output for {len(scenario_names())} scenarios into {doc}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
