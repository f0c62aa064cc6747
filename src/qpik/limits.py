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
        damper_rate: ξ in q̇ ≥ −ξ (d − 0)/influence once d < influence, in 1/s.
    """

    def __init__(self, robot: Robot, limits: JointLimits | None = None, gain: float = 1.0,
                 influence: float = 0.0, damper_rate: float = 20.0):
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

    def apply(self, dt: float, lb: np.ndarray, ub: np.ndarray) -> None:
        """Tighten the velocity box [lb, ub] (nv,) in place."""
        lim = self.limits
        q = self.robot.q[lim.qpos_index]
        to_lower = lim.lower - q  # <= 0 inside the range
        to_upper = lim.upper - q  # >= 0 inside the range
        low = self.gain * to_lower / dt
        high = self.gain * to_upper / dt
        if self.influence > 0.0:
            rate = self.damper_rate / self.influence
            low = np.maximum(low, np.where(-to_lower < self.influence, rate * to_lower, -np.inf))
            high = np.minimum(high, np.where(to_upper < self.influence, rate * to_upper, np.inf))
        dofs = lim.dof_index
        vel_lo, vel_hi = lb[dofs], ub[dofs]
        # Recovery from outside the range never asks for more than the velocity box.
        lb[dofs] = np.maximum(vel_lo, np.minimum(low, vel_hi))
        ub[dofs] = np.minimum(vel_hi, np.maximum(high, vel_lo))


class JointVelocityLimit:
    """|q̇_i| ≤ q̇max_i on the dofs that have a limit (default: the scene's numerics)."""

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
    """Velocity limits first, so position bounds are clipped into the velocity box."""
    return sorted(limits, key=lambda lim: 0 if isinstance(lim, JointVelocityLimit) else 1)
