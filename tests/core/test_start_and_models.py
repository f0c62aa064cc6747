"""Starting states, speed-limit declarations, model inputs and the one-robot rule."""

from __future__ import annotations

import re
from pathlib import Path

import mujoco
import numpy as np
import pytest

from qpik import (
    FrameTask,
    InvalidInput,
    JointPositionLimit,
    ModelError,
    OutsideJointLimits,
    PositionTask,
    PostureTask,
    QPController,
    Robot,
)
from qpik.robots import BUNDLED

ARM_XML = BUNDLED["arm"][0]
ARM_URDF = ARM_XML.with_name("arm.urdf")

# model -> (joints outside their range at qpos0, the torso body)
OUTSIDE_AT_QPOS0 = {
    "ant": ({"ankle_1", "ankle_2", "ankle_3", "ankle_4"}, "torso"),
    "gym_humanoid": ({"right_knee", "left_knee"}, "torso"),
    "humanoid": ({"ltibiarx", "rtibiarx"}, "root"),
}


def _third_party(name: str) -> Path:
    pytest.importorskip("gymnasium" if name in ("ant", "gym_humanoid") else "dm_control")
    from qpik.models import third_party

    return third_party(name)


@pytest.mark.parametrize("name", sorted(OUTSIDE_AT_QPOS0))
def test_a_start_outside_the_ranges_is_an_error_naming_the_joints(name):
    joints, torso = OUTSIDE_AT_QPOS0[name]
    robot = Robot.load(_third_party(name))
    controller = QPController(robot, [FrameTask(robot, torso, "body")], [JointPositionLimit(robot)], dt=0.01)
    with pytest.raises(OutsideJointLimits) as info:
        controller.compute_velocity()
    assert set(info.value.excess) == joints
    for joint in joints:  # the excess is the distance to the nearer bound of the range
        j = robot.joint_id(joint)
        lower, upper = robot.model.jnt_range[j]
        value = robot.model.qpos0[robot.model.jnt_qposadr[j]]
        assert info.value.excess[joint] == pytest.approx(max(lower - value, value - upper), rel=1e-12)
        assert joint in str(info.value)
    # set_q refuses the same configuration at once.
    with pytest.raises(OutsideJointLimits, match="allow_outside_limits"):
        robot.set_q(robot.model.qpos0)


@pytest.mark.parametrize("name", sorted(OUTSIDE_AT_QPOS0))
def test_with_the_opt_in_the_limits_bring_the_joints_back_while_the_torso_is_held(name):
    """A hard torso pose task at its start pose; the position limit returns the joints
    that start outside into range (gain 1: in one step), the torso does not move."""
    joints, torso = OUTSIDE_AT_QPOS0[name]
    robot = Robot.load(_third_party(name), allow_outside_limits=True)
    body = FrameTask(robot, torso, "body", hard=True)
    start = body.frame.position.copy(), body.frame.rotation.copy()
    controller = QPController(robot, [body, PostureTask(robot, gain=1.0, weight=1e-3)],
                              [JointPositionLimit(robot)], dt=0.01)
    names = list(robot.joint_limits.names)
    index = [names.index(j) for j in joints]
    for _ in range(20):
        robot.integrate(controller.compute_velocity(), 0.01)
    robot.update_kinematics()
    values = robot.q[robot.joint_limits.qpos_index[index]]
    assert np.all(values >= robot.joint_limits.lower[index] - 1e-9)
    assert np.all(values <= robot.joint_limits.upper[index] + 1e-9)
    # The torso's pose is the free joint's alone: held to the solver's tolerance.
    np.testing.assert_allclose(body.frame.position, start[0], atol=1e-8)
    np.testing.assert_allclose(body.frame.rotation, start[1], atol=1e-8)
    robot.allow_outside_limits = False
    robot.set_q(robot.q.copy())  # inside now: accepted


def test_a_keyframe_outside_is_refused_at_load_with_the_excess():
    xml = ARM_XML.read_text().replace("</mujoco>", '<keyframe><key name="out" qpos="0 2.7 0 0.5"/></keyframe></mujoco>')
    model = mujoco.MjModel.from_xml_string(xml)
    with pytest.raises(OutsideJointLimits, match=r"theta2 = 2\.7 not in \[-2\.6, 2\.6\] \(by 0\.1\)") as info:
        Robot(model, keyframe="out")
    assert info.value.excess["theta2"] == pytest.approx(0.1)
    assert isinstance(info.value, ModelError)
    robot = Robot(model, keyframe="out", allow_outside_limits=True)
    assert robot.q[1] == 2.7


def test_velocity_limits_declared_for_some_joints_only_is_an_error():
    text = ARM_XML.read_text()
    partial = re.sub(r'<numeric name="qpik_velocity_limit_(theta2|d4)"[^>]*/>', "", text)
    with pytest.raises(ModelError, match=r"some joints but not for \['d4', 'theta2'\]"):
        Robot(mujoco.MjModel.from_xml_string(partial))
    none = re.sub(r'<numeric name="qpik_velocity_limit_[^"]*"[^>]*/>', "", text)
    assert np.all(np.isinf(Robot(mujoco.MjModel.from_xml_string(none)).velocity_limits))


def test_load_takes_a_path_a_model_or_a_spec():
    by_path = Robot.load(str(ARM_XML))
    by_model = Robot.load(mujoco.MjModel.from_xml_path(str(ARM_XML)))
    spec = mujoco.MjSpec.from_file(str(ARM_XML))
    by_spec, direct = Robot.load(spec), Robot(mujoco.MjSpec.from_file(str(ARM_XML)))
    for robot in (by_model, by_spec, direct):
        assert robot.nq == by_path.nq == 4
        np.testing.assert_array_equal(robot.velocity_limits, by_path.velocity_limits)
    with pytest.raises(InvalidInput, match="MjModel or a mujoco.MjSpec, got int"):
        Robot.load(42)
    with pytest.raises(InvalidInput, match="expected a mujoco.MjModel or mujoco.MjSpec, got str"):
        Robot("arm")


def test_the_repository_urdf_loads_through_mujoco_with_the_mjcf_kinematics():
    """The URDF (with its <mujoco> compiler bounds) against arm.xml: same end-effector
    position at random configurations inside the ranges (both MuJoCo's forward kinematics
    of the same DH chain; 1e-12 m, a few roundings on lengths of order 1 m)."""
    urdf, mjcf = Robot.load(ARM_URDF), Robot.load(str(ARM_XML))
    tip_urdf, tip_mjcf = urdf.frame("end_effector", "body"), mjcf.frame("end_effector", "site")
    rng = np.random.default_rng(3)
    for _ in range(5):
        q = rng.uniform(mjcf.joint_limits.lower, mjcf.joint_limits.upper)
        urdf.set_q(q)
        mjcf.set_q(q)
        urdf.update_kinematics()
        mjcf.update_kinematics()
        np.testing.assert_allclose(tip_urdf.position, tip_mjcf.position, atol=1e-12)


def test_a_urdf_without_inertials_gets_a_hint(tmp_path):
    text = ARM_URDF.read_text()
    bare = tmp_path / "bare.urdf"
    bare.write_text(re.sub(r"<mujoco>\s*<compiler.*?</mujoco>", "", text, flags=re.S))
    with pytest.raises(ModelError, match=r"cannot load URDF .*mass and inertia.*<inertial>.*boundmass"):
        Robot.load(bare)


def test_a_task_or_limit_of_another_robot_is_refused():
    arm, twin, hexapod = Robot.load("arm"), Robot.load("arm"), Robot.load("hexapod")
    mine = PositionTask(arm, "end_effector", axes="xy", gain=10.0)
    with pytest.raises(InvalidInput, match="another Robot instance of the same model"):
        QPController(arm, [mine, PositionTask(twin, "end_effector", axes="xy", gain=10.0)], dt=0.01)
    with pytest.raises(InvalidInput, match="limit 'JointPositionLimit' was built on another Robot instance"):
        QPController(arm, [mine], [JointPositionLimit(twin)], dt=0.01)
    hexapod_task = PostureTask(hexapod, gain=1.0)
    with pytest.raises(InvalidInput, match="robot 'hexapod'"):
        QPController(arm, [mine, hexapod_task], dt=0.01)
    from qpik import HierarchicalController, PseudoinverseController, SNSController

    for make in (lambda: HierarchicalController(arm, [mine, hexapod_task], dt=0.01),
                 lambda: SNSController(arm, [mine, hexapod_task], dt=0.01),
                 lambda: PseudoinverseController(arm, [mine, hexapod_task])):
        with pytest.raises(InvalidInput, match="robot 'hexapod'|reads another robot"):
            make()
    for make in (lambda: HierarchicalController(arm, [mine], [JointPositionLimit(hexapod)], dt=0.01),
                 lambda: SNSController(arm, [mine], [JointPositionLimit(hexapod)], dt=0.01)):
        with pytest.raises(InvalidInput, match="limit 'JointPositionLimit' was built on robot 'hexapod'"):
            make()
