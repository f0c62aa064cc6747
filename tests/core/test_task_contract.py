"""The Task interface says itself whether J is the identity selection: nothing guesses from
the task's type (a PostureTask subclass with J = 2I once got half the right velocity)."""

from __future__ import annotations

import numpy as np
import pytest

from qpik import (
    DampingTask,
    InvalidInput,
    PositionTask,
    PostureTask,
    PseudoinverseController,
    QPController,
    Robot,
    batch,
)


class DoubledPosture(PostureTask):
    """A posture task on 2q: J = 2I, v = K (q_ref − q) as before."""

    def __init__(self, robot, **kwargs):
        super().__init__(robot, **kwargs)
        self.jacobian = 2.0 * np.eye(robot.nv)


class PropertyPosture(PostureTask):
    @property
    def jacobian(self):
        return 3.0 * np.eye(self.robot.nv)


@pytest.fixture
def arm():
    robot = Robot.load("arm")
    robot.set_q([0.3, 0.4, -0.2, 0.5])
    robot.update_kinematics()
    return robot


def test_builtin_joint_space_tasks_declare_it(arm):
    assert PostureTask(arm).joint_space and DampingTask(arm).joint_space
    assert not PositionTask(arm, "end_effector", axes="xy").joint_space
    np.testing.assert_array_equal(PostureTask(arm).jacobian, np.eye(arm.nv))


def test_subclass_with_its_own_jacobian_is_a_general_task(arm):
    assert not DoubledPosture(arm).joint_space
    assert not PropertyPosture(arm).joint_space


def test_qp_reads_a_subclass_jacobian(arm):
    target = arm.q + np.array([0.1, -0.2, 0.05, 0.1])
    doubled = DoubledPosture(arm, target=target, gain=1.0)
    plain = PostureTask(arm, target=target, gain=1.0)
    qdot_doubled = QPController(arm, [doubled], dt=0.002, regularization=1e-12).compute_velocity().copy()
    qdot_plain = QPController(arm, [plain], dt=0.002, regularization=1e-12).compute_velocity().copy()
    # min ½‖2 q̇ − v‖² gives q̇ = v/2; the old type list gave v.
    np.testing.assert_allclose(qdot_plain, target - arm.q, atol=1e-9)
    np.testing.assert_allclose(qdot_doubled, 0.5 * (target - arm.q), atol=1e-9)


def test_qp_reads_a_jacobian_property_of_the_subclass(arm):
    target = arm.q + np.array([0.1, -0.2, 0.05, 0.1])
    tripled = PropertyPosture(arm, target=target, gain=1.0)
    qdot = QPController(arm, [tripled], dt=0.002, regularization=1e-12).compute_velocity()
    np.testing.assert_allclose(tripled.compute_jacobian(arm), 3.0 * np.eye(arm.nv))
    np.testing.assert_allclose(qdot, (target - arm.q) / 3.0, atol=1e-9)  # min ½‖3 q̇ − v‖²


def test_a_subclass_jacobian_holds_in_every_world():
    robots = batch.Robot.load("arm", n=4)
    rng = np.random.default_rng(5)
    robots.set_q(robots.q + rng.uniform(-0.3, 0.3, robots.q.shape))
    targets = robots.q + rng.uniform(-0.2, 0.2, robots.q.shape)
    doubled = DoubledPosture(robots, target=targets, gain=1.0)
    assert not doubled.joint_space and doubled.jacobian.shape == (4, robots.nv, robots.nv)
    qdot = QPController(robots, [doubled], dt=0.002, regularization=1e-12).compute_velocity()
    np.testing.assert_allclose(qdot, 0.5 * (targets - robots.q), atol=1e-9)  # each world its own q̇ = v/2


def test_joint_space_selection_is_read_only(arm):
    task = PostureTask(arm)
    with pytest.raises(ValueError):
        task.jacobian[0, 0] = 2.0


def test_jacobian_changed_after_the_controller_was_built_is_an_error(arm):
    task = PostureTask(arm)
    QPController(arm, [task], dt=0.002)
    with pytest.raises(InvalidInput, match="cannot change after the task was given to a controller"):
        task.jacobian = 2.0 * np.eye(arm.nv)
    with pytest.raises(InvalidInput, match="shape"):
        PostureTask(arm).jacobian = np.eye(arm.nv + 1)


def test_pseudoinverse_secondary_must_be_joint_space(arm):
    primary = PositionTask(arm, "end_effector", axes="xy", gain=1.0)
    with pytest.raises(InvalidInput, match="joint-space"):
        PseudoinverseController(arm, [primary], DoubledPosture(arm))
