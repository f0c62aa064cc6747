"""A limit written by a user through its one entry point, ``apply(dt, lower, upper, G, h)``
(every world's: lower, upper (N, nv), G (N, rows, nv), h (N, rows); N = 1 for one robot),
holds in every controller that takes it: a box in the QP, the hierarchy and SNS, a
general row in the QP and the hierarchy (SNS refuses rows, saying so)."""

from __future__ import annotations

import numpy as np
import pytest

from qpik import (
    DampingTask,
    HierarchicalController,
    InvalidInput,
    JointPositionLimit,
    Limit,
    PositionTask,
    QPController,
    Robot,
    SNSController,
)

DT = 0.002
SPEED = 0.05  # rad/s
TOTAL = 0.02  # rad/s


class SlowJoint(Limit):
    """A box: one dof no faster than ``speed``."""

    def __init__(self, robot, dof: int, speed: float):
        self.robot, self.dof, self.speed = robot, dof, speed

    def apply(self, dt, lower, upper, G=None, h=None):
        np.maximum(lower[:, self.dof], -self.speed, out=lower[:, self.dof])
        np.minimum(upper[:, self.dof], self.speed, out=upper[:, self.dof])


class SlowSum(Limit):
    """One general row: the sum of the joint velocities no lower than −``total``."""

    inequality_rows = 1

    def __init__(self, robot, total: float):
        self.robot, self.total = robot, total

    def apply(self, dt, lower, upper, G=None, h=None):
        G[:, 0] = -1.0
        h[:, 0] = self.total


def _setup():
    robot = Robot.load("arm")
    robot.set_q([0.3, 0.6, 0.4, 0.5])
    tip = PositionTask(robot, "end_effector", axes="xy", gain=50.0)
    tip.set_target(tip.measured() + [0.1, 0.1])
    return robot, [tip, DampingTask(robot, weight=1e-6)]


CONTROLLERS = {
    "qp": lambda robot, tasks, limits: QPController(robot, tasks, limits, dt=DT),
    "hqp": lambda robot, tasks, limits: HierarchicalController(robot, tasks, limits, dt=DT),
    "sns": lambda robot, tasks, limits: SNSController(robot, tasks[:1], limits, dt=DT),
}


@pytest.mark.parametrize("kind", sorted(CONTROLLERS))
def test_a_users_box_limit_binds_and_holds(kind):
    robot, tasks = _setup()
    free = CONTROLLERS[kind](robot, tasks, [JointPositionLimit(robot)]).compute_velocity().copy()
    assert abs(free[0]) > 2 * SPEED  # without it the step moves joint 0 faster
    qdot = CONTROLLERS[kind](robot, tasks, [JointPositionLimit(robot), SlowJoint(robot, 0, SPEED)]).compute_velocity()
    assert abs(qdot[0]) <= SPEED * (1 + 1e-9)
    assert abs(qdot[0]) >= SPEED * (1 - 1e-6)  # it binds: the joint goes as fast as it may


@pytest.mark.parametrize("kind", ["qp", "hqp"])
def test_a_users_row_limit_binds_and_holds(kind):
    robot, tasks = _setup()
    free = CONTROLLERS[kind](robot, tasks, []).compute_velocity().copy()
    assert -free.sum() > 2 * TOTAL
    qdot = CONTROLLERS[kind](robot, tasks, [SlowSum(robot, TOTAL)]).compute_velocity()
    assert -qdot.sum() <= TOTAL + 1e-9
    assert -qdot.sum() >= TOTAL - 1e-6


def test_sns_refuses_a_row_limit_naming_it():
    robot, tasks = _setup()
    with pytest.raises(InvalidInput, match="SlowSum"):
        SNSController(robot, tasks[:1], [SlowSum(robot, TOTAL)], dt=DT)
