r"""The Limit interface: inequalities on the joint velocity :math:`\dot q` for the next step Δt.

A limit has one entry point, :meth:`Limit.apply`, which writes its part of the step's
inequalities:

- a box lb ≤ q̇ ≤ ub (nv,), tightened in place (joint position and velocity limits:
  every solver takes boxes natively, and the closed-form step checks them cheaply);
- and/or ``inequality_rows`` general rows :math:`G\dot q \le h` (collision avoidance).
  A row that does not bind this step may be written as 0 ≤ +inf.

``constant`` limits (the same box every step, e.g. speed limits) are written once, when a
controller is built; the others every step.

When both position and velocity limits are present a joint found outside its range
(possible in physics mode) may return at full speed: the position bound is clipped into
the velocity box, so the box is never empty for valid limits.
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
