"""What the paper's conditions and the closed loop's linearization say about a scenario's design:
the facts the claims report needs beside the simulated runs.

This module is the reports' one point of contact with the certificate code (emcosim.paper.certify,
components.certificates): `design_from_scenario`, `design_checks`, `neighbourhood` and `theorem1`.
The linearization is that of the actual plant + controller loop (components.monolithic.ClosedLoop),
evaluated at the target eta*(t).
"""
from __future__ import annotations

import itertools

import numpy as np

from components import certificates
from components.monolithic import ClosedLoop

from ..engine.ssd import Scenario, with_values
from .certify import Design, design_from_scenario


def design(scenario: Scenario, values: dict[str, float] | None = None) -> Design:
    """The scenario's design, with `values` ("component.parameter" -> value) replacing its own."""
    return design_from_scenario(with_values(scenario, values) if values else scenario)


def _jet0(d: Design):
    return None if d.reference is None else d.reference.jet(0.0)


def violated_conditions(d: Design) -> list[tuple[str, str]]:
    """The conditions of the design's proposition or theorem that its parameters violate at the
    target (components.certificates.design_checks): (the condition, one sentence with its numbers)."""
    out = []
    for check in certificates.design_checks(d.controller, _jet0(d)):
        if check.verdict == certificates.FAILS:
            nums = ", ".join(f"{k} = {v:.4g}" for k, v in check.numbers.items() if isinstance(v, (int, float)))
            out.append((check.name, f"violates {check.name}" + (f" ({nums})" if nums else "")
                        + (f"; {check.note}" if check.note else "")))
    return out


def dominant_mode(d: Design, n_times: int = 9) -> dict:
    """The slowest mode of the closed loop linearized at its target eta*(t) (Jacobian of plant +
    controller, components.monolithic.ClosedLoop.jacobian) at n_times times over the horizon:
    decay rate -Re(lambda) [1/s], damping ratio zeta = -Re(lambda)/|lambda| (1 for a real
    eigenvalue: no oscillation) and frequency |Im(lambda)| [rad/s]; the smallest rate and zeta over
    the times (the slowest, least damped case)."""
    loop = ClosedLoop(d.controller, d.reference)
    times = np.linspace(0.0, d.horizon, n_times) if d.horizon > 0 else np.array([0.0])
    rates, zetas, freqs = [], [], []
    for t in times:
        lam = np.linalg.eigvals(loop.jacobian(t, loop.target(t)))
        slow = lam[np.argmax(lam.real)]
        rates.append(-slow.real)
        zetas.append(-slow.real / abs(slow) if slow.imag != 0 else 1.0)
        freqs.append(abs(slow.imag))
    return {"rate": float(min(rates)), "zeta": float(min(zetas)), "frequency": float(max(freqs))}


def hinf_norm_F(F: np.ndarray, n: int = 2000) -> float:
    """sup over w of the largest singular value of (jwI - F)^-1 F (frequency grid, log-spaced
    around F's eigenvalues, plus w = 0 and the eigenvalues' imaginary parts)."""
    lam = np.linalg.eigvals(F)
    mags = np.abs(lam[np.abs(lam) > 0])
    w = np.concatenate([[0.0], np.logspace(np.log10(mags.min()) - 3, np.log10(mags.max()) + 3, n), np.abs(lam.imag)])
    A = 1j * w[:, None, None] * np.eye(F.shape[0]) - F                   # (jwI - F) for every w at once
    X = np.linalg.solve(A, np.broadcast_to(F.astype(complex), A.shape))
    return float(np.max(np.linalg.svd(X, compute_uv=False)[:, 0]))


def theorem1_iii(d: Design, radius: float = 0.1, norm: bool = True) -> dict:
    """Theorem 1 (iii) as emcosim certify evaluates it (components.certificates.theorem1) over a
    tube of relative half-width `radius` around the target, with gamma1/gamma2 of (ii) and the
    norm S = sup_w |(jwI - F_d)^-1 F_d| that decides it (docs/claims.md: (iii) holds iff
    (1 - gamma1/gamma2) S < 1); without `norm`, S is not computed."""
    nb = certificates.neighbourhood(d.controller, d.reference, d.horizon, radius)
    checks, _, _ = certificates.theorem1(d.controller, nb)
    by_name = {c.name.split(":")[0]: c for c in checks}
    ratio = by_name["Theorem 1 (ii)"].numbers.get("gamma1/gamma2")
    F = d.controller.F_d()
    hurwitz = bool(np.max(np.linalg.eigvals(F).real) < 0)
    return {"verdict": by_name["Theorem 1 (iii)"].verdict, "gamma1/gamma2": ratio,
            "S": (hinf_norm_F(F) if hurwitz else float("inf")) if norm else None}


def theorem1_iii_search(scenario: Scenario, grid: dict[str, list[float]], radius: float = 0.1) -> dict:
    """Theorem 1 (iii) at every combination of `grid` ("controller.parameter" -> values): how many
    combinations the controller accepts, at how many (iii) holds, and the first that does."""
    names = list(grid)
    tried = accepted = held = 0
    first = None
    for combo in itertools.product(*grid.values()):
        tried += 1
        values = dict(zip(names, combo))
        try:
            d = design(scenario, values)
        except ValueError:                              # a gain the controller refuses
            continue
        accepted += 1
        if theorem1_iii(d, radius, norm=False)["verdict"] == certificates.HOLDS:
            held += 1
            first = first or values
    return {"tried": tried, "accepted": accepted, "holds": held, "first": first}
