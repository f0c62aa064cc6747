r"""Batched limits: boxes lb ≤ q̇ ≤ ub (N, nv) for the next step, as the serial limits.

Each class validates its arguments by building the serial limit (:mod:`qpik.limits`) on
the robots' template and applies the same formulas across worlds. General rows
:math:`G\dot q \le h` (collision avoidance) are not batched yet.
"""

from __future__ import annotations

import numpy as np

from .. import limits as serial
from .errors import NotBatched
from .robot import Robot
from .tasks import _Difference

__all__ = ["AccelerationLimit", "CollisionAvoidanceLimit", "JointPositionLimit", "JointVelocityLimit", "Limit"]


def consecutive(index: np.ndarray):
    """``index`` as a slice when its entries are consecutive (a view instead of a copy)."""
    index = np.asarray(index, dtype=np.int64)
    if len(index) and np.array_equal(index, np.arange(index[0], index[0] + len(index))):
        return slice(int(index[0]), int(index[0]) + len(index))
    return index


class Limit:
    """Base class: :meth:`apply` tightens the (N, nv) box in place; ``constant`` limits
    are applied once, when a controller is built."""

    constant = False

    def apply(self, dt: float, lb: np.ndarray, ub: np.ndarray) -> None:
        raise NotImplementedError

    def serial_twin(self, robot, world: int):
        """The serial limit of world ``world`` on ``robot`` (for tests and comparisons)."""
        raise NotImplementedError


class JointPositionLimit(Limit):
    """Batched :class:`qpik.JointPositionLimit`: q + q̇Δt stays in range, with the optional
    velocity damper near a bound; the position bound is clipped into the velocity box."""

    def __init__(self, robots: Robot, limits=None, gain: float = 1.0, influence: float = 0.0,
                 damper_rate: float = 20.0, margin: float = 1e-10):
        twin = serial.JointPositionLimit(robots.template, limits, gain, influence, damper_rate, margin)
        self.robots, self.limits = robots, twin.limits
        self.gain, self.influence, self.damper_rate, self.margin = twin.gain, twin.influence, twin.damper_rate, twin.margin
        self._args = dict(limits=limits, gain=gain, influence=influence, damper_rate=damper_rate, margin=margin)
        self._lower = self.limits.lower + self.margin
        self._upper = self.limits.upper - self.margin
        self._rate = damper_rate / influence if influence > 0 else 0.0
        self._qpos, self._dofs = consecutive(self.limits.qpos_index), consecutive(self.limits.dof_index)

    def apply(self, dt: float, lb: np.ndarray, ub: np.ndarray) -> None:
        q = self.robots.q[:, self._qpos]
        low, high = self._lower - q, self._upper - q
        step_rate = self.gain / dt
        if self.influence > 0.0:
            damped = min(self._rate, step_rate)
            low = low * np.where(np.abs(low) < self.influence, damped, step_rate)
            high = high * np.where(np.abs(high) < self.influence, damped, step_rate)
        else:
            low, high = low * step_rate, high * step_rate
        dofs = self._dofs
        vel_lo, vel_hi = lb[:, dofs], ub[:, dofs]
        # Recovery from outside the range never asks for more than the velocity box.
        low = np.minimum(low, vel_hi)
        high = np.maximum(high, vel_lo)
        lb[:, dofs] = np.maximum(vel_lo, low)
        ub[:, dofs] = np.minimum(vel_hi, high)

    def serial_twin(self, robot, world: int):
        return serial.JointPositionLimit(robot, **self._args)


class JointVelocityLimit(Limit):
    """Batched :class:`qpik.JointVelocityLimit`: |q̇_i| ≤ q̇max_i (the same in every world)."""

    constant = True

    def __init__(self, robots: Robot, values=None):
        twin = serial.JointVelocityLimit(robots.template, values)
        self.robots, self.max_velocity, self._values = robots, twin.max_velocity, values

    def apply(self, dt: float, lb: np.ndarray, ub: np.ndarray) -> None:
        np.maximum(lb, -self.max_velocity, out=lb)
        np.minimum(ub, self.max_velocity, out=ub)

    def serial_twin(self, robot, world: int):
        return serial.JointVelocityLimit(robot, self._values)


class AccelerationLimit(Limit):
    """Batched :class:`qpik.AccelerationLimit`: |q̇_k − q̇_{k−1}| ≤ aΔt, q̇_{k−1} measured
    from each world's configurations (q_k ⊖ q_{k−1}) / Δt; at rest before the first step."""

    def __init__(self, robots: Robot, max_acceleration):
        twin = serial.AccelerationLimit(robots.template, max_acceleration)
        self.robots, self.max_acceleration, self._value = robots, twin.max_acceleration, max_acceleration
        self.previous_velocity = np.zeros((robots.n, robots.nv))
        self._previous_q = robots.q.copy()
        self._started = False
        self._difference = _Difference(robots.model)

    def reset(self, velocity=None) -> None:
        """Forget the past: the next step starts from ``velocity`` ((N, nv) or (nv,); rest)."""
        self.previous_velocity[:] = 0.0 if velocity is None else velocity
        self._started = False

    def apply(self, dt: float, lb: np.ndarray, ub: np.ndarray) -> None:
        q = self.robots.q
        if self._started:
            self.previous_velocity = self._difference(self._previous_q, q) / dt
        self._started = True
        self._previous_q = q.copy()
        step = self.max_acceleration * dt
        np.maximum(lb, self.previous_velocity - step, out=lb)
        np.minimum(ub, self.previous_velocity + step, out=ub)

    def serial_twin(self, robot, world: int):
        return serial.AccelerationLimit(robot, self._value)


class CollisionAvoidanceLimit(Limit):
    """Not batched yet: raises :class:`~qpik.batch.NotBatched` (the serial
    :class:`qpik.CollisionAvoidanceLimit` runs one robot at a time)."""

    def __init__(self, robots: Robot, *args, **kwargs):
        raise NotBatched("CollisionAvoidanceLimit is not batched yet: its general rows G q̇ <= h need the batched "
                         "QP's general inequalities; run it with the serial qpik.QPController, one world at a time")
