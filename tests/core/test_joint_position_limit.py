"""JointPositionLimit: its float path for a few joints equals its vectorised path exactly, on
arrays and on lists (``apply_to_lists``)."""

from __future__ import annotations

import numpy as np
import pytest

from qpik import InvalidInput, JointPositionLimit, Robot


@pytest.mark.parametrize("scene", ["arm", "hexapod"])
@pytest.mark.parametrize("influence", [0.0, 0.05, 0.8])
def test_float_and_vector_paths_are_identical(scene, influence):
    robot = Robot.load(scene)
    from qpik.limits import joint_position

    vector = JointPositionLimit(robot, influence=influence, damper_rate=2.0, gain=0.7)
    vector._scalar_joints = None
    limit = joint_position.SCALAR_JOINTS_MAX
    joint_position.SCALAR_JOINTS_MAX = 100  # the float path for the hexapod's 18 joints too
    try:
        floats = JointPositionLimit(robot, influence=influence, damper_rate=2.0, gain=0.7)
    finally:
        joint_position.SCALAR_JOINTS_MAX = limit
    assert floats._scalar_joints is not None
    rng = np.random.default_rng(1)
    limits = robot.joint_limits
    for _ in range(200):  # inside, near and outside the ranges
        robot.q[limits.qpos_index] = rng.uniform(limits.lower - 0.3, limits.upper + 0.3)
        speed = rng.uniform(0.5, 5.0, robot.nv)
        box_a, box_b = (-speed, speed.copy()), (-speed, speed.copy())
        lists_a, lists_b = ((-speed).tolist(), speed.tolist()), ((-speed).tolist(), speed.tolist())
        floats.apply(0.002, *box_a)
        vector.apply(0.002, *box_b)
        np.testing.assert_array_equal(box_a[0], box_b[0])
        np.testing.assert_array_equal(box_a[1], box_b[1])
        # The box as lists: the float loop itself, and (vectorised) the base class's way through apply
        floats.apply_to_lists(0.002, *lists_a)
        vector.apply_to_lists(0.002, *lists_b)
        assert lists_a == lists_b == (box_a[0].tolist(), box_a[1].tolist())
        q_next = robot.q[limits.qpos_index] + 0.002 * box_a[1][limits.dof_index]
        inside = (robot.q[limits.qpos_index] <= limits.upper)
        assert np.all(q_next[inside] <= limits.upper[inside])  # the upper bound is never stepped past


@pytest.mark.parametrize("value", [np.nan, np.inf, -np.inf])
def test_non_finite_position_is_an_error(value):
    robot = Robot.load("arm")
    limit = JointPositionLimit(robot)
    robot.q[1] = value
    with pytest.raises(InvalidInput, match="theta2"):
        limit.apply(0.002, np.full(4, -1.0), np.full(4, 1.0))


@pytest.mark.parametrize("scene", ["arm", "hexapod"])
def test_apply_from_a_box_equals_copying_the_box_then_applying(scene):
    robot = Robot.load(scene)
    limit = JointPositionLimit(robot, influence=0.05, damper_rate=2.0, gain=0.9)
    rng = np.random.default_rng(2)
    limits = robot.joint_limits
    for _ in range(100):
        robot.q[limits.qpos_index] = rng.uniform(limits.lower - 0.2, limits.upper + 0.2)
        speed = rng.uniform(0.5, 5.0, robot.nv)
        lb, ub = -speed.copy(), speed.copy()
        limit.apply(0.002, lb, ub)
        fused_lb, fused_ub = np.zeros(robot.nv), np.zeros(robot.nv)
        limit.apply_from(0.002, (-speed).tolist(), speed.tolist(), fused_lb, fused_ub)
        np.testing.assert_array_equal(fused_lb, lb)
        np.testing.assert_array_equal(fused_ub, ub)


@pytest.mark.parametrize("argument, value", [
    ("influence", "0.1 rad"), ("influence", [0.1, 0.2]), ("influence", None), ("influence", -0.1),
    ("damper_rate", "fast"), ("damper_rate", [20.0]), ("damper_rate", 0.0), ("damper_rate", np.nan),
    ("gain", "1"), ("gain", [0.5]), ("gain", 0.0), ("gain", 1.5),
    ("margin", "tiny"), ("margin", [1e-10]), ("margin", np.inf)])
def test_a_bad_parameter_is_a_typed_error_naming_it(argument, value):
    """Strings and lists used to escape as TypeError/ValueError from a comparison."""
    with pytest.raises(InvalidInput, match=argument.replace("_", " ").split()[0]):
        JointPositionLimit(Robot.load("arm"), **{argument: value})


def test_numbers_of_any_type_are_accepted_as_floats():
    limit = JointPositionLimit(Robot.load("arm"), gain=np.float32(0.5), influence=1, damper_rate=np.int64(10))
    assert (limit.gain, limit.influence, limit.damper_rate) == (0.5, 1.0, 10.0)
    assert all(type(v) is float for v in (limit.gain, limit.influence, limit.damper_rate))
