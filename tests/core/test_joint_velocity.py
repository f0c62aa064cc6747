"""JointVelocityLimit: bounds from a dict of joints, an (nv,) array or the scene's numerics;
never a silent ±inf on a model that declares none."""

from __future__ import annotations

import mujoco
import numpy as np
import pytest

from qpik import InvalidInput, JointVelocityLimit, ModelError, PositionTask, QPController, Robot, UnknownName


def test_scene_numerics_are_read_when_no_values_are_given():
    arm = Robot.load("arm")
    np.testing.assert_array_equal(JointVelocityLimit(arm).max_velocity, [8.0, 8.0, 8.0, 2.0])
    hexapod = Robot.load("hexapod")
    limit = JointVelocityLimit(hexapod)
    sliders = [hexapod.joint_dofs(f"slider{i}")[0] for i in range(1, 7)]
    np.testing.assert_array_equal(limit.max_velocity[sliders], 0.5)
    hinges = [hexapod.joint_dofs(f"u{i}_{side}")[0] for i in range(1, 7) for side in "ab"]
    np.testing.assert_array_equal(limit.max_velocity[hinges], 5.0)
    # The platform's free joint: one value per dof, linear (m/s) then angular (rad/s).
    np.testing.assert_array_equal(limit.max_velocity[hexapod.joint_dofs("platform")], [1, 1, 1, 5, 5, 5])


def test_a_model_without_speed_limits_needs_them_given(humanoid_path):
    robot = Robot.load(humanoid_path)
    with pytest.raises(ModelError, match=r"declares no joint speed limit.*qpik_velocity_limit_"):
        JointVelocityLimit(robot)
    free = robot.model.joint(0).name
    limit = JointVelocityLimit(robot, {"lfemurrz": 2.0, free: [1, 1, 1, 3, 3, 3]})
    expected = np.full(robot.nv, np.inf)
    expected[:6] = [1, 1, 1, 3, 3, 3]
    expected[robot.joint_dofs("lfemurrz")] = 2.0
    np.testing.assert_array_equal(limit.max_velocity, expected)
    np.testing.assert_array_equal(JointVelocityLimit(robot, {free: 0.5}).max_velocity[:6], 0.5)


def test_bad_values_are_typed_errors(jaco_path):
    robot = Robot.load(jaco_path)
    with pytest.raises(UnknownName, match=r"'jiont_1'.*'joint_1'"):
        JointVelocityLimit(robot, {"jiont_1": 1.0})
    with pytest.raises(InvalidInput, match="positive"):
        JointVelocityLimit(robot, {"joint_1": 0.0})
    with pytest.raises(InvalidInput, match="positive"):
        JointVelocityLimit(robot, np.full(6, np.nan))
    with pytest.raises(InvalidInput, match=r"shape \(6,\)"):
        JointVelocityLimit(robot, np.ones(5))
    with pytest.raises(InvalidInput, match="numbers"):
        JointVelocityLimit(robot, {"joint_1": "fast"})
    with pytest.raises(InvalidInput, match="one number or 1"):
        JointVelocityLimit(robot, {"joint_1": [1.0, 2.0]})


def test_the_qp_keeps_the_given_bounds(jaco_path):
    robot = Robot.load(jaco_path, allow_outside_limits=True)  # joint_2 starts below its range
    mujoco.mj_integratePos(robot.model, robot.q, np.full(robot.nv, 0.4), 1.0)
    robot.update_kinematics()
    task = PositionTask(robot, "wristsite", gain=50.0)
    task.set_target(task.target + [0.3, -0.2, 0.1])  # far: the unbounded QP would be fast
    bounds = {"joint_1": 0.2, "joint_2": 0.3, "joint_3": 0.25}
    limited = QPController(robot, [task], [JointVelocityLimit(robot, bounds)], dt=0.002).compute_velocity().copy()
    free = QPController(robot, [task], dt=0.002).compute_velocity()
    assert np.all(np.abs(free[:3]) > [0.2, 0.3, 0.25])
    assert np.all(np.abs(limited[:3]) <= np.array([0.2, 0.3, 0.25]) + 1e-12)
