r"""The Limit interface: inequalities on the joint velocity :math:`\dot q` for the next step Δt.

A limit contributes either or both of

- a box lb ≤ q̇ ≤ ub (nv,), tightened in place by :meth:`Limit.apply` (joint position
  and velocity limits: every solver takes boxes natively, the fast path);
- ``inequality_rows`` general rows :math:`G\dot q \le h`, written in place by
  :meth:`Limit.fill_inequalities` (collision avoidance). A row that does not bind this
  step may be written as 0 ≤ +inf.

``constant`` limits (the same bounds every step, e.g. speed limits) are applied once when
a controller is built; the others every step.

When both position and velocity limits are present a joint found outside its range
(possible in physics mode) may return at full speed: the position bound is clipped into
the velocity box, so the box is never empty for valid limits.
"""

from __future__ import annotations

import numpy as np


class Limit:
    """Base class of the limits: a box on q̇ and/or general rows G q̇ ≤ h for the step Δt.

    Attributes:
        constant: the same bounds every step (a controller applies them once).
        box: whether :meth:`apply` tightens the box.
        inequality_rows: how many rows :meth:`fill_inequalities` writes.
    """

    constant = False
    box = True
    inequality_rows = 0

    def apply(self, dt: float, lb: np.ndarray, ub: np.ndarray) -> None:
        """Tighten the velocity box [lb, ub] (nv,) in place."""

    def apply_to_lists(self, dt: float, lower: list, upper: list) -> None:
        """:meth:`apply` on the box held as lists of floats (for a controller that works on
        floats), in place."""
        lb, ub = np.array(lower), np.array(upper)
        self.apply(dt, lb, ub)
        lower[:], upper[:] = lb.tolist(), ub.tolist()

    def fill_inequalities(self, dt: float, G: np.ndarray, h: np.ndarray) -> None:
        """Write this limit's rows G (rows x nv) and h (rows,) in place."""


def as_slice(index: np.ndarray):
    """A slice for consecutive indices (views, no fancy-index copies), else the array."""
    if len(index) and np.array_equal(index, np.arange(index[0], index[0] + len(index))):
        return slice(int(index[0]), int(index[0]) + len(index))
    return np.asarray(index, dtype=int)


def order_limits(limits) -> list:
    """Constant limits (velocity) first, so position bounds are clipped into their box."""
    return sorted(limits, key=lambda lim: 0 if lim.constant else 1)
