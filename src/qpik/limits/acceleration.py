"""Bound the change of the joint velocity from one step to the next, in every world."""

from __future__ import annotations

import numpy as np

from ..numerics import ConfigurationDifference
from ..tasks.inputs import world_values
from .limit import Limit, bound_values


class AccelerationLimit(Limit):
    r"""Acceleration bounds :math:`|\dot q_k - \dot q_{k-1}| \le a\,\Delta t` (pink's
    ``AccelerationLimit``): a box around the previous step's velocity, in every world.

    The previous velocity is what each world did: each step the limit differentiates the
    configuration it sees against the one of its previous step,
    :math:`\dot q_{k-1} = (q_k \ominus q_{k-1}) / \Delta t` (``mj_differentiatePos``,
    :class:`~qpik.numerics.ConfigurationDifference`). In a kinematic rollout this
    is the last command (to rounding), in a physics rollout the measured motion; nothing
    has to be passed from the controller to the limit. Call the controller once per
    control period, integrating in between. A world starts at rest
    (:math:`\dot q_{-1} = 0`: the first step is bounded by :math:`a\Delta t`), or from the
    velocity given to :meth:`reset`.

    Beside position limits the box can be empty (a joint arriving at its bound faster
    than it can brake): the controller then reports the problem infeasible, naming
    the limits.

    Args:
        robot: the robot (one world or N: the same bounds in every world).
        max_acceleration: a (rad/s² or m/s²), a number for every dof or an (nv,) array
            (``inf`` where a dof is free).

    Attributes:
        previous_velocities: (N, nv) each world's previous velocity (after a step: the one
            it measured); ``previous_velocity`` is what a user reads of it.

    Raises:
        InvalidInput: a bound that is not positive or is finite beyond 1e12, a wrong shape.
    """

    def __init__(self, robot, max_acceleration):
        n, nv = robot.n, robot.nv
        self.robot = robot
        self.max_acceleration = bound_values(max_acceleration, nv, "max_acceleration", " (one per dof)")
        self.previous_velocities = np.zeros((n, nv))
        self.previous_velocity = robot.present(self.previous_velocities)
        self._previous_q = robot.qpos.copy()
        self._difference = ConfigurationDifference(robot.model, n)
        self._max = np.tile(self.max_acceleration, (n, 1))
        self._step, self._bound = np.empty((n, nv)), np.empty((n, nv))
        # The worlds starting afresh at their next step, from these velocities.
        self._fresh, self._start = np.ones(n, dtype=bool), np.zeros((n, nv))
        self._fresh_rows = self._fresh[:, None]
        self._pending = True

    def reset(self, velocity=None, worlds=None) -> None:
        """Forget the past: the next step of ``worlds`` (index array; None: every world)
        starts from ``velocity`` (default: at rest), one (nv,) for every world or (N, nv)
        one per world.

        Raises:
            InvalidInput: a wrong shape, or (one world) a velocity not finite.
            InvalidWorlds: (N worlds) the worlds whose velocity is not finite.
        """
        shape = (self.robot.nv,)
        start = np.zeros((self.robot.n,) + shape) if velocity is None else \
            world_values(self.robot, velocity, shape, "the velocity to start from")
        chosen = slice(None) if worlds is None else np.asarray(worlds, dtype=int)
        self._start[chosen] = start[chosen]
        self.previous_velocities[chosen] = start[chosen]
        self._fresh[chosen] = True
        self._pending = True

    def apply(self, dt: float, lower: np.ndarray, upper: np.ndarray, G=None, h=None) -> None:
        """Tighten the box [lower, upper] (N, nv) around each world's previous velocity."""
        q, previous = self.robot.qpos, self.previous_velocities
        self._difference(self._previous_q, q, previous)
        np.divide(previous, dt, previous)
        if self._pending:
            np.copyto(previous, self._start, where=self._fresh_rows)
            self._fresh.fill(False)
            self._pending = False
        np.copyto(self._previous_q, q)
        step, bound = self._step, self._bound
        np.multiply(self._max, dt, step)
        np.subtract(previous, step, bound)
        np.maximum(lower, bound, lower)
        np.add(previous, step, bound)
        np.minimum(upper, bound, upper)
