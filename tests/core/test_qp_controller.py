"""QPController: explicit dt, automatic kinematics updates, errors that name the cause,
soft tasks that degrade instead of failing."""

from __future__ import annotations

import numpy as np
import pytest

from qpik import (DampingTask, InfeasibleProblem, InvalidInput, JointPositionLimit, JointVelocityLimit,
                  PositionTask, QPController, Robot)

DT = 0.002


@pytest.fixture
def arm():
    robot = Robot.load("arm")
    robot.set_q([np.pi / 2, 0.3, -0.2, 0.5])
    robot.update_kinematics()
    return robot


def test_dt_is_required(arm):
    task = PositionTask(arm, "end_effector", axes="xy")
    with pytest.raises(InvalidInput, match="dt is required"):
        QPController(arm, [task])
    for bad in (0.0, -0.002, float("nan"), float("inf"), "fast"):
        with pytest.raises(InvalidInput, match="dt"):
            QPController(arm, [task], dt=bad)


def test_kinematics_follow_q_without_an_explicit_update(arm):
    """Writing q and forgetting update_kinematics() gives the same step as updating."""
    task = PositionTask(arm, "end_effector", axes="xy", gain=50.0, hard=True)
    qp = QPController(arm, [task, DampingTask(arm)], dt=DT)
    task.set_target([1.0, 1.5])
    arm.q[:] = [1.0, 0.4, -0.3, 0.4]  # no update_kinematics()
    forgotten = qp.compute_velocity().copy()
    arm.update_kinematics()
    updated = qp.compute_velocity().copy()
    np.testing.assert_array_equal(forgotten, updated)
    # ...and it tracks: a rollout that never calls update_kinematics converges.
    for _ in range(400):
        arm.integrate(qp.compute_velocity(), DT)
    arm.update_kinematics()
    np.testing.assert_allclose(task.frame.position[:2], [1.0, 1.5], atol=1e-6)


def test_infeasible_hard_task_names_the_binding_speed_limits(arm):
    task = PositionTask(arm, "end_effector", axes="xy", gain=500.0, hard=True)
    task.set_target([0.0, -2.0])  # far away: K e needs far more than 8 rad/s
    qp = QPController(arm, [task, DampingTask(arm)], [JointVelocityLimit(arm)], dt=DT)
    with pytest.raises(InfeasibleProblem) as info:
        qp.compute_velocity()
    message = str(info.value)
    assert "hard position task" in message and "speed limit" in message and "hard=False" in message
    assert any(joint in message for joint in ("theta1", "theta2", "theta3", "d4"))


def test_infeasible_hard_task_names_a_binding_position_limit(arm):
    limits = arm.joint_limits.tightened({"theta1": (np.pi / 2 - 1e-3, np.pi / 2 + 1e-3),
                                         "theta2": (0.3 - 1e-3, 0.3 + 1e-3),
                                         "theta3": (-0.2 - 1e-3, -0.2 + 1e-3),
                                         "d4": (0.5 - 1e-3, 0.5 + 1e-3)})
    task = PositionTask(arm, "end_effector", axes="xy", gain=100.0, hard=True)
    task.set_target([0.5, 2.5])
    qp = QPController(arm, [task, DampingTask(arm)], [JointPositionLimit(arm, limits)], dt=DT)
    with pytest.raises(InfeasibleProblem, match="position limit"):
        qp.compute_velocity()


def test_soft_task_with_a_far_target_degrades(arm):
    """Levenberg–Marquardt damping with a target 1e6 m away: bounded, finite, no error."""
    limits = [JointPositionLimit(arm), JointVelocityLimit(arm)]
    for distance in (10.0, 1e6, 1e12):
        task = PositionTask(arm, "end_effector", axes="xy", gain=500.0, lm_damping=10.0)
        task.set_target([distance, distance])
        qp = QPController(arm, [task, DampingTask(arm, 1e-2)], limits, dt=DT, solver="osqp")
        qdot = qp.compute_velocity()
        assert np.all(np.isfinite(qdot))
        assert np.all(np.abs(qdot) <= arm.velocity_limits + 1e-9)


def test_narrow_range_is_rejected(arm):
    limits = arm.joint_limits.tightened({"theta2": (0.3, 0.3 + 1e-11)})
    with pytest.raises(InvalidInput, match="narrower than twice the limit margin.*theta2"):
        JointPositionLimit(arm, limits)
