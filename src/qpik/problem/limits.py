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
from ..limits.limit import Limit, order_limits
from .rows import row_slices

# A box of up to this many dofs (with no general rows) is written and checked in floats
# when every limit that changes it takes lists (``Limit.takes_lists``): NumPy's per-call
# cost exceeds the arithmetic on arrays this small.
FLOAT_BOX_MAX_DOFS = 32


class Inequalities:
    """The box and the general rows of ``limits`` (constant ones first: position bounds
    are then clipped into the speed box) for the period ``dt``, written by :meth:`write`
    into ``lb``, ``ub``, ``G``, ``h`` (``out``: a solver's own arrays, or None). The
    constant box is ``lower0``, ``upper0``; ``rows`` counts the general rows and
    ``row_limits`` gives each limit that writes some with its rows."""

    def __init__(self, nv: int, limits: Sequence[Limit], dt: float, out: tuple | None = None):
        self.limits = order_limits(limits)
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
        self._lb, self._ub, self.G, self.h = out if out is not None else \
            (np.zeros(nv), np.zeros(nv), np.zeros((self.rows, nv)), np.zeros(self.rows))
        self.row_limits = [(limit, rows) for limit, rows in zip(changing, row_slices(sizes)) if limit.inequality_rows]
        self._writes = [(limit.apply, (dt, self._lb, self._ub) if not limit.inequality_rows else
                         (dt, self._lb, self._ub, self.G[rows], self.h[rows]))
                        for limit, rows in zip(changing, row_slices(sizes))]
        self._in_floats = nv <= FLOAT_BOX_MAX_DOFS and not self.rows and all(lim.takes_lists for lim in changing)
        self._lower0, self._upper0 = self.lower0.tolist(), self.upper0.tolist()
        self.lower, self.upper = list(self._lower0), list(self._upper0)  # the box in floats (small boxes)
        self._stale = False  # whether lb and ub lag behind the box in floats
        self._scratch, self._check_in_floats = np.zeros(nv), nv <= FLOAT_BOX_MAX_DOFS
        # A box finite on every dof (limits only tighten it) refuses NaN and ±inf by its comparisons.
        self._finite_box = bool(np.isfinite(self.lower0).all() and np.isfinite(self.upper0).all())

    def write(self) -> None:
        """The step's box and rows."""
        dt = self.dt
        if self._in_floats:
            lower, upper = self._lower0.copy(), self._upper0.copy()
            for apply, _ in self._writes:
                apply(dt, lower, upper)
            self.lower, self.upper, self._stale = lower, upper, True
            return
        np.copyto(self._lb, self.lower0)
        np.copyto(self._ub, self.upper0)
        for apply, arguments in self._writes:
            apply(*arguments)

    @property
    def lb(self) -> np.ndarray:
        """The step's lower bounds (nv,)."""
        self.sync()
        return self._lb

    @property
    def ub(self) -> np.ndarray:
        """The step's upper bounds (nv,)."""
        self.sync()
        return self._ub

    def sync(self) -> None:
        """A box computed in floats written into ``lb`` and ``ub`` (which a solver reads)."""
        if self._stale:
            self._lb[:], self._ub[:] = self.lower, self.upper
            self._stale = False

    def box(self) -> tuple[list, list]:
        """The step's box as lists of floats."""
        return (self.lower, self.upper) if self._in_floats else (self._lb.tolist(), self._ub.tolist())

    def admits(self, x: np.ndarray) -> bool:
        """Whether x is finite, in the step's box and under its rows (exact comparisons:
        a point on a bound is inside)."""
        if self._check_in_floats:  # in floats (the box's own, or its arrays')
            values = x.tolist()
            if not (self._finite_box or math.isfinite(sum(values))):  # an absent bound admits ±inf
                return False
            lower, upper = (self.lower, self.upper) if self._in_floats else self.box()
            for value, low, high in zip(values, lower, upper):
                if not low <= value <= high:
                    return False
        else:
            gap = self._scratch
            np.subtract(x, self._lb, gap)
            np.minimum(gap, self._ub - x, gap)  # NaN (a NaN x, or ±inf on an absent bound) fails
            if not np.minimum.reduce(gap) >= 0.0:
                return False
        return not self.rows or bool((self.G.dot(x) <= self.h).all())
