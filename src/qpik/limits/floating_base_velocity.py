"""Speed bounds on a floating base (a free joint): linear and angular, per axis."""

from __future__ import annotations

import mujoco
import numpy as np

from ..errors import InvalidInput, ModelError
from ..robot import Robot
from .limit import Limit


class FloatingBaseVelocityLimit(Limit):
    r"""Bound a free joint's linear and angular velocity, per axis:
    :math:`|v_k| \le v_{max,k}`, :math:`|\omega_k| \le \omega_{max,k}`.

    A joint-wise speed limit names hinges; a floating base left out of it is unbounded
    (a humanoid's base once reached 134 rad/s under a 5 rad/s joint limit). MuJoCo's
    free-joint velocity is the base's linear velocity in world axes and its angular
    velocity in the base's own axes, so the bounds hold on those axes.

    Per-axis boxes, not norms (exact, constant and taken by every controller): the norm
    is then at most :math:`\sqrt3` times a scalar bound; pass :math:`L/\sqrt3` to bound it by L.

    Args:
        robot: the robot.
        linear: m/s, a number or one per world axis (3,); ``None`` leaves it free.
        angular: rad/s, a number or one per base axis (3,); ``None`` leaves it free.
        joint: the free joint (default: the model's only one).

    Raises:
        ModelError: the model has no free joint, or several and none is named.
        UnknownName: ``joint`` names no joint.
        InvalidInput: ``joint`` is not free; a bound that is not positive; both None.
    """

    constant = True

    def __init__(self, robot: Robot, linear=None, angular=None, joint: str | None = None):
        if linear is None and angular is None:
            raise InvalidInput("FloatingBaseVelocityLimit: give a linear and/or an angular bound")
        first = int(robot.joint_dofs(free_joint(robot, joint))[0])
        self.robot = robot
        self.dofs = np.arange(first, first + 6)
        self.max_velocity = np.concatenate([_bounds(linear, "linear"), _bounds(angular, "angular")])

    def apply(self, dt: float, lb: np.ndarray, ub: np.ndarray, G=None, h=None) -> None:
        dofs = self.dofs
        lb[dofs] = np.maximum(lb[dofs], -self.max_velocity)
        ub[dofs] = np.minimum(ub[dofs], self.max_velocity)


def free_joint(robot: Robot, joint: str | None) -> str:
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
    try:
        bound = np.broadcast_to(np.asarray(value, dtype=float), (3,)).copy()
    except (TypeError, ValueError):
        raise InvalidInput(f"the {what} bound must be a number or 3 numbers, got {value!r}") from None
    if not np.all(bound > 0):  # NaN fails too
        raise InvalidInput(f"the {what} bound must be positive (inf for none), got {value!r}")
    return bound
