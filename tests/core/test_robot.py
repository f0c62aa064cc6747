"""Robot: frames of every type (views of MuJoCo's arrays), checked names, the keyframe rule."""

from __future__ import annotations

import mujoco
import numpy as np
import pytest

from qpik import InvalidInput, Robot, UnknownName


def test_frames_are_views_of_mujoco_arrays_and_follow_the_kinematics(jaco_path):
    robot = Robot.load(jaco_path)
    site, body = robot.frame("wristsite"), robot.frame("b_6", "body")
    assert np.shares_memory(site.position, robot.data.site_xpos)
    assert np.shares_memory(site.rotation, robot.data.site_xmat)
    assert np.shares_memory(body.position, robot.data.xpos) and np.shares_memory(body.rotation, robot.data.xmat)
    before = site.position.copy()
    robot.q[:] = 0.3
    robot.update_kinematics()
    assert not np.allclose(before, site.position)  # the view moved with the kinematics
    np.testing.assert_array_equal(site.position, robot.data.site("wristsite").xpos)
    np.testing.assert_array_equal(body.rotation.ravel(), robot.data.body("b_6").xmat)


@pytest.mark.parametrize("frame_type", ["site", "body", "geom"])
def test_frame_jacobian_is_mujocos_of_that_type(frame_type):
    model = mujoco.MjModel.from_xml_string(NAMED_FRAMES)
    robot = Robot(model)
    robot.q[:] = [0.4, -0.7]
    robot.update_kinematics()
    frame = robot.frame("f", frame_type)
    jacp, jacr = np.zeros((3, robot.nv)), np.zeros((3, robot.nv))
    frame.jacobian(jacp, jacr)
    expected_p, expected_r = np.zeros((3, robot.nv)), np.zeros((3, robot.nv))
    function = {"site": mujoco.mj_jacSite, "body": mujoco.mj_jacBody, "geom": mujoco.mj_jacGeom}[frame_type]
    function(model, robot.data, expected_p, expected_r, frame.id)
    np.testing.assert_array_equal(jacp, expected_p)
    np.testing.assert_array_equal(jacr, expected_r)
    # The three frames named "f" are different points: each type reads its own arrays.
    arrays = {"site": ("site_xpos", "site_xmat"), "body": ("xpos", "xmat"), "geom": ("geom_xpos", "geom_xmat")}
    position, rotation = arrays[frame_type]
    np.testing.assert_array_equal(frame.position, getattr(robot.data, position)[frame.id])
    np.testing.assert_array_equal(frame.rotation.ravel(), getattr(robot.data, rotation)[frame.id])
    others = {t: robot.frame("f", t).position for t in arrays if t != frame_type}
    assert all(not np.allclose(frame.position, p) for p in others.values())
    other = Robot(model)  # another robot of the same model (at qpos0): its own pose
    other.update_kinematics()
    np.testing.assert_array_equal(other.frame_position(frame), getattr(other.data, position)[frame.id])
    np.testing.assert_array_equal(other.frame_rotation(frame).ravel(), getattr(other.data, rotation)[frame.id])
    assert not np.allclose(other.frame_position(frame), frame.position)


# A body, a geom and a site all named "f", at different places.
NAMED_FRAMES = """
<mujoco model="named">
  <compiler angle="radian"/>
  <worldbody>
    <body name="link">
      <joint name="hinge" axis="0 0 1"/>
      <geom type="capsule" fromto="0 0 0 0.5 0 0" size="0.02"/>
      <body name="f" pos="0.5 0 0">
        <joint name="elbow" axis="0 1 0"/>
        <geom name="f" type="sphere" pos="0.2 0.1 0" size="0.03"/>
        <site name="f" pos="0.3 0 0.1"/>
      </body>
    </body>
  </worldbody>
</mujoco>
"""


def test_unknown_names_list_the_close_matches(jaco_path):
    robot = Robot.load(jaco_path)
    with pytest.raises(UnknownName, match=r"unknown site 'wrist'.*close matches: \['wristsite'\]"):
        robot.frame("wrist")
    with pytest.raises(UnknownName, match=r"unknown body 'b6'.*'b_6'"):
        robot.frame("b6", "body")
    with pytest.raises(UnknownName, match=r"unknown joint 'joint1'.*'joint_1'"):
        robot.joint_id("joint1")
    with pytest.raises(UnknownName, match="no named equality"):
        robot.equality_id("loop")
    with pytest.raises(InvalidInput, match="frame_type"):
        robot.frame("wristsite", "link")
    with pytest.raises(InvalidInput, match="must be a string"):
        robot.frame(3)


def test_keyframe_rule(jaco_path):
    # Bundled robots start at their home keyframe; a named keyframe must exist.
    np.testing.assert_allclose(Robot.load("arm").q, [np.pi / 2, 0.0, 0.0, 0.5])
    hexapod = Robot.load("hexapod")
    np.testing.assert_array_equal(hexapod.q, hexapod.model.key("home").qpos)
    with pytest.raises(UnknownName, match=r"unknown keyframe 'hom'.*\['home'\]"):
        Robot.load("arm", keyframe="hom")
    with pytest.raises(UnknownName, match="unknown keyframe 'hom'"):
        Robot(hexapod.model, keyframe="hom")
    # Robot(model) and a path start at qpos0, also on a model without any keyframe...
    np.testing.assert_array_equal(Robot(hexapod.model).q, hexapod.model.qpos0)
    jaco = Robot.load(jaco_path)
    np.testing.assert_array_equal(jaco.q, jaco.model.qpos0)
    # ...and asking such a model for "home" is an error, not a silent qpos0.
    with pytest.raises(UnknownName, match="no named keyframe"):
        Robot.load(jaco_path, keyframe="home")
    assert Robot.load("arm", keyframe=None).q[0] == Robot.load("arm").model.qpos0[0]


def test_joint_dofs_of_every_joint_type(humanoid_path):
    robot = Robot.load(humanoid_path)
    free = robot.model.joint(0).name
    np.testing.assert_array_equal(robot.joint_dofs(free), np.arange(6))
    hinge = robot.model.joint(5).name
    np.testing.assert_array_equal(robot.joint_dofs(hinge), [robot.model.jnt_dofadr[5]])
