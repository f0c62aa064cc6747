r"""The Limit interface: bounds on the joint velocity :math:`\dot q` for the next step Δt.

A limit tightens the velocity box lb ≤ q̇ ≤ ub (nv,) in place with
:meth:`Limit.apply`. ``constant`` limits (the same bounds every step, e.g. speed
limits) are applied once when a controller is built; the others every step.

When both position and velocity limits are present a joint found outside its range
(possible in physics mode) may return at full speed: the position bound is clipped into
the velocity box, so the box is never empty for valid limits.
"""

from __future__ import annotations

import numpy as np


class Limit:
    """Base class of the limits: a box on q̇ for the step Δt."""

    constant = False  # True: the same bounds every step (applied once)

    def apply(self, dt: float, lb: np.ndarray, ub: np.ndarray) -> None:
        """Tighten the velocity box [lb, ub] (nv,) in place."""
        raise NotImplementedError


def as_slice(index: np.ndarray):
    """A slice for consecutive indices (views, no fancy-index copies), else the array."""
    if len(index) and np.array_equal(index, np.arange(index[0], index[0] + len(index))):
        return slice(int(index[0]), int(index[0]) + len(index))
    return np.asarray(index, dtype=int)


def order_limits(limits) -> list:
    """Constant limits (velocity) first, so position bounds are clipped into their box."""
    return sorted(limits, key=lambda lim: 0 if lim.constant else 1)
