"""Manipulability measures: Yoshikawa's analytic gradient against central finite differences
(MuJoCo's own tangent steps, so free and ball dofs included) on the bundled robots, the
third-party models and a model with ball, free, hinge and slide joints; σ's joints."""

from __future__ import annotations

import mujoco
import numpy as np
import pytest

from qpik import InvalidInput, ManipulabilityTask, Robot, SigmaProxy, UnknownName, Yoshikawa
from qpik.robots.arm import model as arm

# Free base, a ball joint, then a hinge and a slide in one body.
MIXED = """
<mujoco model="mixed">
  <compiler angle="radian"/>
  <worldbody>
    <body name="base">
      <freejoint/>
      <geom size="0.1"/>
      <body name="upper" pos="0.3 0 0">
        <joint name="shoulder" type="ball"/>
        <geom size="0.1"/>
        <body name="lower" pos="0.3 0.1 0">
          <joint name="elbow" axis="0 1 0"/>
          <joint name="ram" type="slide" axis="1 0 0"/>
          <geom size="0.1"/>
          <site name="tip" pos="0.2 0.1 0.05"/>
        </body>
      </body>
    </body>
  </worldbody>
</mujoco>
"""

# model -> (frame, frame type, translational rows, rotational rows)
CASES = [
    ("arm", "end_effector", "site", "xy", ""),
    ("hexapod", "leg2_tip", "site", "xyz", ""),
    ("hexapod", "leg4", "body", "", "xz"),
    ("jaco", "wristsite", "site", "xyz", "xyz"),
    ("humanoid", "lhand", "body", "xyz", ""),
    ("humanoid", "rfoot_touch", "site", "xyz", "xz"),
    ("pusher", "tips_arm", "body", "xyz", "xyz"),
    ("pusher", "tip_arml", "geom", "xz", ""),
    ("mixed", "tip", "site", "xyz", ""),
    ("mixed", "tip", "site", "xyz", "xyz"),
    ("mixed", "lower", "body", "yz", "z"),
]


def robot_for(model_path, name: str) -> Robot:
    if name == "mixed":
        return Robot(mujoco.MjModel.from_xml_string(MIXED))
    return Robot.load(model_path(name))


def central_differences(measure, robot: Robot, step: float = 1e-6) -> np.ndarray:
    """∂m/∂q_k ≈ (m(q ⊕ h e_k) − m(q ⊖ h e_k)) / 2h, with MuJoCo's mj_integratePos."""
    q0 = robot.q.copy()
    gradient = np.zeros(robot.nv)
    for k in range(robot.nv):
        values = []
        for h in (step, -step):
            robot.q[:] = q0
            mujoco.mj_integratePos(robot.model, robot.q, np.eye(robot.nv)[k] * h, 1.0)
            robot.update_kinematics()
            values.append(measure.value())
        gradient[k] = (values[0] - values[1]) / (2 * step)
    robot.q[:] = q0
    robot.update_kinematics()
    return gradient


@pytest.mark.parametrize("name, frame, frame_type, axes, orientation_axes", CASES)
def test_yoshikawa_gradient_matches_finite_differences(model_path, name, frame, frame_type, axes, orientation_axes):
    robot = robot_for(model_path, name)
    rng = np.random.default_rng(7)
    for _ in range(2):
        mujoco.mj_integratePos(robot.model, robot.q, rng.normal(scale=0.4, size=robot.nv), 1.0)
        robot.update_kinematics()
        measure = Yoshikawa(robot, frame, frame_type, axes=axes, orientation_axes=orientation_axes)
        gradient = robot.present(measure.gradient()).copy()  # (nv,): the robot's one world
        fd = central_differences(measure, robot)
        assert np.max(np.abs(fd)) > 1e-3  # a measure that varies, so the check can fail
        np.testing.assert_allclose(gradient, fd, rtol=0, atol=1e-6 * np.max(np.abs(fd)))


def test_yoshikawa_on_the_arm_is_the_closed_form():
    """The planar arm: w = |det J| of its 2 x 4 position Jacobian's Gram matrix, from the DH model."""
    q = np.array([0.4, 0.9, -0.6, 0.7])
    robot = Robot.load("arm")
    robot.set_q(q)
    robot.update_kinematics()
    J = arm.position_jacobian(q)
    assert Yoshikawa(robot, "end_effector", axes="xy").value() == pytest.approx(np.sqrt(np.linalg.det(J @ J.T)), rel=1e-12)
    assert Yoshikawa(robot, "end_effector", axes="xyz").value() == pytest.approx(0.0, abs=1e-9)  # z row is zero


def test_singular_configuration_has_zero_measure_and_gradient():
    robot = Robot(mujoco.MjModel.from_xml_string(MIXED))
    measure = Yoshikawa(robot, "base", "body", axes="", orientation_axes="xyz")  # the base's angular rows...
    gradient = robot.present(measure.gradient())
    assert gradient.shape == (robot.nv,)
    assert measure.value() == pytest.approx(1.0)  # ...are the identity: w = 1, constant
    np.testing.assert_allclose(gradient, 0.0, atol=1e-15)
    lifeless = Yoshikawa(Robot.load("arm"), "end_effector", axes="z")  # the planar arm never moves along z
    gradient = lifeless.robot.present(lifeless.gradient())
    assert lifeless.value() == 0.0
    np.testing.assert_array_equal(gradient, 0.0)


def test_manipulability_task_follows_the_gradient_on_its_dofs(humanoid_path):
    robot = Robot.load(humanoid_path)
    measure = Yoshikawa(robot, "lhand", "body")
    task = ManipulabilityTask(robot, measure, gain=3.0)
    task.update()
    gradient = robot.present(measure.gradient()).copy()
    assert task.joint_space and 0 not in task.dofs  # the free base is left out
    np.testing.assert_allclose(task.target_velocity, 3.0 * gradient[task.dofs])


def test_sigma_proxy_takes_its_joints_explicitly(jaco_path):
    robot = Robot.load(jaco_path)
    sigma = SigmaProxy(robot, ["joint_2", "joint_3"])
    robot.q[1:3] = [0.4, 1.1]
    gradient = robot.present(sigma.gradient())
    np.testing.assert_allclose(gradient, [0, np.sin(0.4) * np.cos(0.4), np.sin(1.1) * np.cos(1.1), 0, 0, 0])
    assert sigma.value() == pytest.approx(0.5 * (np.sin(0.4) ** 2 + np.sin(1.1) ** 2))
    with pytest.raises(TypeError):
        SigmaProxy(robot)  # no default joints: ("theta2", "theta3") are the arm's
    with pytest.raises(UnknownName, match="theta2"):
        SigmaProxy(robot, ["theta2", "theta3"])
    with pytest.raises(InvalidInput):
        SigmaProxy(robot, "joint_2")
    with pytest.raises(InvalidInput, match="ball or free"):
        SigmaProxy(Robot(mujoco.MjModel.from_xml_string(MIXED)), ["shoulder"])


def test_a_diverged_configuration_is_a_divergence_error_not_a_warning():
    """Gradient ascent on w with an unlimited slide joint (the any-robot fuzz: the
    pseudoinverse law, no limits) extends the joint without end; once JJᵀ overflowed the
    task warned (RuntimeWarning from the determinant) on every step. A DivergenceError
    now, with no warning; a long but finite extension still gives a finite gradient. The
    configuration itself is refused past 1e10 (where MuJoCo resets one), so the overflow
    comes from a site 1e200 out."""
    from qpik import DivergenceError

    xml = """<mujoco><worldbody><body><joint name="h" axis="0 0 1"/><geom size="0.05" mass="1"/>
      <body><joint name="s" type="slide" axis="1 0 0"/><geom size="0.05" mass="1"/>
      <site name="tip" pos="0.5 0 0"/></body></body></worldbody></mujoco>"""
    robot = Robot(mujoco.MjModel.from_xml_string(xml))
    task = ManipulabilityTask(robot, Yoshikawa(robot, "tip", "site", axes="xy"))
    robot.set_q([0.3, 1e3])
    robot.update_kinematics()
    task.update()
    assert np.all(np.isfinite(task.target_velocity)) and np.abs(task.target_velocity).max() > 0
    robot.set_q([0.3, 1e200])  # refused past 1e10, where MuJoCo resets a configuration
    with pytest.raises(InvalidInput, match=r"beyond 1e\+10.*joint s at 1e\+200"):
        robot.update_kinematics()
    robot = Robot(mujoco.MjModel.from_xml_string(xml.replace('pos="0.5 0 0"', 'pos="1e200 0 0"')))
    task = ManipulabilityTask(robot, Yoshikawa(robot, "tip", "site", axes="xy"))
    robot.set_q([0.3, 1.0])
    robot.update_kinematics()
    with pytest.raises(DivergenceError, match="overflowed"):
        task.update()
