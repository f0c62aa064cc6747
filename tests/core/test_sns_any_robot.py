"""SNSController on models qpik did not ship with: a small generated chain started with a
joint outside its range, and a model without degrees of freedom."""

import warnings

import mujoco
import numpy as np
import pytest

from qpik.controllers.qp import QPController
from qpik.controllers.sns import SNSController
from qpik.errors import InvalidInput
from qpik.limits import JointPositionLimit, JointVelocityLimit
from qpik.robot import Robot
from qpik.tasks import PositionTask, PostureTask

DT = 0.01  # s
SPEED = 2.0  # rad/s, every joint's velocity limit

# Three hinges: two about z, the last about y (so a task in x and z needs all three).
CHAIN = """<mujoco><compiler angle="radian"/><worldbody>
<body name="l0"><joint name="j0" axis="0 0 1" range="-1 1"/>
  <geom type="capsule" fromto="0 0 0 0.3 0 0" size="0.02"/>
<body name="l1" pos="0.3 0 0"><joint name="j1" axis="0 0 1" range="-0.5 0.5"/>
  <geom type="capsule" fromto="0 0 0 0.3 0 0" size="0.02"/>
<body name="l2" pos="0.3 0 0"><joint name="j2" axis="0 1 0" range="-0.5 0.5"/>
  <geom type="capsule" fromto="0 0 0 0.3 0 0" size="0.02"/>
  <site name="tip" pos="0.3 0 0"/>
</body></body></body></worldbody></mujoco>"""


def _chain_outside(posture: bool):
    """j2 started 0.4 rad below its range; the tip asked to x = 0.05, z = 0.2."""
    robot = Robot(mujoco.MjModel.from_xml_string(CHAIN), allow_outside_limits=True)
    robot.set_q(np.array([-0.2, -0.34, -0.9]))
    robot.update_kinematics()
    position = PositionTask(robot, "tip", axes="xz", gain=20.0)
    position.set_target(np.array([0.05, 0.2]))
    tasks = [position]
    if posture:
        rest = PostureTask(robot, target=np.zeros(3), gain=5.0)
        rest.priority = 1
        tasks.append(rest)
    limits = [JointPositionLimit(robot), JointVelocityLimit(robot, np.full(3, SPEED))]
    return robot, position, SNSController(robot, tasks, limits, dt=DT)


@pytest.mark.parametrize("posture", [False, True], ids=["position", "position+posture"])
def test_a_joint_outside_its_range_is_brought_back_without_a_warning_or_error(posture):
    """The joint outside its range leaves passes that no scale of the task fits in (task
    scale −1, "none"), which used to be passed on as the rank threshold of the next pass:
    a zero singular value then counted as rank, a division by zero (a RuntimeWarning)
    and a DivergenceError. Now every step returns a velocity inside the box with a scale
    in [0, 1] (never −0.0); a task executed (s > 0) moves in its own direction, J q̇ = s v
    (the SNS promise); and j2 climbs back into its range at the speed the box allows.
    (Once back, j2 rests on its bound and the x-z task, which needs j2 to go on, is left
    out: the other two hinges turn about z and cannot move the tip in z, so no scale keeps
    the task's direction; that is SNS's rule, the QP would trade direction for progress.)"""
    robot, position, sns = _chain_outside(posture)
    lower = robot.joint_limits.lower[2]
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        for _ in range(60):
            q2 = robot.q[2]
            qdot = sns.compute_velocity()
            # within the box (rounding only: the last step clips to it)
            assert np.all(qdot >= sns.lb) and np.all(qdot <= sns.ub)
            s = sns.task_scale[0]
            assert 0.0 <= s <= 1.0 and np.copysign(1.0, s) == 1.0
            if s > 0.0:  # tolerance: rounding of |q̇| ≤ 2 rad/s through J (entries ≤ 0.9 m)
                np.testing.assert_allclose(position.jacobian @ qdot, s * position.target_velocity,
                                           rtol=0, atol=1e-12)
            if q2 < lower:  # outside: back toward the range, at the speed limit or the step to it
                assert qdot[2] == pytest.approx(min(SPEED, (lower - q2) / DT), rel=1e-12)
            robot.integrate(qdot, DT)
            robot.update_kinematics()
    assert robot.q[2] >= lower - 1e-12  # back in its range (0.4 rad at 2 rad/s: 20 steps)


def test_a_model_without_dofs_is_refused_as_the_qp_refuses_it():
    """Nothing to solve for: the QP refuses such a model at construction with
    InvalidInput; SNS did the same work and failed with a bare ValueError (max() of an
    empty box) at its first step."""
    robot = Robot(mujoco.MjModel.from_xml_string(
        '<mujoco><worldbody><body name="b"><geom type="sphere" size="0.1"/><site name="s"/></body>'
        "</worldbody></mujoco>"))
    assert robot.nv == 0
    task = PositionTask(robot, "s")
    with pytest.raises(InvalidInput):
        QPController(robot, [task], [], dt=DT)
    with pytest.raises(InvalidInput, match="degree of freedom"):
        SNSController(robot, [task], [], dt=DT)
