"""Three priority levels on a third-party 7-DoF arm, gymnasium's pusher (loaded from the
installed package, never copied): the fingertip's pose, then the elbow's position, then a
posture. The pusher has no sites and the tasks attach to sites, so the test adds two with
MuJoCo's MjSpec (and removes the puck and the goal, which are not part of the arm).

Checked every step: the pose is met and kept (level 0); the elbow gets the best the pose
and the joint limits leave (an independent QP with another solver); wherever no bound is
active the hierarchy equals SNS, i.e. the prioritised pseudoinverse law.
"""

import importlib.util
from pathlib import Path

import mujoco
import numpy as np
import pytest
import qpsolvers

from qpik.controllers.hierarchy import HierarchicalController
from qpik.controllers.sns import SNSController
from qpik.limits import JointPositionLimit, JointVelocityLimit
from qpik.robot import Robot
from qpik.rollout import simulate
from qpik.rollout.levels import Level, LevelErrors
from qpik.tasks import FrameTask, PositionTask, PostureTask
from qpik.trajectories import Segment

GYMNASIUM = importlib.util.find_spec("gymnasium")
pytestmark = pytest.mark.skipif(GYMNASIUM is None, reason="gymnasium is not installed (its pusher is the 7-DoF model)")

ARM_JOINTS = ("r_shoulder_pan_joint", "r_shoulder_lift_joint", "r_upper_arm_roll_joint", "r_elbow_flex_joint",
              "r_forearm_roll_joint", "r_wrist_flex_joint", "r_wrist_roll_joint")
START = np.array([0.2, 0.3, 0.0, -1.2, 0.0, -0.6, 0.0])
GAIN = 50.0
DT = 0.002
DURATION = 2.0
SPEED = 0.5  # rad/s on every joint (the model declares none): the elbow's demand saturates it


def _pusher() -> Robot:
    path = Path(GYMNASIUM.origin).parent / "envs" / "mujoco" / "assets" / "pusher.xml"
    spec = mujoco.MjSpec.from_file(str(path))
    for body in ("object", "goal"):
        spec.delete(spec.body(body))
    spec.body("tips_arm").add_site(name="tip", pos=[0.1, 0.0, 0.0])  # between the two fingertips
    spec.body("r_elbow_flex_link").add_site(name="elbow")
    robot = Robot(spec.compile(), name="pusher")
    assert robot.joint_names == ARM_JOINTS and robot.nv == 7
    robot.set_q(START)
    robot.update_kinematics()
    return robot


class _PoseReference:
    """The fingertip along a 12 cm segment, its orientation held; the elbow asked 15 cm up."""

    def __init__(self, pose: FrameTask, elbow: PositionTask):
        self.pose, self.rotation = pose, pose.target_rotation.copy()
        start = pose.target_position.copy()
        self.segment = Segment(start, start + [0.06, -0.08, 0.05], DURATION, time_law="quintic")
        elbow.set_target(elbow.target + [0.0, 0.0, 0.15])

    def apply(self, t):
        p, v = self.segment.sample(t)
        self.pose.set_target(p, self.rotation, linear_velocity=v)

    def desired(self):
        return self.pose.target_position

    def measure(self, robot):
        return {"x": robot.frame_position(self.pose.frame).copy()}


def _problem():
    robot = _pusher()
    pose = FrameTask(robot, "tip", position_gain=GAIN, orientation_gain=GAIN)
    elbow = PositionTask(robot, "elbow", axes="xyz", gain=GAIN)
    posture = PostureTask(robot, gain=2.0)
    limits = [JointPositionLimit(robot), JointVelocityLimit(robot, np.full(7, SPEED))]
    levels = LevelErrors([Level("pose", (pose,), "m, rad"), Level("elbow", (elbow,), "m"),
                          Level("posture", (posture,), "rad")])
    return robot, [[pose], [elbow], [posture]], limits, _PoseReference(pose, elbow), levels


class _Checked:
    """The hierarchy, checked each step against quadprog (level 0 alone, then level 1 with
    level 0's optimum kept) and against SNS on the same state."""

    def __init__(self, robot, levels, limits):
        self.inner = HierarchicalController(robot, levels=levels, limits=limits, solver="daqp", dt=DT)
        self.sns = SNSController(robot, levels=levels, limits=limits, dt=DT)
        self.kind, self.solver, self.robot = "hqp", "daqp", robot
        (self.pose,), (self.elbow,), _ = levels
        self.gaps, self.optima, self.agreements, self.free_steps = [], [], [], 0

    def compute_velocity(self):
        qdot = self.inner.compute_velocity()
        J0, v0, J1, v1 = self.pose.jacobian, self.pose.target_velocity, self.elbow.jacobian, self.elbow.target_velocity
        lb, ub = self.inner.lb, self.inner.ub
        eye = 1e-9 * np.eye(7)
        best_pose = qpsolvers.solve_qp(J0.T @ J0 + eye, -J0.T @ v0, lb=lb, ub=ub, solver="quadprog")
        best = qpsolvers.solve_qp(J1.T @ J1 + eye, -J1.T @ v1, A=J0, b=J0 @ best_pose, lb=lb, ub=ub, solver="quadprog")
        np.testing.assert_allclose(J0 @ qdot, J0 @ best_pose, atol=1e-7)
        self.optima.append(float(np.linalg.norm(J1 @ best - v1)))
        self.gaps.append(float(np.linalg.norm(J1 @ qdot - v1)) - self.optima[-1])
        sns = self.sns.compute_velocity()
        if not self.sns.saturated.any() and np.all(qdot < ub - 1e-9) and np.all(qdot > lb + 1e-9):
            self.free_steps += 1
            self.agreements.append(float(np.max(np.abs(sns - qdot))))
        return qdot


@pytest.fixture(scope="module")
def checked_rollout():
    robot, levels, limits, reference, level_errors = _problem()
    checked = _Checked(robot, levels, limits)
    log = simulate(checked, reference, DURATION + 0.5, dt=DT, levels=level_errors, robot_name="pusher")
    return checked, log


def test_pose_level_is_met_and_limits_kept(checked_rollout):
    _, log = checked_rollout
    summary = log.summary()
    assert summary.completed and summary.limit_violation_max == 0.0
    assert np.all(np.abs(log.qdot) <= SPEED + 1e-12)
    assert np.sum(np.any(np.abs(log.qdot) >= SPEED - 1e-9, axis=1)) > 300  # the box is active
    assert summary.levels.error_max[0] <= 1e-4  # pose error (m and rad) along the path
    assert summary.levels.error_final[0] <= 1e-6
    assert summary.levels.error_max[1] > 0.05  # the elbow cannot rise 15 cm with the pose held


def test_elbow_level_is_the_best_the_pose_and_limits_allow(checked_rollout):
    checked, _ = checked_rollout
    optima, gaps = np.array(checked.optima), np.array(checked.gaps)
    assert np.min(optima) > 1.0  # the elbow's target is never reachable: a real second level
    assert np.max(np.abs(gaps)) <= 1e-6 * np.max(optima)


def test_without_active_bounds_the_hierarchy_is_sns(checked_rollout):
    checked, log = checked_rollout
    assert checked.free_steps >= 300
    assert max(checked.agreements) <= 1e-7


def test_sns_rollout_keeps_the_limits_and_the_pose():
    robot, levels, limits, reference, level_errors = _problem()
    log = simulate(SNSController(robot, levels=levels, limits=limits, dt=DT), reference, DURATION + 0.5, dt=DT,
                   levels=level_errors)
    summary = log.summary()
    assert summary.limit_violation_max == 0.0 and np.all(np.abs(log.qdot) <= SPEED + 1e-12)
    assert summary.levels.error_max[0] <= 1e-4 and summary.task_scale_min == 1.0
