"""Joint position limits with a velocity damper near the bounds."""

from __future__ import annotations

import numpy as np

from ..errors import InvalidInput
from ..robot import JointLimits
from ..tasks.inputs import as_index, positive_scalar
from .limit import Limit


class JointPositionLimit(Limit):
    r"""Keep limited joints inside their range at the end of the step, in every world.

    The step may cover a fraction ``gain`` of the distance to each bound:
    :math:`(l - q)\,g/\Delta t \le \dot q \le (u - q)\,g/\Delta t`. Within ``influence`` of a
    bound the speed toward it is at most ``damper_rate`` times the distance over the
    influence (a velocity damper: the joint slows down exponentially as it arrives), never
    more than the step bound. Clipped into the speed box: a joint found outside its range
    returns at full speed and the box is never empty.

    Args:
        robot: the robot (one world or N).
        limits: the ranges to enforce (default: the model's ``range`` attributes).
        gain: fraction in (0, 1] of the remaining distance that one step may cover.
        influence: distance to a bound below which the velocity damper acts
            (0 disables the damper).
        damper_rate: ξ (joint units/s): once the distance d to a bound is below
            ``influence``, the speed toward it is at most ξ d / influence.
        margin: the bounds are pulled in by this much (joint units), so that rounding in
            q + q̇Δt never lands a hair outside the range.

    Raises:
        InvalidInput: a parameter that is not a single finite number in its range (at
            most 1e12), or a range narrower than twice the margin.
    """

    def __init__(self, robot, limits: JointLimits | None = None, gain: float = 1.0,
                 influence: float = 0.0, damper_rate: float = 20.0, margin: float = 1e-10):
        self.limits = self.ranges = robot.joint_limits if limits is None else limits
        gain = positive_scalar(gain, "position-limit gain")
        if gain > 1.0:
            raise InvalidInput(f"position-limit gain must lie in (0, 1], got {gain}")
        margin = positive_scalar(margin, "position-limit margin", allow_zero=True)
        influence = positive_scalar(influence, "position-limit influence (of the damper)", allow_zero=True)
        damper_rate = positive_scalar(damper_rate, "position-limit damper rate")
        narrow = ~(self.limits.upper - self.limits.lower > 2.0 * margin)
        if narrow.any():
            bad = [f"{n} [{lo:g}, {hi:g}]" for n, lo, hi, b in zip(self.limits.names, self.limits.lower,
                                                                 self.limits.upper, narrow) if b]
            raise InvalidInput(f"joint range narrower than twice the limit margin ({margin:g}) or empty: "
                               f"{', '.join(bad)}")
        self.robot, self.gain, self.influence, self.damper_rate, self.margin = robot, gain, influence, damper_rate, \
            margin
        n, k = robot.n, len(self.limits.names)
        # Worlds last (NumPy's loops run along the worlds, not along a few joints): the lower
        # and upper bounds (k, 1), pulled in by the margin, and the step to each (2, k, N).
        self._bounds = (self.limits.lower + margin)[:, None], (self.limits.upper - margin)[:, None]
        self._qpos, self._dofs = as_index(self.limits.qpos_index), as_index(self.limits.dof_index)
        self._steps, self._factor = np.empty((2, k, n)), np.empty((2, k, n))
        self._rate, self._rate_value = np.empty((2, k, n)), None  # gain/dt at full shape (a same-shape product)
        self._near, self._rows = np.empty((2, k, n), dtype=bool), tuple(self._steps)  # rows: low, high
        self._kept = None  # (the box it was given, _views' views of q and of the box), while consecutive

    def apply(self, dt: float, lower: np.ndarray, upper: np.ndarray, G=None, h=None) -> None:
        """Tighten the velocity box [lower, upper] (N, nv) in place."""
        steps, (low, high) = self._steps, self._rows  # the step to each bound, low <= 0 <= high inside the range
        q, speed_lower, speed_upper = self._views(lower, upper)
        lower_bound, upper_bound = self._bounds  # q is finite: the kinematics update refuses it otherwise
        np.subtract(lower_bound, q, low)  # (two same-shape calls cost less than one broadcast)
        np.subtract(upper_bound, q, high)
        rate = self.gain / dt
        if self.influence > 0.0:
            # Within the influence of a bound: rate x distance, never more than the step bound.
            np.less(np.abs(steps, self._factor), self.influence, self._near)
            self._factor.fill(rate)
            np.copyto(self._factor, min(self.damper_rate / self.influence, rate), where=self._near)
            np.multiply(steps, self._factor, steps)
        else:
            if rate != self._rate_value:
                self._rate.fill(rate)
                self._rate_value = rate
            np.multiply(steps, self._rate, steps)
        # Recovery from outside the range never asks for more than the speed box.
        np.minimum(low, speed_upper, low)
        np.maximum(high, speed_lower, high)
        np.maximum(speed_lower, low, speed_lower)
        np.minimum(speed_upper, high, speed_upper)
        if not isinstance(self._dofs, slice):
            lower[:, self._dofs], upper[:, self._dofs] = speed_lower.T, speed_upper.T

    def _views(self, lower: np.ndarray, upper: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """q and the box's columns of the limited joints, worlds last (k, N): views where they
        are consecutive (kept while the controller gives the same box), else copies."""
        if self._kept is not None and self._kept[0] is lower:
            return self._kept[1:]
        views = self.robot.qpos[:, self._qpos].T, lower[:, self._dofs].T, upper[:, self._dofs].T
        if isinstance(self._qpos, slice) and isinstance(self._dofs, slice):
            self._kept = (lower, *views)
        return views
