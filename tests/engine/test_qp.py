"""The engine's QPController: one world against the serial QPController (an independent
implementation of the same QP), N worlds each against its own one-world run, and the
promises (typed errors, a failing world named while the others are solved)."""

from __future__ import annotations

import numpy as np
import pytest

import qpik.controllers as serial_controllers
import qpik.limits as serial_limits
import qpik.tasks as serial_tasks
from qpik.batch.robot import Robot as Robots
from qpik import limits as engine_limits
from qpik import tasks as engine_tasks
from qpik.controllers import QPController
from qpik.errors import InfeasibleProblem, InvalidInput, WorldsFailed
from qpik.robot import Robot

DT = 0.002
ARM_START = np.array([np.pi / 2, 0.0, 0.0, 0.5])
RANGES = {"theta2": (-1.0, 1.0), "theta3": (-1.0, 1.0)}  # the σ gradient pushes past them: limits bind


def arm_problem(robot, tasks, limits, controller, ranges=None, start=ARM_START):
    robot.set_q(start)
    robot.update_kinematics()
    position = tasks.PositionTask(robot, "end_effector", axes="xy", gain=500.0, hard=True)
    sigma = tasks.ManipulabilityTask(robot, tasks.SigmaProxy(robot, ["theta2", "theta3"]), gain=5.0)
    joint_limits = robot.joint_limits.tightened(ranges or {})
    bounds = [limits.JointPositionLimit(robot, joint_limits, influence=0.8, damper_rate=2.0),
              limits.JointVelocityLimit(robot)]
    return position, controller(robot, [position, sigma], bounds, solver="daqp", dt=DT)


def rollout(robot, position, qp, steps: int):
    """The source's path from each world's start: the segment (1, −1) m long in 5 s on a
    cubic time law (docs/arm.md); (steps, [N,] nq) configurations."""
    robot.ensure_kinematics()
    start = np.array(position.target)
    trajectory = []
    for k in range(steps):
        t = k * DT
        s, ds = (-2 * t**3 + 15 * t**2) / 125, (-6 * t**2 + 30 * t) / 125
        position.set_target(start + s * np.array([1.0, -1.0]), ds * np.array([1.0, -1.0]))
        robot.integrate(qp.compute_velocity(), DT)
        trajectory.append(np.array(robot.q))
    return np.array(trajectory)


@pytest.mark.parametrize("ranges", [None, RANGES], ids=["seed-redundant", "joint-limits"])
def test_one_world_follows_the_serial_controller(ranges):
    """The whole path (2,500 steps); with the ranges θ2 and θ3 reach their bounds after
    about 2 s, and the held bounds and the solver take over. Both solve the same strictly
    convex QP: the trajectories agree to rounding carried over the run (1e-11 rad; the
    configurations are O(1))."""
    runs, calls = [], []
    for tasks, limits, controller in ((engine_tasks, engine_limits, QPController),
                                      (serial_tasks, serial_limits, serial_controllers.QPController)):
        robot = Robot.load("arm")
        position, qp = arm_problem(robot, tasks, limits, controller, ranges)
        runs.append(rollout(robot, position, qp, 2500))
        calls.append(qp.solver_calls)
    assert np.abs(runs[0] - runs[1]).max() <= 1e-11
    # No limit binds on the seed path: every step is the closed form's (the solver is the
    # exception, not the rule); with the ranges, the held bounds settle most binding steps.
    if ranges is None:
        assert calls[0] == 0
    else:  # the bounds bind on most of the last 3 s: held bounds settle nearly all of those steps
        assert np.abs(runs[0][-1, 1:3]).max() > 0.999 and calls[0] <= calls[1], calls


def test_each_of_n_worlds_is_its_own_one_world_run():
    rng = np.random.default_rng(7)
    starts = ARM_START + rng.uniform(-0.3, 0.3, (4, 4)) * [1.0, 1.0, 1.0, 0.5]
    robots = Robots.load("arm", n=4)
    position, qp = arm_problem(robots, engine_tasks, engine_limits, QPController, RANGES, starts)
    together = rollout(robots, position, qp, 400)
    for w in range(4):
        robot = Robot.load("arm")
        one, single = arm_problem(robot, engine_tasks, engine_limits, QPController, RANGES, starts[w])
        alone = rollout(robot, one, single, 400)
        # The same operations on world w's numbers, vectorised or not: 1e-10 relative.
        assert np.abs(together[:, w] - alone).max() <= 1e-10 * np.abs(alone).max()


def pusher_problem(robot, tasks, limits, controller, hard: bool):
    robot.set_q(np.array([0.2, 0.3, 0.0, -1.2, 0.0, -0.6, 0.0]))
    robot.update_kinematics()
    pose = tasks.FrameTask(robot, "tips_arm", "body", position_gain=100.0, orientation_gain=100.0, hard=hard,
                           lm_damping=0.0 if hard else 1.0)
    posture = tasks.PostureTask(robot, gain=10.0, weight=1e-3)
    bounds = [limits.JointPositionLimit(robot), limits.JointVelocityLimit(robot, np.full(robot.nv, 3.0))]
    return pose, controller(robot, [pose, posture], bounds, solver="daqp", dt=DT)


@pytest.mark.parametrize("hard", [True, False], ids=["hard pose", "soft pose (dense H)"])
def test_the_pusher_pose_follows_the_serial_controller(pusher_model, hard):
    runs = []
    for tasks, limits, controller in ((engine_tasks, engine_limits, QPController),
                                      (serial_tasks, serial_limits, serial_controllers.QPController)):
        robot = Robot(pusher_model, name="pusher")
        pose, qp = pusher_problem(robot, tasks, limits, controller, hard)
        start, rotation = np.array(pose.target_position), np.array(pose.target_rotation)
        trajectory = []
        for k in range(300):
            offset = 0.1 * np.array([np.sin(4 * k * DT), 0.0, np.cos(4 * k * DT) - 1.0])
            pose.set_target(start + offset, rotation)
            robot.integrate(qp.compute_velocity(), DT)
            trajectory.append(robot.q.copy())
        runs.append(np.array(trajectory))
    assert np.abs(runs[0] - runs[1]).max() <= 1e-10  # the same QP, rounding carried over 300 steps


def test_a_far_target_gets_the_solvers_capped_cost():
    """A posture target 1e12 rad away: c ~ 1e13, capped before a solver sees it; the
    engine answers as the serial controller does (norm-wise, to the cap's 1e-9)."""
    answers = []
    for tasks, controller in ((engine_tasks, QPController), (serial_tasks, serial_controllers.QPController)):
        robot = Robot.load("arm")
        posture = tasks.PostureTask(robot, gain=100.0, weight=1.0)
        posture.set_target(robot.q + 1e12)
        qp = controller(robot, [posture, tasks.DampingTask(robot, weight=1e-3)], [], solver="daqp", dt=DT)
        answers.append(np.array(qp.compute_velocity()))
    assert np.linalg.norm(answers[0] - answers[1]) <= 1e-9 * np.linalg.norm(answers[1])
    assert np.abs(answers[0]).max() < 1e10


def _contradiction(robot, targets):
    """A hard position task asking for a point 1 m away in one 2 ms step under 8 rad/s bounds."""
    position = engine_tasks.PositionTask(robot, "end_effector", axes="xy", gain=500.0, hard=True)
    position.set_target(targets)
    return QPController(robot, [position, engine_tasks.DampingTask(robot)], [engine_limits.JointVelocityLimit(robot)],
                        dt=DT)


def test_an_infeasible_step_is_typed_and_names_the_task():
    robot = Robot.load("arm")
    qp = _contradiction(robot, robot.frame("end_effector").position[:2] + 1.0)
    with pytest.raises(InfeasibleProblem, match="position task"):
        qp.compute_velocity()


def test_a_failing_world_is_named_and_the_others_solved():
    robots = Robots.load("arm", n=3)
    robots.ensure_kinematics()
    here = robots.frame("end_effector").positions[:, :2].copy()
    targets = here + np.array([[0.001, 0.0], [1.0, 1.0], [0.0, -0.001]])  # world 1 cannot get there
    qp = _contradiction(robots, targets)
    with pytest.raises(WorldsFailed) as failed:
        qp.compute_velocity()
    assert failed.value.worlds.tolist() == [1] and "InfeasibleProblem" in failed.value.reasons[1]
    assert np.all(failed.value.qdot[1] == 0.0)
    for w in (0, 2):
        robot = Robot.load("arm")
        alone = _contradiction(robot, targets[w]).compute_velocity()
        assert np.abs(failed.value.qdot[w] - alone).max() <= 1e-12 * np.abs(alone).max()


def test_bad_set_ups_are_refused():
    robot = Robot.load("arm")
    task = engine_tasks.DampingTask(robot)
    with pytest.raises(InvalidInput, match="dt"):
        QPController(robot, [task], [])
    with pytest.raises(InvalidInput, match="at least one task"):
        QPController(robot, [], [], dt=DT)
    with pytest.raises(InvalidInput, match="weight"):
        engine_tasks.DampingTask(robot, weight=1e308)
