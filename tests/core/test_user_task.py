"""A task written as a mink user writes one (``dim``, ``compute_error``,
``compute_jacobian``) runs in every controller and in a rollout; the base class owns its
gain, weight, priority, hardness and the K·Δt check."""

from __future__ import annotations

import mujoco
import numpy as np
import pytest

from qpik import (
    DampingTask,
    HierarchicalController,
    InvalidInput,
    JacobianTransposeController,
    PositionReference,
    PseudoinverseController,
    QPController,
    Robot,
    SNSController,
    Task,
    batch,
    simulate,
)
from qpik.errors import GainWarning
from qpik.trajectories import Hold

DT = 0.002


class TipDistance(Task):
    """1-D: the distance of the arm's end effector from a fixed point ``centre``."""

    dim = 1

    def __init__(self, robot, centre, site="end_effector", **options):
        super().__init__(robot, **options)
        self.centre = np.asarray(centre, dtype=float)
        self.site = robot.model.site(site).id
        self.target = np.array([self.distance(robot)])

    def distance(self, robot) -> float:
        return float(np.linalg.norm(robot.data.site_xpos[self.site] - self.centre))

    def compute_error(self, robot):
        return self.target - self.distance(robot)

    def compute_jacobian(self, robot):
        offset = robot.data.site_xpos[self.site] - self.centre
        jacp = np.zeros((3, robot.nv))
        mujoco.mj_jacSite(robot.model, robot.data, jacp, None, self.site)
        return (offset / np.linalg.norm(offset)) @ jacp[None]


@pytest.fixture
def arm():
    robot = Robot.load("arm")
    robot.set_q([0.3, 0.6, -0.4, 0.2])
    robot.update_kinematics()
    return robot


def test_the_user_jacobian_is_the_derivative_of_what_the_error_measures(arm, finite_difference_jacobian):
    task = TipDistance(arm, centre=[0.1, -0.2, 0.0], gain=10.0)
    # x = x_d − e, so ∂x/∂q = −∂e/∂q; central differences with eps 1e-6 on a smooth
    # distance (curvature ~1/|offset| ~ 3 1/m): truncation ~1e-12, rounding ~1e-10.
    fd = finite_difference_jacobian(arm, lambda robot: -task.compute_error(robot))
    np.testing.assert_allclose(task.compute_jacobian(arm), fd, atol=1e-8)


def make_task(robot, **options):
    task = TipDistance(robot, centre=[0.1, -0.2, 0.0], **options)
    task.set_target([task.target[0] + 0.15])  # 15 cm farther out: every controller must move
    return task


CONTROLLERS = {
    "qp": lambda robot, task: QPController(robot, [task, DampingTask(robot, weight=1e-4)], dt=DT),
    "qp-hard": lambda robot, task: QPController(robot, [task, DampingTask(robot, weight=1e-4)], dt=DT),
    "hqp": lambda robot, task: HierarchicalController(robot, [task], dt=DT),
    "pinv": lambda robot, task: PseudoinverseController(robot, [task]),
    "jt": lambda robot, task: JacobianTransposeController(robot, [task], alpha=5.0),
    "sns": lambda robot, task: SNSController(robot, [task], dt=DT),
}


@pytest.mark.parametrize("kind", sorted(CONTROLLERS))
def test_a_user_task_converges_in_every_controller(arm, kind):
    task = make_task(arm, gain=50.0, hard=kind == "qp-hard")
    controller = CONTROLLERS[kind](arm, task)
    start = abs(float(task.compute_error(arm)[0]))
    for _ in range(1500):  # 3 s: e decays as exp(−K t) = exp(−150) for the exact laws
        arm.integrate(controller.compute_velocity(), DT)
    arm.update_kinematics()
    final = abs(float(task.compute_error(arm)[0]))
    assert start > 0.1
    # The Jacobian-transpose law only descends the gradient (a lag); the others track.
    assert final < (1e-3 if kind == "jt" else 1e-6), final
    np.testing.assert_allclose(task.measured(), task.target, atol=1e-3 if kind == "jt" else 1e-6)


def test_a_user_task_in_a_rollout_with_a_reference(arm):
    task = make_task(arm, gain=50.0)
    goal = task.target.copy()
    controller = QPController(arm, [task, DampingTask(arm, weight=1e-4)], dt=DT)
    log = simulate(controller, PositionReference(task, Hold(goal, 2.0)), 2.0, dt=DT)
    assert log.summary().final_error < 1e-6
    np.testing.assert_allclose(task.measured(), goal, atol=1e-6)


class TargetedTipDistance(TipDistance):
    """TipDistance given its target (one, or one per world): built on N worlds as on one."""

    def __init__(self, robot, centre, target, site="end_effector", **options):
        Task.__init__(self, robot, **options)
        self.centre = np.asarray(centre, dtype=float)
        self.site = robot.model.site(site).id
        self.set_target(target)


def test_what_a_user_task_measures_in_every_world_is_its_own_one_world_measure():
    """N = 4 worlds in different states, one target each: ``measured()`` (x = x_d − e,
    the user's methods evaluated world by world) equals each world's own one-robot task."""
    rng = np.random.default_rng(4)
    robots = batch.Robot.load("arm", n=4)
    robots.set_q(robots.q + rng.uniform(-0.4, 0.4, robots.q.shape))
    targets = rng.uniform(0.2, 0.5, (4, 1))
    task = TargetedTipDistance(robots, [0.1, -0.2, 0.0], targets, gain=1.0)
    measured = task.measured()
    assert measured.shape == (4, 1)
    for w in range(4):
        one = Robot.load("arm")
        one.set_q(robots.q[w])
        one.update_kinematics()
        alone = TargetedTipDistance(one, [0.1, -0.2, 0.0], targets[w], gain=1.0)
        np.testing.assert_allclose(measured[w], alone.measured(), rtol=1e-10, atol=0)
        np.testing.assert_allclose(measured[w], [alone.distance(one)], rtol=1e-10, atol=0)


def test_the_base_class_owns_gain_weight_priority_and_damping(arm):
    task = TipDistance(arm, centre=[0, 0, 0], gain=[7.0], weight=3.0, hard=True, priority=2, lm_damping=0.5)
    assert task.dim == 1 and task.hard and task.priority == 2 and task.lm_damping == 0.5
    np.testing.assert_array_equal(task.feedback_gains(), [7.0])
    np.testing.assert_array_equal(task.weight, [3.0])
    task.set_target([1.0], velocity=[0.25])
    task.update()
    # v = ẋ_d + K e, the feed-forward optional.
    np.testing.assert_allclose(task.target_velocity, 0.25 + 7.0 * task.error)
    np.testing.assert_allclose(task.error, 1.0 - task.distance(arm))


def test_the_default_gain_is_dead_beat_and_needs_a_period(arm):
    task = make_task(arm)
    assert task.needs_period
    with pytest.raises(InvalidInput, match="give the task a gain"):
        PseudoinverseController(arm, [task])
    QPController(arm, [task], dt=DT)
    np.testing.assert_allclose(task.feedback_gains(), [1.0 / DT])
    assert not task.needs_period


@pytest.mark.parametrize("build", [
    lambda robot, task: QPController(robot, [task], dt=DT),
    lambda robot, task: HierarchicalController(robot, [task], dt=DT),
    lambda robot, task: SNSController(robot, [task], dt=DT),
], ids=["qp", "hqp", "sns"])
def test_a_gain_that_diverges_is_refused_as_for_builtin_tasks(arm, build):
    with pytest.raises(InvalidInput, match="K·dt"):
        build(arm, make_task(arm, gain=2.5 / DT))  # K·Δt = 2.5 > 2
    with pytest.warns(GainWarning):
        build(arm, make_task(arm, gain=1.5 / DT))  # 1 < K·Δt <= 2: overshoots


def test_a_user_task_that_lies_about_its_shape_is_told(arm):
    class WrongRows(TipDistance):
        def compute_jacobian(self, robot):
            return np.zeros((2, robot.nv))

    class NaNError(TipDistance):
        def compute_error(self, robot):
            return np.array([np.nan])

    for cls, message in ((WrongRows, r"compute_jacobian must return shape \(1, 4\)"),
                         (NaNError, "compute_error returned NaN")):
        controller = QPController(arm, [cls(arm, centre=[0, 0, 0], gain=1.0)], dt=DT)
        with pytest.raises(InvalidInput, match=message):
            controller.compute_velocity()


def test_a_subclass_without_the_contract_is_refused_when_built(arm):
    class NoJacobian(Task):
        dim = 1

        def compute_error(self, robot):
            return np.zeros(1)

    class NoDim(Task):
        def compute_error(self, robot):
            return np.zeros(1)

        def compute_jacobian(self, robot):
            return np.zeros((1, robot.nv))

    with pytest.raises(InvalidInput, match=r"NoJacobian must define compute_jacobian\(robot\)"):
        NoJacobian(arm)
    with pytest.raises(InvalidInput, match="NoDim needs its row count dim"):
        NoDim(arm)


def test_builtin_tasks_answer_the_same_two_methods(arm, finite_difference_jacobian):
    from qpik import PositionTask

    task = PositionTask(arm, "end_effector", axes="xy", gain=10.0)
    np.testing.assert_allclose(task.compute_error(arm), task.target - arm.data.site_xpos[task.frame.id][:2])
    fd = finite_difference_jacobian(arm, lambda robot: robot.data.site_xpos[task.frame.id][:2].copy())
    np.testing.assert_allclose(task.compute_jacobian(arm), fd, atol=1e-8)
