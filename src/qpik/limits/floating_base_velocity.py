"""Speed bounds on a floating base (a free joint): linear and angular, per axis, in every world."""

from __future__ import annotations

import mujoco
import numpy as np

from ..errors import InvalidInput, ModelError
from .limit import Limit, bound_values


class FloatingBaseVelocityLimit(Limit):
    r"""Bound a free joint's linear and angular velocity, per axis:
    :math:`|v_k| \le v_{max,k}`, :math:`|\omega_k| \le \omega_{max,k}`, in every world.

    A joint-wise speed limit names hinges; a floating base left out of it is unbounded
    (a humanoid's base once reached 134 rad/s under a 5 rad/s joint limit). MuJoCo's
    free-joint velocity is the base's linear velocity in world axes and its angular
    velocity in the base's own axes, so the bounds hold on those axes.

    Per-axis boxes, not norms (exact, constant and taken by every controller): the norm
    is then at most :math:`\sqrt3` times a scalar bound; pass :math:`L/\sqrt3` to bound it by L.

    Args:
        robot: the robot (one world or N: the same bounds in every world).
        linear: m/s, a number or one per world axis (3,); ``None`` leaves it free.
        angular: rad/s, a number or one per base axis (3,); ``None`` leaves it free.
        joint: the free joint (default: the model's only one).

    Raises:
        ModelError: the model has no free joint, or several and none is named.
        UnknownName: ``joint`` names no joint.
        InvalidInput: ``joint`` is not free; a bound that is not positive or is finite
            beyond 1e12; both None.
    """

    constant = True  # the same bounds every step: the controller applies them once

    def __init__(self, robot, linear=None, angular=None, joint: str | None = None):
        if linear is None and angular is None:
            raise InvalidInput("FloatingBaseVelocityLimit: give a linear and/or an angular bound")
        first = int(robot.joint_dofs(free_joint(robot, joint))[0])
        self.robot = robot
        self.dofs = np.arange(first, first + 6)
        self.max_velocity = np.concatenate([_bounds(linear, "linear"), _bounds(angular, "angular")])
        self._columns = slice(first, first + 6)
        self._negative = -self.max_velocity

    def apply(self, dt: float, lower: np.ndarray, upper: np.ndarray, G=None, h=None) -> None:
        """Tighten the base's six columns of the box [lower, upper] (N, nv) in place."""
        base_lower, base_upper = lower[:, self._columns], upper[:, self._columns]
        np.maximum(base_lower, self._negative, base_lower)
        np.minimum(base_upper, self.max_velocity, base_upper)


def free_joint(robot, joint: str | None) -> str:
    """The name of ``joint`` checked to be free, or of the model's only free joint."""
    model = robot.model
    free = [model.joint(j).name for j in range(model.njnt) if model.jnt_type[j] == mujoco.mjtJoint.mjJNT_FREE]
    if joint is None:
        if len(free) != 1:
            raise ModelError(f"model {robot.name!r} has {len(free)} free joints {free}: name one (joint=...)"
                             if free else f"model {robot.name!r} has no free joint (no floating base)")
        return free[0]
    robot.joint_dofs(joint)  # UnknownName for a joint the model does not have
    if joint not in free:
        raise InvalidInput(f"joint {joint!r} is not a free joint; free joints: {free}")
    return joint


def _bounds(value, what: str) -> np.ndarray:
    if value is None:
        return np.full(3, np.inf)
    return bound_values(value, 3, f"the {what} bound", " (one per axis)")
