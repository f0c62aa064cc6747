"""The engine's QPController: one world's answers, step after step of a rollout, each the
minimiser of its QP solved independently (the QP written out from the tasks' rows and the
limits' box and rows, DAQP called directly, the active set solved exactly:
tests/engine/references.py), N worlds each against its own one-world run (a user's own
limit among them), and the promises (a far target's capped cost, typed errors, a failing
world named while the others are solved)."""

from __future__ import annotations

import importlib.util
from pathlib import Path

import numpy as np
import pytest

from qpik import limits as engine_limits
from qpik import tasks as engine_tasks
from qpik.batch.robot import Robot as Robots
from qpik.controllers import QPController
from qpik.errors import InfeasibleProblem, InvalidInput, WorldsFailed
from qpik.robot import Robot

_spec = importlib.util.spec_from_file_location("references", Path(__file__).with_name("references.py"))
references = importlib.util.module_from_spec(_spec)
_spec.loader.exec_module(references)

DT = 0.002
ARM_START = np.array([np.pi / 2, 0.0, 0.0, 0.5])
RANGES = {"theta2": (-1.0, 1.0), "theta3": (-1.0, 1.0)}  # the σ gradient pushes past them: limits bind


def arm_problem(robot, ranges=None, start=ARM_START, extra_limits=(), solver="daqp"):
    robot.set_q(start)
    robot.update_kinematics()
    position = engine_tasks.PositionTask(robot, "end_effector", axes="xy", gain=500.0, hard=True)
    sigma = engine_tasks.ManipulabilityTask(robot, engine_tasks.SigmaProxy(robot, ["theta2", "theta3"]), gain=5.0)
    joint_limits = robot.joint_limits.tightened(ranges or {})
    bounds = [engine_limits.JointPositionLimit(robot, joint_limits, influence=0.8, damper_rate=2.0),
              engine_limits.JointVelocityLimit(robot), *extra_limits]
    return position, QPController(robot, [position, sigma], bounds, solver=solver, dt=DT)


def follow_the_path(position):
    """``before(k)``: the source's path from the start, the segment (1, −1) m long in 5 s on
    a cubic time law (docs/arm.md)."""
    start = np.array(position.target)

    def before(k: int) -> None:
        t = k * DT
        s, ds = (-2 * t**3 + 15 * t**2) / 125, (-6 * t**2 + 30 * t) / 125
        position.set_target(start + s * np.array([1.0, -1.0]), ds * np.array([1.0, -1.0]))

    return before


def rollout(robot, position, qp, steps: int, answers: list | None = None):
    """The path from each world's start; (steps, [N,] nq) configurations (the answers
    appended to ``answers``)."""
    robot.ensure_kinematics()
    before = follow_the_path(position)
    trajectory = []
    for k in range(steps):
        before(k)
        qdot = qp.compute_velocity()
        if answers is not None:
            answers.append(np.array(qdot))
        robot.integrate(qdot, DT)
        trajectory.append(np.array(robot.q))
    return np.array(trajectory)


@pytest.mark.parametrize("ranges", [None, RANGES], ids=["seed-redundant", "joint-limits"])
def test_each_step_of_the_path_is_its_qps_minimiser(ranges, lockstep):
    """The whole path (2,500 steps): the answers equal the minimisers of their QPs solved
    independently (1e-9 of their norm). With the ranges θ2 and θ3 reach their bounds after
    about 2 s, and the held bounds' closed form and the solver take over."""
    robot = Robot.load("arm")
    position, qp = arm_problem(robot, ranges)
    binding = []

    def after(k, qdot):  # a bound of the step's box active at its answer
        binding.append(bool(np.any(np.isclose(qdot, qp.lb, rtol=1e-12, atol=0) |
                                   np.isclose(qdot, qp.ub, rtol=1e-12, atol=0))))

    # Without ranges every step is the same closed form on a smooth path: every 5th checked.
    lockstep(robot, qp, 2500, DT, follow_the_path(position), after, every=5 if ranges is None else 1)
    # No limit binds on the seed path: every step is the closed form's (the solver is the
    # exception, not the rule); with the ranges, the held bounds' closed form settles the
    # binding steps (one solver step in 2,500, measured).
    if ranges is None:
        assert qp.solver_calls == 0 and not any(binding)
    else:
        assert np.abs(robot.q[1:3]).max() > 0.999 and sum(binding) > 1000
        assert qp.solver_calls <= 5, qp.solver_calls


def pusher_problem(robot, hard: bool):
    robot.set_q(np.array([0.2, 0.3, 0.0, -1.2, 0.0, -0.6, 0.0]))
    robot.update_kinematics()
    pose = engine_tasks.FrameTask(robot, "tips_arm", "body", position_gain=100.0, orientation_gain=100.0, hard=hard,
                                  lm_damping=0.0 if hard else 1.0)
    posture = engine_tasks.PostureTask(robot, gain=10.0, weight=1e-3)
    bounds = [engine_limits.JointPositionLimit(robot), engine_limits.JointVelocityLimit(robot, np.full(robot.nv, 3.0))]
    return pose, QPController(robot, [pose, posture], bounds, solver="daqp", dt=DT)


@pytest.mark.parametrize("hard", [True, False], ids=["hard pose", "soft pose (dense H)"])
def test_the_pusher_pose_steps_are_their_qps_minimisers(pusher_model, hard, lockstep):
    """A circle of the tip (300 steps), the pose hard (equality rows) or soft and LM-damped
    (a dense Hessian): every answer is the minimiser of its QP solved independently."""
    robot = Robot(pusher_model, name="pusher")
    pose, qp = pusher_problem(robot, hard)
    start, rotation = np.array(pose.target_position), np.array(pose.target_rotation)

    def circle(k: int) -> None:
        pose.set_target(start + 0.1 * np.array([np.sin(4 * k * DT), 0.0, np.cos(4 * k * DT) - 1.0]), rotation)

    answers = lockstep(robot, qp, 300, DT, circle)
    assert np.abs(answers).max() > 0.1  # the arm did move


def test_a_far_target_gets_the_solvers_capped_cost():
    """A posture target 1e12 rad away: v = K e = 1e14, c = −w v, capped before a solver sees
    it at 1e9 times H's scale (its largest diagonal entry; docs/controllers.md): the answer
    is −H⁻¹ c_capped, with H = diag(w + w_damping + ε), written out (norm-wise, to the
    cap's 1e-9)."""
    robot = Robot.load("arm")
    posture = engine_tasks.PostureTask(robot, gain=100.0, weight=1.0)
    posture.set_target(robot.q + 1e12)
    qp = QPController(robot, [posture, engine_tasks.DampingTask(robot, weight=1e-3)], [], solver="daqp", dt=DT)
    answer = np.array(qp.compute_velocity())
    diagonal = np.full(robot.nv, 1.0 + 1e-3 + 1e-12)
    c = -1.0 * 100.0 * np.array(posture.error)
    capped = c * (1e9 * max(1.0, diagonal.max()) / np.abs(c).max())
    expected = -capped / diagonal
    assert np.linalg.norm(answer - expected) <= 1e-9 * np.linalg.norm(expected)
    assert np.abs(answer).max() < 1e10


class SlowSum(engine_limits.Limit):
    """A user's limit: one general row, ``sign`` times the joint velocities' sum at most
    ``total``, in every world (the same row everywhere)."""

    inequality_rows = 1

    def __init__(self, total: float, sign: float = 1.0):
        self.total, self.sign = total, sign

    def apply(self, dt, lower, upper, G=None, h=None):
        G[:, 0], h[:, 0] = self.sign, self.total


def test_a_users_limit_binds_and_each_world_is_its_own_run():
    """The path with a user's general row (Σ q̇ <= 0.5) beside the ranges: on 4 worlds of
    different starts each world's path equals its own one-world run (1e-10 relative) over
    300 steps, in which the row binds in some worlds."""
    rng = np.random.default_rng(8)
    starts = ARM_START + rng.uniform(-0.3, 0.3, (4, 4)) * [1.0, 1.0, 1.0, 0.5]
    robots = Robots.load("arm", n=4)
    position, qp = arm_problem(robots, RANGES, starts, [SlowSum(0.5)])
    answers = []
    together = rollout(robots, position, qp, 300, answers)
    for w in range(4):
        robot = Robot.load("arm")
        one, single = arm_problem(robot, RANGES, starts[w], [SlowSum(0.5)])
        alone = rollout(robot, one, single, 300)
        assert np.abs(together[:, w] - alone).max() <= 1e-10 * np.abs(alone).max()
    bound = np.isclose(np.array(answers).sum(axis=2), 0.5, rtol=1e-9).any(axis=0)
    assert 0 < bound.sum() < 4, bound  # the row did bind, in some worlds


@pytest.mark.parametrize("solver", ["osqp", "proxqp"])
def test_an_iterative_solver_in_each_world_is_its_own_run(solver):
    """An iterative solver stops where its residuals pass its tolerance (1e-8), so where it
    ends depends on where it starts: each world warm-starts from its own last answer, as
    its one-world run does, and over 200 steps of the path with the ranges binding each
    world's q̇ equals its own run's to 1e-10 relative (the data agree to rounding)."""
    pytest.importorskip({"osqp": "osqp", "proxqp": "proxsuite"}[solver])
    starts = ARM_START + np.random.default_rng(3).uniform(-0.3, 0.3, (4, 4)) * [1.0, 1.0, 1.0, 0.5]
    position, qp = arm_problem(Robots.load("arm", n=4), RANGES, starts, solver=solver)
    together = []
    rollout(qp.robot, position, qp, 200, together)
    assert qp.solver_calls > 0
    for w in range(4):
        one, single = arm_problem(Robot.load("arm"), RANGES, starts[w], solver=solver)
        alone = []
        rollout(single.robot, one, single, 200, alone)
        gap = np.linalg.norm(np.array(together)[:, w] - alone, axis=1)
        assert np.all(gap <= 1e-10 * (1.0 + np.linalg.norm(alone, axis=1))), gap.max()


def test_a_users_limit_in_one_world_gives_its_qps_minimisers(lockstep):
    """One world's path with the row −Σ q̇ <= 0.15: every answer is the minimiser of its QP
    (the row in G, h as the limit wrote it into fresh arrays), and the row binds."""
    robot = Robot.load("arm")
    position, qp = arm_problem(robot, RANGES, ARM_START, [SlowSum(0.15, -1.0)])
    answers = lockstep(robot, qp, 300, DT, follow_the_path(position))
    assert np.isclose(answers.sum(axis=1), -0.15, rtol=1e-9).sum() > 10  # the row bound


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
