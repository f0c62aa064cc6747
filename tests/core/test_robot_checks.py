"""Robot: model sanity checks at load, and the validation of ``integrate``.

Each defect found by the fuzz (a NaN range silently dropping the limit, a keyframe outside
the ranges loading silently, a zero or NaN timestep, ``integrate`` accepting a bad dt or
q̇) has a test here that fails on the code before the checks.
"""

from pathlib import Path

import mujoco
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from qpik.errors import InvalidInput, ModelError, UnknownName
from qpik.robot import Robot
from qpik.robots import BUNDLED

ARM_XML = BUNDLED["arm"][0].read_text()
HOME = 'qpos="1.5707963267948966 0 0 0.5"'


def _arm_variant(tmp_path: Path, old: str, new: str) -> Path:
    assert old in ARM_XML
    path = tmp_path / "arm_variant.xml"
    path.write_text(ARM_XML.replace(old, new, 1))
    return path


@pytest.mark.parametrize("timestep", ["0", "-0.002", "nan", "inf"])
def test_a_timestep_that_is_not_positive_and_finite_is_a_model_error(tmp_path, timestep):
    path = _arm_variant(tmp_path, 'timestep="0.002"', f'timestep="{timestep}"')
    with pytest.raises(ModelError, match="timestep"):
        Robot.load(path)


@pytest.mark.parametrize("joint_range", ["nan 2.6", "-2.6 nan", "nan nan"])
def test_a_nan_joint_range_is_a_model_error_naming_the_joint(tmp_path, joint_range):
    # MuJoCo loads it and drops theta2's limit without a word.
    path = _arm_variant(tmp_path, 'range="-2.6 2.6"', f'range="{joint_range}"')
    mujoco.MjModel.from_xml_path(str(path))  # MuJoCo compiles it
    with pytest.raises(ModelError, match="theta2"):
        Robot.load(path)


def test_a_nan_range_on_an_explicitly_limited_joint_is_a_model_error(tmp_path):
    path = _arm_variant(tmp_path, 'range="-2.6 2.6"', 'limited="true" range="nan 2.6"')
    with pytest.raises(ModelError, match="theta2"):
        Robot.load(path)


def test_a_reversed_range_that_mujoco_ignores_is_a_model_error(tmp_path):
    path = _arm_variant(tmp_path, 'range="-2.6 2.6"', 'range="2.6 -2.6"')
    assert not mujoco.MjModel.from_xml_path(str(path)).jnt_limited[1]  # MuJoCo: unlimited, silently
    with pytest.raises(ModelError, match="theta2.*lower bound must be below"):
        Robot.load(path)


def test_an_explicitly_unlimited_joint_with_a_valid_range_loads(tmp_path):
    path = _arm_variant(tmp_path, 'range="-2.6 2.6"', 'limited="false" range="-2.6 2.6"')
    robot = Robot.load(path)
    assert "theta2" not in robot.joint_limits.names


def test_a_start_keyframe_outside_the_ranges_is_a_model_error(tmp_path):
    path = _arm_variant(tmp_path, HOME, 'qpos="1.5707963267948966 0 0 1.5"')  # d4 ∈ [0, 1]
    with pytest.raises(ModelError, match=r"keyframe 'home'.*d4 = 1\.5 not in \[0, 1\]"):
        Robot.load(path, keyframe="home")
    # Starting elsewhere is the way out the message names.
    assert np.all(Robot.load(path, keyframe=None).q == 0.0)


def test_a_keyframe_a_rounding_outside_a_range_loads(tmp_path):
    path = _arm_variant(tmp_path, HOME, 'qpos="1.5707963267948966 0 0 1.0000000000001"')
    assert Robot.load(path, keyframe="home").q[3] == pytest.approx(1.0, abs=1e-12)


def test_a_non_finite_keyframe_is_a_model_error(tmp_path):
    path = _arm_variant(tmp_path, HOME, 'qpos="nan 0 0 0.5"')
    with pytest.raises(ModelError, match="non-finite"):
        Robot.load(path, keyframe="home")


def test_non_finite_kinematics_at_the_start_are_a_model_error(tmp_path):
    path = _arm_variant(tmp_path, '<body name="link1">', '<body name="link1" pos="nan 0 0">')
    with pytest.raises(ModelError, match="not finite"):
        Robot.load(path)


def test_an_unknown_keyframe_lists_close_matches_and_a_path_starts_at_qpos0(tmp_path):
    with pytest.raises(UnknownName, match=r"close matches: \['home'\]"):
        Robot.load("arm", keyframe="hom")
    path = _arm_variant(tmp_path, '<key name="home"', '<key name="rest"')
    assert np.all(Robot.load(path).q == 0.0)
    np.testing.assert_array_equal(Robot.load(path, keyframe="rest").q, [np.pi / 2, 0, 0, 0.5])


def test_unknown_names_list_close_matches():
    robot = Robot.load("arm")
    with pytest.raises(UnknownName, match="close matches: .*'end_effector'"):
        robot.site_id("end_efector")
    with pytest.raises(UnknownName, match="close matches: .*'theta2'"):
        robot.joint_id("theta_2")
    with pytest.raises(UnknownName, match="close matches: .*'theta3'"):
        robot.joint_limits.tightened({"theta_3": (-1.0, 1.0)})


def test_a_tightened_range_must_lie_inside_the_joint_range():
    limits = Robot.load("arm").joint_limits
    with pytest.raises(InvalidInput, match="outside the joint's range"):
        limits.tightened({"theta2": (-3.0, 1.0)})
    with pytest.raises(InvalidInput, match="below upper"):
        limits.tightened({"theta2": (float("nan"), 1.0)})
    assert limits.tightened({"theta2": (-1.0, 1.0)}).lower[1] == -1.0


@pytest.mark.parametrize("dt", [0.0, -0.002, float("nan"), float("inf"), None, "0.002"])
def test_integrate_rejects_a_step_that_is_not_positive_and_finite(dt):
    robot = Robot.load("arm")
    before = robot.q.copy()
    with pytest.raises(InvalidInput, match="dt"):
        robot.integrate(np.ones(robot.nv), dt)
    np.testing.assert_array_equal(robot.q, before)


@pytest.mark.parametrize("qdot", [[np.nan, 0, 0, 0], [0, np.inf, 0, 0], [np.inf, -np.inf, 0, 0],
                                  [0.0, 0.0, 0.0], [[0.0]] * 4, "fast"])
def test_integrate_rejects_a_non_finite_or_misshaped_velocity(qdot):
    robot = Robot.load("arm")
    before = robot.q.copy()
    with pytest.raises(InvalidInput, match="joint velocity"):
        robot.integrate(qdot if isinstance(qdot, str) else np.array(qdot, dtype=float), 0.002)
    np.testing.assert_array_equal(robot.q, before)


def test_integrate_accepts_lists_strided_and_read_only_arrays():
    robot = Robot.load("hexapod")
    qdot = np.zeros((robot.nv, 2))
    qdot[0, 0] = 0.1  # slider1, a slide joint: q1 += 0.1 dt
    start = robot.q[0]
    robot.integrate(qdot[:, 0], 0.01)
    frozen = qdot[:, 0].copy()
    frozen.flags.writeable = False
    robot.integrate(frozen, 0.01)
    robot.integrate(list(frozen), 0.01)
    assert robot.q[0] == pytest.approx(start + 3 * 0.001, abs=1e-15)


@settings(max_examples=50, deadline=None)
@given(st.lists(st.floats(-5, 5) | st.just(float("nan")), min_size=4, max_size=4), st.floats(-5, 5))
def test_vectorised_violations_equal_the_per_configuration_violation(q, shift):
    limits = Robot.load("arm").joint_limits
    rows = np.array([q, np.array(q) + shift, np.zeros(4), [-0.0, -0.0, -0.0, -0.0]])
    vectorised = limits.violations(rows)
    expected = [limits.violation(row) for row in rows]
    np.testing.assert_array_equal(vectorised, expected)
    index = limits.qpos_index  # the definition, one configuration at a time (a NaN counts 0.0)
    reference = [max(0.0, np.max(limits.lower - row[index]), np.max(row[index] - limits.upper)) for row in rows]
    np.testing.assert_array_equal(vectorised, reference)
    assert not np.any(np.signbit(vectorised))


CART_POLE = """<mujoco><compiler angle="radian"/><worldbody><body name="cart">
<joint name="slide" type="slide" axis="1 0 0"/><geom size="0.1"/>
<body name="pole" pos="0 0 0.5"><joint name="hinge" axis="0 1 0"/><geom size="0.05"/>
<site name="tip" pos="0 0 0.5"/></body></body></worldbody></mujoco>"""


@pytest.mark.parametrize("value", [2e10, -1e11, np.inf, np.nan])
def test_a_configuration_mujoco_would_reset_is_refused_by_one_robot_and_by_n(value):
    """Past 1e10 (mjMAXVAL) MuJoCo's forward resets a configuration to qpos0: the batch's
    frames would silently be qpos0's while one robot's are at q. Both refuse it, naming
    the joint (and the world); a world within it is computed as before."""
    from qpik import batch
    from qpik.errors import InvalidWorlds
    model = mujoco.MjModel.from_xml_string(CART_POLE)
    one = Robot(model, allow_outside_limits=True)
    one.q[:] = [value, 0.2]
    with pytest.raises(InvalidInput, match="joint slide"):
        one.ensure_kinematics()
    robots = batch.Robot(model, n=3, allow_outside_limits=True)
    robots.q[:] = [[0.3, 0.2], [value, 0.2], [1e9, 0.1]]
    with pytest.raises(InvalidWorlds, match=r"not finite or beyond 1e\+10.* in worlds 1 \(world 1: joint slide") as refused:
        robots.ensure_kinematics()
    assert list(refused.value.worlds) == [1]
    robots.q[1] = [0.5, 0.2]
    robots.ensure_kinematics()
    one.q[:] = [1e9, 0.1]
    one.ensure_kinematics()
    # The same MuJoCo arithmetic in both: equal to a few roundings of the position's norm.
    expected = one.frame("tip").position
    assert np.linalg.norm(robots.frame("tip").positions[2] - expected) <= 4 * np.finfo(float).eps * np.linalg.norm(expected)
