"""How the electrical operating point is fixed when n_e > n_m (issue 34; docs/plant-description.md).

The p-row of eq. (open-loop elecmech) fixes only n_m combinations of the electrical state: along a reference
(Definition 1) or at an equilibrium (the set E of Section 3, p = 0)

    grad_q H_e(q*, x_e*) = b := -F*,   F* = M q*'' + (dM/dt) q*' + R_m q*' + grad V(q*) + grad_q T.

For H_e = 1/2 x_e^T Psi(q) x_e with every dPsi/dq_k diagonal, grad_q H_e = A(q) w with w_i = x_e_i^2 and
A_ki = (dPsi/dq_k)_ii / 2: n_m linear equations in n_e unknowns w >= 0. A rule picks one solution:

- "least_energy": the least stored electrical energy H_e = 1/2 sum_i Psi_ii w_i (Psi diagonal) that holds the
  force balance: a linear program whose solution has n_m energized ports B (w_B = A_B^-1 b, the others 0); it
  is smooth in q while the set B does not change. Where several ports hold the force at the same energy
  (identical coils on one axis), the load is shared: the least-norm w on those ports. Where B changes along a
  reference, x_e*(t) is not differentiable (a port switches on or off through sqrt(w)): that reference is
  not feasible for this rule.
- "least_input": the same with the input the equilibrium needs, |u|^2 = sum_i (R_e,ii Psi_ii / G_e,ii)^2 w_i
  (diagonal R_e, G_e, J_e = 0): the linear program with other weights.
- "bias": n_e - n_m coordinates are given, each a value (x_e_i = v) or a ratio to another coordinate
  (x_e_i = r x_e_j); the force balance fixes the rest. Smooth in q wherever the solved w stay > 0.

The same rule gives x_e_d (regulation) and x_e*(t) with x_e*'(t) (tracking): A w' = b' - A' w.
Every function takes complex jets (complex-step derivatives): the branch is chosen on real parts.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field
from itertools import combinations
from typing import Any, Sequence

import numpy as np

RULES = ("least_energy", "least_input", "bias")
LEAST = ("least_energy", "least_input")


@dataclass(frozen=True)
class Rule:
    """An operating-point rule: the kind, and for "bias" the fixed values (i, v) and ratios (i, j, r): x_i = r x_j
    (0-based indices of x_e)."""

    kind: str = "least_energy"
    values: tuple[tuple[int, float], ...] = ()
    ratios: tuple[tuple[int, int, float], ...] = ()
    given: bool = field(default=True, compare=False)
    """False when no rule was given and least_energy is the default."""

    def describe(self, names: Sequence[str]) -> str:
        if self.kind == "least_energy":
            return "least electrical energy that holds the force balance" + ("" if self.given else " (the default)")
        if self.kind == "least_input":
            return "least input |u|^2 that holds the force balance at rest"
        fixed = [f"{names[i]} = {v:.6g}" for i, v in self.values] + [f"{names[i]} = {r:.6g} {names[j]}"
                                                                      for i, j, r in self.ratios]
        return "bias " + ", ".join(fixed)

    def as_tuple(self) -> tuple:
        """The rule as plain data (what components.codegen prints into a generated plant class)."""
        return (self.kind, self.values, self.ratios, self.given)

    @classmethod
    def from_tuple(cls, data: Sequence[Any]) -> "Rule":
        kind, values, ratios, given = data
        return cls(kind, tuple((int(i), float(v)) for i, v in values),
                   tuple((int(i), int(j), float(r)) for i, j, r in ratios), bool(given))


class NoOperatingPoint(ValueError):
    """The rule finds no real x_e holding the force balance."""


def weights(rule: Rule, psi: np.ndarray, R_e: np.ndarray, J_e: np.ndarray, G_e: np.ndarray) -> np.ndarray:
    """The cost per unit of w_i = x_e_i^2 that a "least" rule minimises: the stored energy 1/2 Psi_ii (least_energy;
    the factor 1/2 does not change the choice) or, at rest, the input u = G_e^-1 (R_e - J_e) Psi x_e (the x_e-row of
    eq. open-loop elecmech with x_e' = 0), |u|^2 = sum_i ((R_e - J_e)_ii Psi_ii / G_e_ii)^2 w_i for diagonal R_e,
    J_e (then 0) and G_e (least_input)."""
    if rule.kind != "least_input":
        return np.asarray(psi)
    return (np.diag(R_e - J_e) * np.asarray(psi) / np.diag(G_e)) ** 2


def solve(rule: Rule, A: np.ndarray, b: np.ndarray, psi: np.ndarray, sign: float) -> tuple[np.ndarray, tuple]:
    """(x_e, branch) with A (x_e^2) = b by `rule`; `psi` the cost weights of a "least" rule (`weights`), `sign` the side of
    the solved roots (x_e_sign). The branch names the solved (energized) ports; it changes where x_e is not smooth."""
    n_m, n_e = A.shape
    if rule.kind in LEAST:
        if not all(np.all(np.isfinite(v)) for v in (A, b, psi)):      # an overflow in F*, A(q*) or the costs
            raise NoOperatingPoint(f"the force balance A(q) w = {np.real(b).tolist()} or the costs "
                                   f"{np.real(psi).tolist()} are not finite (an overflow)")
        vertices = []
        for B in combinations(range(n_e), n_m):
            AB = np.real(A[:, B])
            if abs(np.linalg.det(AB)) <= 1e-14 * max(float(np.max(np.abs(AB))), 1e-300) ** n_m:
                continue
            wB = np.linalg.solve(A[:, B], b)
            if not np.all(np.real(wB) >= 0):
                continue
            cost = float(np.real(np.asarray(psi)[list(B)] @ wB))
            if not math.isfinite(cost):                               # 0 x inf: no cost to compare (issue 40)
                raise NoOperatingPoint(f"the cost of the ports {B} is not finite (w = {np.real(wB).tolist()})")
            vertices.append((cost, B, wB))
        if not vertices:
            raise NoOperatingPoint(f"no w = x_e^2 >= 0 with n_m = {n_m} energized ports solves A(q) w = {np.real(b).tolist()}")
        best = min(c for c, _, _ in vertices)
        tied = sorted({i for c, B, _ in vertices if c <= best + 1e-12 * abs(best) for i in B})
        if len(tied) > n_m:                  # equal energy on several ports (identical coils): share it evenly
            w = _least_norm(A[:, tied], b)
            if np.all(np.real(w) > 0):
                x = np.zeros(n_e, dtype=w.dtype)
                x[tied] = sign * np.sqrt(w)
                return x, tuple(tied)
        _, B, wB = min(vertices, key=lambda v: v[0])
        x = np.zeros(n_e, dtype=wB.dtype)
        x[list(B)] = sign * np.sqrt(wB)
        return x, B
    F, M = _reduced(rule, A, n_e)
    wF = np.linalg.solve(M, b - _fixed_force(rule, A))
    if not np.all(np.real(wF) > 0):
        raise NoOperatingPoint(f"with the bias, the solved w = x_e^2 = {np.real(wF).tolist()} has an entry <= 0")
    x = np.zeros(n_e, dtype=np.result_type(wF, float))
    x[list(F)] = sign * np.sqrt(wF)
    for i, v in rule.values:
        x[i] = v
    for i, j, r in rule.ratios:
        x[i] = r * x[j]
    return x, tuple(F)


def rate(rule: Rule, branch: tuple, A: np.ndarray, A_dot: np.ndarray, b_dot: np.ndarray, x: np.ndarray) -> np.ndarray:
    """x_e' along the branch: differentiate A w = b in time, A w' = b' - A' w, with w' = 0 on the ports the rule
    holds at zero or at a value, w_i' = r^2 w_j' on a ratio, then x_i' = w_i' / (2 x_i)."""
    n_e = A.shape[1]
    w = x * x
    rhs = b_dot - A_dot @ w
    x_dot = np.zeros(n_e, dtype=np.result_type(rhs, x))
    if rule.kind in LEAST:
        B = list(branch)
        if len(B) == A.shape[0]:
            wB_dot = np.linalg.solve(A[:, B], rhs)
        else:                                # the even share w_B = A_B^T (A_B A_B^T)^-1 b, differentiated
            AB, AB_dot = A[:, B], A_dot[:, B]
            G = AB @ AB.T
            y = np.linalg.solve(G, AB @ w[B])                          # A_B w_B = b
            y_dot = np.linalg.solve(G, b_dot - (AB_dot @ AB.T + AB @ AB_dot.T) @ y)
            wB_dot = AB_dot.T @ y + AB.T @ y_dot
        x_dot[B] = wB_dot / (2 * x[B])
        return x_dot
    F, M = _reduced(rule, A, n_e)
    wF_dot = np.linalg.solve(M, rhs)
    x_dot[list(F)] = wF_dot / (2 * x[list(F)])
    for i, j, r in rule.ratios:
        x_dot[i] = r * x_dot[j]
    return x_dot


def _least_norm(A: np.ndarray, b: np.ndarray) -> np.ndarray:
    """The solution of A w = b (A of full row rank) with the least |w|: A^T (A A^T)^-1 b."""
    return A.T @ np.linalg.solve(A @ A.T, b)


def _reduced(rule: Rule, A: np.ndarray, n_e: int) -> tuple[list[int], np.ndarray]:
    """The solved ports F and the n_m x n_m matrix M with A w = M w_F + (fixed values' force): a ratio x_i = r x_j
    adds r^2 A[:, i] to column j."""
    held = {i for i, _ in rule.values} | {i for i, _, _ in rule.ratios}
    F = [i for i in range(n_e) if i not in held]
    M = A[:, F].astype(np.result_type(A, float), copy=True)
    for i, j, r in rule.ratios:
        M[:, F.index(j)] += r * r * A[:, i]
    return F, M


def _fixed_force(rule: Rule, A: np.ndarray) -> np.ndarray:
    out = np.zeros(A.shape[0], dtype=np.result_type(A, float))
    for i, v in rule.values:
        out = out + A[:, i] * v * v
    return out


def switches(times: Sequence[float], branches: Sequence[tuple], names: Sequence[str]) -> str | None:
    """Where the energized ports change along sampled times: why x_e*(t) is not C^3 there (None if never)."""
    for k in range(1, len(branches)):
        if branches[k] != branches[k - 1]:
            a = ", ".join(names[i] for i in branches[k - 1]) or "none"
            b = ", ".join(names[i] for i in branches[k]) or "none"
            return (f"x_e*(t) switches from port(s) {a} to {b} between t = {times[k - 1]:.6g} s and {times[k]:.6g} s: "
                    "a port turns on or off through sqrt(w), so x_e*(t) is not differentiable there (Definition 1 "
                    "needs x_e*' and the tracking laws its derivatives; choose a bias instead)")
    return None
