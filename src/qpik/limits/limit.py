r"""The Limit interface: inequalities on the joint velocity :math:`\dot q` for the next step Δt.

A limit has one entry point, :meth:`Limit.apply`: it tightens the box lb ≤ q̇ ≤ ub in
place and/or writes its ``inequality_rows`` general rows :math:`G\dot q \le h` (a row that
does not bind this step may be 0 ≤ +inf). ``constant`` limits (the same box every step,
e.g. speed limits) are applied once, when a controller is built. A position bound is
clipped into the speed box, so a joint found outside its range returns at full speed
and the box is never empty for valid limits.
"""

from __future__ import annotations

import numpy as np


class Limit:
    """Base class of the limits: a box on q̇ and/or general rows G q̇ ≤ h for the step Δt.

    Attributes:
        constant: the same box every step (written once; such a limit writes no rows).
        inequality_rows: how many rows :meth:`apply` writes into G and h.
        ranges: the joint ranges the limit keeps q inside (a
            :class:`~qpik.robot.JointLimits`: position limits), else None.
        takes_lists: whether :meth:`apply` also takes the box as lists of floats (a
            controller then keeps the box of a robot of a few dofs in floats).
    """

    constant = False
    inequality_rows = 0
    ranges = None
    takes_lists = False

    def apply(self, dt: float, lb: np.ndarray, ub: np.ndarray, G: np.ndarray | None = None,
              h: np.ndarray | None = None) -> None:
        """Write this limit for a step of ``dt`` seconds: tighten the box [lb, ub] (nv,)
        in place (NumPy arrays; lists of floats too where ``takes_lists``), and/or write
        its rows G (inequality_rows x nv) and h (inequality_rows,)."""


def as_slice(index: np.ndarray):
    """A slice for consecutive indices (views, no fancy-index copies), else the array."""
    if len(index) and np.array_equal(index, np.arange(index[0], index[0] + len(index))):
        return slice(int(index[0]), int(index[0]) + len(index))
    return np.asarray(index, dtype=int)


def order_limits(limits) -> list:
    """Constant limits (velocity) first, so position bounds are clipped into their box."""
    return sorted(limits, key=lambda lim: 0 if lim.constant else 1)
