"""Two small pieces that the coupling's estimates share: the points before the current time (`History`)
and a Taylor polynomial's value (`taylor`)."""
from __future__ import annotations

from typing import Any, Sequence

KEEP = 3        # points kept: a rollback over two substeps (stepcontrol.py) leaves the point before them


class History:
    """The points (t, data) recorded at communication points before the current one. A step that is rolled
    back and retried must not see the abandoned point: `before(t)` drops every point at or after t."""

    def __init__(self) -> None:
        self.points: list[tuple[float, Any]] = []

    def before(self, t: float) -> list[tuple[float, Any]]:
        """The points before t (the points at or after t are dropped), oldest first."""
        points = self.points
        while points and points[-1][0] >= t:
            points.pop()
        return points

    def last(self, t: float) -> tuple[float, Any] | None:
        """The latest point before t, or None."""
        points = self.before(t)
        return points[-1] if points else None

    def add(self, t: float, data: Any) -> None:
        """Record the point t (after the points before it), keeping the last KEEP."""
        points = self.before(t)
        points.append((t, data))
        del points[:-KEEP]

    def clear(self) -> None:
        self.points.clear()

    def __len__(self) -> int:
        return len(self.points)


def taylor(value: float, derivatives: Sequence[float], h: float) -> float:
    """value + sum_j derivatives[j-1] h^j / j!: the polynomial an input follows over a step of h."""
    p, term = value, 1.0
    for j, d in enumerate(derivatives, start=1):
        term *= h / j
        p += d * term
    return p
