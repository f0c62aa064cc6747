r"""The Limit interface: inequalities on the joint velocity :math:`\dot q` for the next step Δt,
in every world.

A limit has one entry point, :meth:`Limit.apply`: it tightens the box
lower ≤ q̇ ≤ upper (each (N, nv)) in place and/or writes its ``inequality_rows`` general
rows :math:`G\dot q \le h` (G (N, rows, nv), h (N, rows); a row that does not bind this
step may be 0 ≤ +inf). ``constant`` limits (the same box every step, e.g. speed limits)
are applied once, when a controller is built. A position bound is clipped into the speed
box, so a joint found outside its range returns at full speed and the box is never empty
for valid limits.
"""

from __future__ import annotations

import numpy as np

from ..errors import InvalidInput
from ..tasks.inputs import PARAMETER_LIMIT


class Limit:
    """Base class of the limits: a box on q̇ and/or general rows G q̇ ≤ h for the step Δt.

    Attributes:
        constant: the same box every step (written once; such a limit writes no rows).
        inequality_rows: how many rows :meth:`apply` writes into G and h (per world).
        ranges: the joint ranges the limit keeps q inside (a
            :class:`~qpik.robot.JointLimits`: position limits), else None.
    """

    constant = False
    inequality_rows = 0
    ranges = None

    def apply(self, dt: float, lower: np.ndarray, upper: np.ndarray, G: np.ndarray | None = None,
              h: np.ndarray | None = None) -> None:
        """Write this limit for a step of ``dt`` seconds in every world: tighten the box
        [lower, upper] (N, nv) in place, and/or write its rows G (N, rows, nv), h (N, rows)."""


def order_limits(limits) -> list:
    """Constant limits (velocity) first, so position bounds are clipped into their box."""
    return sorted(limits, key=lambda lim: 0 if lim.constant else 1)


def bound_values(value, size: int, what: str, entries: str = "") -> np.ndarray:
    """A limit's bounds: a number for every entry or ``size`` numbers (``entries`` says
    which, for the message), each positive and at most :data:`PARAMETER_LIMIT`, or +inf
    for no bound.

    Raises:
        InvalidInput: a wrong shape, or a bound that is not positive (NaN, zero,
            negative) or finite beyond the limit.
    """
    try:
        bound = np.broadcast_to(np.asarray(value, dtype=float), (size,)).copy()
    except (TypeError, ValueError):
        raise InvalidInput(f"{what} must be a number or {size} numbers{entries}, got {value!r}") from None
    return checked_bounds(bound, what, value)


def checked_bounds(bound: np.ndarray, what: str, given) -> np.ndarray:
    """``bound``, or InvalidInput (naming ``given``) for an entry that is not positive (NaN
    fails) or is finite beyond :data:`PARAMETER_LIMIT` (+inf: no bound)."""
    if not np.all((bound > 0) & ((bound <= PARAMETER_LIMIT) | (bound == np.inf))):
        raise InvalidInput(f"{what} must be positive and at most {PARAMETER_LIMIT:g} (inf for none), got {given!r}")
    return bound
