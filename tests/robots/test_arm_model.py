"""The arm's MJCF scene against the DH formulas of docs/arm.md (independent reference)."""

import mujoco
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from qpik.robots.arm import model as arm
from qpik.robot import Robot

angles = st.floats(-np.pi, np.pi, allow_nan=False)
strokes = st.floats(0.0, 1.0, allow_nan=False)


@pytest.fixture(scope="module")
def robot():
    return Robot.load("arm")


def _mujoco_pose(robot, q):
    robot.set_q(q)
    robot.update_kinematics()
    site = robot.site_id("end_effector")
    jacp = np.zeros((3, robot.nv))
    robot.site_jacobian(site, jacp)
    return robot.site_position(site).copy(), jacp


@settings(max_examples=200, deadline=None)
@given(angles, angles, angles, strokes)
def test_mujoco_matches_dh_formulas(t1, t2, t3, d4):
    robot = Robot.load("arm", allow_outside_limits=True)  # the formulas hold beyond the ranges too
    q = np.array([t1, t2, t3, d4])
    position, jacp = _mujoco_pose(robot, q)
    assert np.max(np.abs(position[:2] - arm.end_effector_position(q))) <= 1e-12
    assert abs(position[2]) <= 1e-12
    assert np.max(np.abs(jacp[:2] - arm.position_jacobian(q))) <= 1e-12
    assert np.max(np.abs(jacp[2])) <= 1e-12  # planar: no z motion
    # The DH product and the closed form agree too.
    T = arm.forward_kinematics(q)
    assert np.max(np.abs(T[:2, 3] - arm.end_effector_position(q))) <= 1e-12
    assert np.max(np.abs(T[:3, 2] - arm.prismatic_axis(q))) <= 1e-12


def test_jacobian_at_source_start_matches_spec(robot):
    q0 = np.array([np.pi / 2, 0.0, 0.0, 0.5])
    position, jacp = _mujoco_pose(robot, q0)
    np.testing.assert_allclose(position[:2], [0.5, 2.0], atol=1e-12)
    np.testing.assert_allclose(jacp[:2], [[-2, -1, 0, 1], [0.5, 0.5, 0.5, 0]], atol=1e-12)
    assert np.linalg.matrix_rank(jacp[:2]) == 2  # two redundant degrees of mobility


def test_mujoco_jacobian_matches_finite_differences(robot):
    rng = np.random.default_rng(3)
    for _ in range(10):
        q = np.concatenate([rng.uniform(-2.5, 2.5, 3), rng.uniform(0.1, 0.9, 1)])
        _, jacp = _mujoco_pose(robot, q)
        fd = np.zeros((2, 4))
        for k in range(4):
            dq = np.zeros(4)
            dq[k] = 1e-6
            fd[:, k] = (arm.end_effector_position(q + dq) - arm.end_effector_position(q - dq)) / 2e-6
        assert np.max(np.abs(fd - jacp[:2])) < 1e-8


def test_scene_is_in_radians_with_documented_limits():
    robot = Robot.load("arm")
    m = robot.model
    np.testing.assert_allclose(m.jnt_range, [[-np.pi, np.pi], [-2.6, 2.6], [-2.6, 2.6], [0.0, 1.0]])
    assert robot.joint_limits.names == ("theta1", "theta2", "theta3", "d4")
    np.testing.assert_allclose(robot.velocity_limits, [8.0, 8.0, 8.0, 2.0])
    assert m.opt.timestep == pytest.approx(0.002)
    np.testing.assert_allclose(robot.q, [np.pi / 2, 0, 0, 0.5])  # the "home" keyframe
    assert m.nu == 8  # position + velocity servo per joint


def test_sigma_proxy_matches_formula():
    rng = np.random.default_rng(0)
    for _ in range(20):
        q = rng.uniform(-2, 2, 4)
        assert arm.sigma(q) == pytest.approx(0.5 * (np.sin(q[1]) ** 2 + np.sin(q[2]) ** 2))
        fd = np.array([(arm.sigma(q + e) - arm.sigma(q - e)) / 2e-6 for e in np.eye(4) * 1e-6])
        np.testing.assert_allclose(arm.sigma_gradient(q), fd, atol=1e-9)


def test_bad_configuration_is_rejected(robot):
    from qpik.errors import InvalidInput

    with pytest.raises(InvalidInput):
        robot.set_q([0.0, 0.0, 0.0])
    with pytest.raises(InvalidInput):
        robot.set_q([0.0, np.nan, 0.0, 0.0])
    with pytest.raises(InvalidInput):
        arm.end_effector_position([0.0, 0.0, np.inf, 0.0])


def test_mjdata_is_worked_in_place(robot):
    q_view = robot.q
    robot.set_q([0.1, 0.2, 0.3, 0.4])
    assert q_view is robot.data.qpos or np.shares_memory(q_view, robot.data.qpos)
    mujoco.mj_kinematics(robot.model, robot.data)
