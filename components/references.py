"""Reference jets (q*, q*', q*'', q*''') for the tracking and regulation controllers.

A jet is turned into a feasible trajectory eta*(t) and x_e*'(t) by the plant
(`EMPlant.feasible_state`, Definition 1). `Reference.derivatives` gives q* and its derivatives of any
order, analytically: what the Reference FMU answers to fmi2GetRealOutputDerivatives (its output
q_star_dddot of order k is q*^(3+k)).
"""
from __future__ import annotations

import math

import numpy as np

from .parameters import Parameter, resolve
from .ph_plant import Jet

# the reference jet as variables (name, unit, description): the outputs of the Reference FMU and the inputs
# of the tracking controllers; entry k is q*^(k)
JET_VARIABLES = (("q_star", "m", "reference position q*"),
                 ("q_star_dot", "m/s", "first derivative of the reference position, q*'"),
                 ("q_star_ddot", "m/s2", "second derivative of the reference position, q*''"),
                 ("q_star_dddot", "m/s3", "third derivative of the reference position, q*'''"))


class Reference:
    """A reference position q*(t) with three continuous derivatives."""

    PARAMETERS: dict[str, Parameter] = {}
    name = "reference"

    def __init__(self, **params: float):
        self.params = resolve(self.PARAMETERS, params, self.name)
        for k, v in self.params.items():
            setattr(self, k, v)

    def values(self, t: float) -> tuple[float, float, float, float]:
        """(q*, q*', q*'', q*''') at time t, as numbers."""
        return self.derivatives(t, 3)          # a subclass may write it out (the monolithic loop calls it often)

    def jet(self, t: float) -> Jet:
        """The jet at time t as arrays of shape (1,)."""
        return Jet(*(np.array([v]) for v in self.values(t)))

    def derivatives(self, t: float, order: int) -> tuple[float, ...]:
        """(q*, q*', ..., q*^(order)) at time t, as numbers; `values(t)` is its first four entries."""
        raise NotImplementedError


def _check_order(order: int) -> int:
    if isinstance(order, bool) or not (isinstance(order, (int, np.integer)) and order >= 0):
        raise ValueError(f"derivative order {order!r} must be an integer >= 0")
    return int(order)


class Constant(Reference):
    """Constant set-point q*(t) = q_d."""

    name = "constant reference"
    PARAMETERS = {p.name: p for p in [
        Parameter("q_d", 3e-5, "m", "set-point position", "any"),
    ]}

    def values(self, t: float) -> tuple[float, float, float, float]:
        return self.q_d, 0.0, 0.0, 0.0

    def derivatives(self, t: float, order: int) -> tuple[float, ...]:
        return (self.q_d,) + (0.0,) * _check_order(order)


class Sinusoid(Reference):
    """q*(t) = offset + amplitude sin(omega t + phase); the paper's MEMS q* = 0.05 + 0.05 sin 30t (eq. csim)."""

    name = "sinusoidal reference"
    PARAMETERS = {p.name: p for p in [
        Parameter("offset", 0.05, "m", "mean position", "any"),
        Parameter("amplitude", 0.05, "m", "amplitude", "any"),
        Parameter("omega", 30.0, "rad/s", "angular frequency", ">= 0"),
        Parameter("phase", 0.0, "rad", "phase at t = 0", "any"),
    ]}

    def values(self, t: float) -> tuple[float, float, float, float]:
        a, w, th = self.amplitude, self.omega, self.omega * t + self.phase
        s, c = math.sin(th), math.cos(th)
        return self.offset + a * s, a * w * c, -a * w ** 2 * s, -a * w ** 3 * c

    def derivatives(self, t: float, order: int) -> tuple[float, ...]:
        """q*^(k) = amplitude omega^k sin(omega t + phase + k pi/2), plus offset for k = 0."""
        a, w, th = self.amplitude, self.omega, self.omega * t + self.phase
        s, c = math.sin(th), math.cos(th)
        cycle = (s, c, -s, -c)                               # sin(th + k pi/2) for k mod 4
        return tuple((self.offset if k == 0 else 0.0) + a * w ** k * cycle[k % 4]
                     for k in range(_check_order(order) + 1))


class SmoothStep(Reference):
    """Set-point transition from q_from to q_to starting at t_start and lasting `duration`.

    Uses the degree-7 polynomial s(tau) = 35 tau^4 - 84 tau^5 + 70 tau^6 - 20 tau^7, whose first
    three derivatives vanish at tau = 0 and tau = 1, so q*, q*', q*'', q*''' are continuous.
    """

    name = "smooth transition reference"
    PARAMETERS = {p.name: p for p in [
        Parameter("q_from", 2e-5, "m", "set-point before the transition", "any"),
        Parameter("q_to", 3e-5, "m", "set-point after the transition", "any"),
        Parameter("t_start", 0.0, "s", "start of the transition", ">= 0"),
        Parameter("duration", 1e-3, "s", "duration of the transition"),
    ]}

    S = {4: 35.0, 5: -84.0, 6: 70.0, 7: -20.0}                 # s(tau) = sum_n S[n] tau^n

    def derivatives(self, t: float, order: int) -> tuple[float, ...]:
        """q*^(k) = (q_to - q_from) s^(k)(tau) / duration^k with tau = (t - t_start) / duration.

        Derivatives of order 4 and higher jump at tau = 0 and tau = 1 (s''''(0) = 840); they are taken
        from the right, the side of a communication step that starts at t: the polynomial's on
        0 <= tau < 1, zero elsewhere. Orders 0-3 are continuous and equal `values`."""
        order = _check_order(order)
        tau = (t - self.t_start) / self.duration
        if not 0.0 <= tau < 1.0:                                # constant before and after the transition
            return (self.q_to if tau >= 1.0 else self.q_from,) + (0.0,) * order
        d, T = self.q_to - self.q_from, self.duration
        out = []
        for k in range(order + 1):
            sk = sum(c * math.perm(n, k) * tau ** (n - k) for n, c in self.S.items() if n >= k)
            out.append((self.q_from if k == 0 else 0.0) + d * sk / T ** k)
        return tuple(out)


KINDS = {"constant": Constant, "sinusoid": Sinusoid, "smooth_step": SmoothStep}
