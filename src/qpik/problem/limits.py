"""The step's inequalities: the box lb ≤ q̇ ≤ ub and the general rows G q̇ ≤ h.

Each limit is written through its one entry point, :meth:`~qpik.limits.limit.Limit.apply`.
Constant limits (speed bounds) are written once, into the constant box; every step
starts from a copy of it and lets the other limits tighten it and write their rows.
"""

from __future__ import annotations

import math
from typing import Sequence

import numpy as np

from ..errors import InvalidInput
from ..limits.limit import Limit
from .rows import row_slices

# Up to this many dofs a point is checked against the box in floats: NumPy's per-call
# cost outweighs the loop (measured: 30 dofs 3.4 µs in floats, 4.0 in three calls).
FLOAT_CHECK_MAX_DOFS = 40


class Inequalities:
    """The box and the general rows of a set of limits, for the control period ``dt``.

    Args:
        nv: the number of dofs.
        limits: the limits.
        dt: the control period (s).
        out: the arrays to write the step into, (lb, ub, G, h) (a solver's own, say),
            or None for arrays of its own.

    Attributes:
        limits: the limits, constant ones first (position bounds are then clipped into
            the speed box).
        lower0, upper0: the constant box (nv,), written once.
        lb, ub, G, h: the step's box and rows, after :meth:`write`.
        row_limits: (limit, its rows of G and h) for each limit that writes rows.
    """

    def __init__(self, nv: int, limits: Sequence[Limit], dt: float, out: tuple | None = None):
        self.limits = sorted(limits, key=lambda limit: 0 if limit.constant else 1)
        self.dt = dt
        self.lower0, self.upper0 = np.full(nv, -np.inf), np.full(nv, np.inf)
        for limit in self.limits:
            if limit.constant:
                if limit.inequality_rows:
                    raise InvalidInput(f"{type(limit).__name__}: a constant limit writes the box only (no rows)")
                limit.apply(dt, self.lower0, self.upper0)
        changing = [limit for limit in self.limits if not limit.constant]
        sizes = [limit.inequality_rows for limit in changing]
        self.rows = sum(sizes)
        self.lb, self.ub, self.G, self.h = out if out is not None else \
            (np.zeros(nv), np.zeros(nv), np.zeros((self.rows, nv)), np.zeros(self.rows))
        self.row_limits = [(limit, rows) for limit, rows in zip(changing, row_slices(sizes)) if limit.inequality_rows]
        lb, ub = self.lb, self.ub
        self._scratch = np.zeros(nv)
        self._in_floats = nv <= FLOAT_CHECK_MAX_DOFS
        self._writes = [(limit.apply, (dt, lb, ub)) if not limit.inequality_rows else
                        (limit.apply, (dt, lb, ub, self.G[rows], self.h[rows]))
                        for limit, rows in zip(changing, row_slices(sizes))]

    def write(self) -> None:
        """The step's box into ``lb``, ``ub`` and rows into ``G``, ``h``."""
        np.copyto(self.lb, self.lower0)
        np.copyto(self.ub, self.upper0)
        for apply, arguments in self._writes:
            apply(*arguments)

    def admits(self, x: np.ndarray) -> bool:
        """Whether x is finite, in the step's box and under its rows (exact comparisons:
        a point on a bound is inside)."""
        if self._in_floats:
            values = x.tolist()
            if not math.isfinite(sum(values)):  # NaN or ±inf anywhere (an absent bound admits ±inf)
                return False
            for value, low, high in zip(values, self.lb.tolist(), self.ub.tolist()):
                if not low <= value <= high:
                    return False
        else:
            gap = self._scratch
            np.subtract(x, self.lb, out=gap)
            np.minimum(gap, self.ub - x, out=gap)  # NaN (a NaN x, or ±inf on an absent bound) fails
            if not np.minimum.reduce(gap) >= 0.0:
                return False
        return not self.rows or bool((np.dot(self.G, x) <= self.h).all())
