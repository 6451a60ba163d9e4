"""The one symbolic statement of a described plant's model (eq. open-loop elecmech), which every printer takes.

`plant_expressions(desc)` differentiates the description's M, V, Psi once with sympy and builds, in the
description's own symbols (q, p, x_e, u and the parameters):

    V(q), grad V, hess V; Psi(q), d Psi/d q_k, d^2 Psi/d q_k d q_l; M^-1 (constant M, or n_m <= 3)
    H(eta) = 1/2 p^T M(q)^-1 p + V(q) + 1/2 x_e^T Psi(q) x_e                 (eq. open-loop elecmech)
    grad H;  f(eta, u) = F grad H + g u,  F = [[0, I, 0], [-I, -R_m, 0], [0, 0, J_e - R_e]], g = [0; 0; G_e]
    df/deta (= F hess H) and df/du (= g)
    the event indicator of the domain (the margin to its boundary, components: domain_margin)

Printers: components.codegen (Python, the model functions of the generated plant classes) and
components.c_codegen (C99, the native FMUs). A printer never differentiates on its own.
"""
from __future__ import annotations

from dataclasses import dataclass

import sympy

from .description import Description


@dataclass(frozen=True)
class PlantExpressions:
    """The model of one description as sympy expressions (module docstring); matrices are sympy Matrices,
    `dPsi[k]` is d Psi / d q_k and `d2Psi[k][l]` is d^2 Psi / d q_k d q_l."""

    desc: Description
    q: tuple[sympy.Symbol, ...]
    p: tuple[sympy.Symbol, ...]
    x_e: tuple[sympy.Symbol, ...]
    u: tuple[sympy.Symbol, ...]
    V: sympy.Expr
    grad_V: sympy.Matrix
    hess_V: sympy.Matrix
    Psi: sympy.Matrix
    dPsi: tuple[sympy.Matrix, ...]
    d2Psi: tuple[tuple[sympy.Matrix, ...], ...]

    @property
    def eta(self) -> tuple[sympy.Symbol, ...]:
        """The state (q, p, x_e) of eq. (open-loop elecmech)."""
        return self.q + self.p + self.x_e

    @property
    def M_inv(self) -> sympy.Matrix:
        """M(q)^-1 (symbolic inverse: constant M, or n_m <= 3)."""
        if not self.desc.constant_mass and self.desc.n_m > 3:
            raise ValueError(f"{self.desc.source}: [model] M: depends on q with n_m = {self.desc.n_m} > 3 "
                             "(no symbolic inverse)")
        return _inverse(self.desc.M)

    @property
    def H(self) -> sympy.Expr:
        """H(eta) = 1/2 p^T M^-1 p + V(q) + 1/2 x_e^T Psi(q) x_e, eq. (open-loop elecmech)."""
        p, x = sympy.Matrix(self.p), sympy.Matrix(self.x_e)
        return (p.T * self.M_inv * p)[0, 0] / 2 + self.V + (x.T * self.Psi * x)[0, 0] / 2

    @property
    def grad_H(self) -> sympy.Matrix:
        return sympy.Matrix([self.H]).jacobian(list(self.eta)).T

    @property
    def hess_H(self) -> sympy.Matrix:
        """The Hessian of H (n x n): the output derivatives H'' = eta'^T hess H eta' + grad H . eta''."""
        return sympy.hessian(self.H, list(self.eta))

    @property
    def F(self) -> sympy.Matrix:
        """The structure matrix J - R of eq. (open-loop elecmech)."""
        d = self.desc
        m, e = d.n_m, d.n_e
        F = sympy.zeros(2 * m + e, 2 * m + e)
        F[:m, m:2 * m] = sympy.eye(m)
        F[m:2 * m, :m] = -sympy.eye(m)
        F[m:2 * m, m:2 * m] = -d.R_m
        F[2 * m:, 2 * m:] = d.J_e - d.R_e
        return F

    @property
    def g(self) -> sympy.Matrix:
        """The input matrix [0; 0; G_e] of eq. (open-loop elecmech)."""
        d = self.desc
        return sympy.zeros(2 * d.n_m, d.n_e).col_join(d.G_e)

    @property
    def f(self) -> sympy.Matrix:
        """eta' = F grad H(eta) + g u, eq. (open-loop elecmech)."""
        return self.F * self.grad_H + self.g * sympy.Matrix(self.u)

    @property
    def jacobian(self) -> sympy.Matrix:
        """df/deta (n x n): F hess H, differentiated from f itself."""
        return self.f.jacobian(list(self.eta))

    @property
    def domain_margin(self) -> sympy.Expr | None:
        """The margin to the boundary of the admissible domain (positive inside; None: no boundary), as
        components' domain_margin computes it: a one-degree-of-freedom plant with linear inequalities
        a q + b > 0, the distance (a q + b) / |a| to the nearer end; otherwise the smallest g_j(q)."""
        d = self.desc
        margins = list(d.domain_margins)
        if not margins:
            return None
        if d.n_m == 1 and d.n_e == 1 and d.constant_mass:
            q = self.q[0]
            polys = [sympy.Poly(g, q) if g.is_polynomial(q) else None for g in margins]
            if all(poly is not None and poly.degree() == 1 for poly in polys):
                margins = [g / sympy.Abs(poly.all_coeffs()[0]) for g, poly in zip(margins, polys)]  # type: ignore[union-attr]
        return margins[0] if len(margins) == 1 else sympy.Min(*margins)


def _inverse(M: sympy.Matrix) -> sympy.Matrix:
    return M.inv().applyfunc(sympy.simplify)


def plant_expressions(desc: Description) -> PlantExpressions:
    """The symbolic model of `desc` (module docstring): the derivatives of V and Psi, taken here once."""
    qs = desc.q_symbols
    V, Psi = desc.V, desc.Psi
    return PlantExpressions(
        desc=desc, q=tuple(qs), p=tuple(desc.p_symbols), x_e=tuple(desc.x_e_symbols), u=tuple(desc.u_symbols),
        V=V, grad_V=sympy.Matrix([V.diff(qk) for qk in qs]),
        hess_V=sympy.Matrix(len(qs), len(qs), [V.diff(qk, ql) for qk in qs for ql in qs]),
        Psi=Psi, dPsi=tuple(Psi.diff(qk) for qk in qs),
        d2Psi=tuple(tuple(Psi.diff(qk, ql) for ql in qs) for qk in qs))
