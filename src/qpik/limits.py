r"""Limits: bounds on the joint velocity :math:`\dot q` for the next step Δt.

Both limits act on single dofs, so they are box constraints lb ≤ q̇ ≤ ub, which every
QP solver handles natively (DAQP as simple bounds, OSQP as identity rows).

- :class:`JointPositionLimit`: q + q̇Δt stays in [lower, upper]; with a velocity
  damper (Faverjon–Tournassoud) the allowed speed toward a bound shrinks linearly
  once the joint is within ``influence`` of it.
- :class:`JointVelocityLimit`: |q̇| ≤ q̇max.

When both are present a joint found outside its range (possible in physics mode) may
return at full speed: the position bound is clipped into the velocity box, so the
box is never empty for valid limits.
"""

from __future__ import annotations

import numpy as np

from .errors import InvalidInput
from .robot import JointLimits, Robot


class JointPositionLimit:
    """Keep limited joints inside their range at the end of the step.

    Args:
        robot: the robot.
        limits: the ranges to enforce (default: the model's ``range`` attributes).
        gain: fraction in (0, 1] of the remaining distance that one step may cover.
        influence: distance to a bound below which the velocity damper acts
            (0 disables the damper).
        damper_rate: ξ (joint units/s): once the distance d to a bound is below
            ``influence``, the speed toward it is at most ξ d / influence, so the joint
            slows down exponentially as it arrives.
        margin: the bounds are pulled in by this much (joint units), so that rounding in
            q + q̇Δt never lands a hair outside the range.
    """

    constant = False  # depends on q: recomputed every step

    def __init__(self, robot: Robot, limits: JointLimits | None = None, gain: float = 1.0,
                 influence: float = 0.0, damper_rate: float = 20.0, margin: float = 1e-10):
        self.limits = robot.joint_limits if limits is None else limits
        if not 0.0 < gain <= 1.0:
            raise InvalidInput(f"position-limit gain must lie in (0, 1], got {gain}")
        if np.any(self.limits.lower >= self.limits.upper):
            bad = [n for n, lo, hi in zip(self.limits.names, self.limits.lower, self.limits.upper) if lo >= hi]
            raise InvalidInput(f"empty joint range for {bad}")
        if influence < 0 or damper_rate <= 0:
            raise InvalidInput("damper influence must be >= 0 and its rate > 0")
        self.robot = robot
        self.gain = gain
        self.influence = influence
        self.damper_rate = damper_rate
        # Rows: lower then upper bound, pulled in by the margin.
        self._bounds = np.stack([self.limits.lower + margin, self.limits.upper - margin])
        self._qpos = _as_slice(self.limits.qpos_index)
        self._dofs = _as_slice(self.limits.dof_index)
        self._steps = np.empty_like(self._bounds)
        self._low, self._high = self._steps  # row views, made once
        self._rate = damper_rate / influence if influence > 0 else 0.0
        self._factor = np.empty_like(self._bounds)
        self._near = np.empty(self._bounds.shape, dtype=bool)

    def apply(self, dt: float, lb: np.ndarray, ub: np.ndarray) -> None:
        """Tighten the velocity box [lb, ub] (nv,) in place."""
        steps = self._steps  # distance to each bound: row 0 <= 0, row 1 >= 0 inside the range
        np.subtract(self._bounds, self.robot.q[self._qpos], out=steps)
        if self.influence > 0.0:
            # Within the influence distance of a bound the speed toward it is rate x
            # distance, but never more than the step limit (a damper faster than gain/Δt
            # would step past the bound); elsewhere the step limit q + q̇Δt in range applies.
            np.less(np.abs(steps, out=self._factor), self.influence, out=self._near)
            self._factor.fill(self.gain / dt)
            np.copyto(self._factor, min(self._rate, self.gain / dt), where=self._near)
            steps *= self._factor
        else:
            steps *= self.gain / dt
        low, high = self._low, self._high
        vel_lo, vel_hi = lb[self._dofs], ub[self._dofs]  # views when the dofs are contiguous
        # Recovery from outside the range never asks for more than the velocity box.
        np.minimum(low, vel_hi, out=low)
        np.maximum(high, vel_lo, out=high)
        np.maximum(vel_lo, low, out=vel_lo)
        np.minimum(vel_hi, high, out=vel_hi)
        if not isinstance(self._dofs, slice):
            lb[self._dofs] = vel_lo
            ub[self._dofs] = vel_hi


def _as_slice(index: np.ndarray):
    """A slice for consecutive indices (views, no fancy-index copies), else the array."""
    if len(index) and np.array_equal(index, np.arange(index[0], index[0] + len(index))):
        return slice(int(index[0]), int(index[0]) + len(index))
    return np.asarray(index, dtype=int)


class JointVelocityLimit:
    """|q̇_i| ≤ q̇max_i on the dofs that have a limit (default: the scene's numerics)."""

    constant = True  # the same bounds every step: the controller applies them once

    def __init__(self, robot: Robot, max_velocity: np.ndarray | None = None):
        vmax = robot.velocity_limits if max_velocity is None else np.asarray(max_velocity, dtype=float)
        if vmax.shape != (robot.nv,):
            raise InvalidInput(f"velocity limits must have shape ({robot.nv},), got {vmax.shape}")
        if np.any(np.isnan(vmax)) or np.any(vmax <= 0):
            raise InvalidInput("velocity limits must be positive (inf for none)")
        self.max_velocity = vmax

    def apply(self, dt: float, lb: np.ndarray, ub: np.ndarray) -> None:
        np.maximum(lb, -self.max_velocity, out=lb)
        np.minimum(ub, self.max_velocity, out=ub)


def order_limits(limits) -> list:
    """Constant limits (velocity) first, so position bounds are clipped into their box."""
    return sorted(limits, key=lambda lim: 0 if lim.constant else 1)
