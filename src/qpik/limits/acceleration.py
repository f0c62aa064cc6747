"""Bound the change of the joint velocity from one step to the next."""

from __future__ import annotations

import mujoco
import numpy as np

from ..errors import InvalidInput
from ..robot import Robot
from .limit import Limit


class AccelerationLimit(Limit):
    r"""Acceleration bounds :math:`|\dot q_k - \dot q_{k-1}| \le a\,\Delta t` (pink's
    ``AccelerationLimit``): a box around the previous step's velocity.

    The previous velocity is what the robot did: each step the limit differentiates the
    configuration it sees against the one of its previous step,
    :math:`\dot q_{k-1} = (q_k \ominus q_{k-1}) / \Delta t` (``mj_differentiatePos``).
    In a kinematic rollout this is the last command (to rounding), in a physics rollout
    the measured motion; nothing has to be passed from the controller to the limit.
    Call the controller once per control period, integrating in between. It starts at
    rest (:math:`\dot q_{-1} = 0`: the first step is bounded by :math:`a\Delta t`), or
    from the velocity given to :meth:`reset`.

    Beside position limits the box can be empty (a joint arriving at its bound faster
    than it can brake): the controller then reports the problem infeasible, naming
    the limits.

    Args:
        robot: the robot.
        max_acceleration: a (rad/s² or m/s²), a number for every dof or an (nv,) array
            (``inf`` where a dof is free).

    Raises:
        InvalidInput: a bound that is not positive, a wrong shape.
    """

    def __init__(self, robot: Robot, max_acceleration):
        try:
            bound = np.broadcast_to(np.asarray(max_acceleration, dtype=float), (robot.nv,)).copy()
        except (TypeError, ValueError):
            raise InvalidInput(f"max_acceleration must be a number or {robot.nv} numbers (one per dof), "
                               f"got {max_acceleration!r}") from None
        if not np.all(bound > 0):  # NaN fails too
            raise InvalidInput(f"max_acceleration must be positive (inf for none), got {max_acceleration!r}")
        self.robot = robot
        self.max_acceleration = bound
        self.previous_velocity = np.zeros(robot.nv)
        self._previous_q = robot.q.copy()
        self._started = False

    def reset(self, velocity=None) -> None:
        """Forget the past: the next step starts from ``velocity`` (default: at rest)."""
        self.previous_velocity[:] = 0.0 if velocity is None else np.asarray(velocity, dtype=float)
        self._started = False

    def apply(self, dt: float, lb: np.ndarray, ub: np.ndarray, G=None, h=None) -> None:
        q = self.robot.data.qpos
        if self._started:
            mujoco.mj_differentiatePos(self.robot.model, self.previous_velocity, dt, self._previous_q, q)
        self._started = True
        self._previous_q[:] = q
        step = self.max_acceleration * dt
        np.maximum(lb, self.previous_velocity - step, out=lb)
        np.minimum(ub, self.previous_velocity + step, out=ub)
