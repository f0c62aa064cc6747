"""The engine's joint position and velocity limits: their boxes at N = 1 against the rules
written out joint by joint, each of N worlds its own one-world box, typed errors, and a
QP rollout that keeps them, each step the minimiser of its QP solved independently."""

from __future__ import annotations

import importlib.util
from pathlib import Path

import numpy as np
import pytest

import qpik
from qpik import batch
from qpik.controllers import QPController
from qpik.errors import InvalidInput, ModelError, UnknownName
from qpik.limits import JointPositionLimit, JointVelocityLimit
from qpik.tasks import DampingTask, PositionTask

_spec = importlib.util.spec_from_file_location("references", Path(__file__).with_name("references.py"))
references = importlib.util.module_from_spec(_spec)
_spec.loader.exec_module(references)

DT = 0.002
# Configurations of the bundled arm: inside, near the bounds (within the damper's
# influence), and outside the range (a limit brings such a joint back).
ARM_STATES = np.array([[0.1, -0.4, 0.7, 0.05], [2.79, -2.6, 1.2, 0.01], [-3.2, 3.5, -0.2, 0.31], [0.0, 0.0, 0.0, -0.02]])


def arm(q=None) -> qpik.Robot:
    robot = qpik.Robot.load("arm", allow_outside_limits=True)
    if q is not None:
        robot.set_q(q)
    return robot


def speed_box(robot, n: int = 1) -> tuple[np.ndarray, np.ndarray]:
    vmax = robot.velocity_limits
    return np.tile(-vmax, (n, 1)), np.tile(vmax, (n, 1))


@pytest.mark.parametrize("influence", [0.0, 0.3])
def test_position_box_follows_the_rule_joint_by_joint(influence):
    """Inside, near the bounds (within the damper's influence) and outside the range: the
    box is the rule's (references.position_limit_box), the same scalar operations in the
    same order, so equal to the last bit."""
    robot = arm()
    limit = JointPositionLimit(robot, influence=influence, damper_rate=4.0, gain=0.9)
    tightened = 0
    for q in ARM_STATES:
        robot.set_q(q)
        lower, upper = speed_box(robot)
        expected = references.position_limit_box(limit, q, DT, lower[0], upper[0])
        tightened += int(np.sum(expected[0] != lower[0]) + np.sum(expected[1] != upper[0]))
        limit.apply(DT, lower, upper)
        np.testing.assert_array_equal(lower[0], expected[0])
        np.testing.assert_array_equal(upper[0], expected[1])
    assert tightened >= 4  # the states near and outside the ranges: the rule did bind


def test_position_box_of_each_world_is_its_own():
    robots = batch.Robot.load("arm", n=len(ARM_STATES), allow_outside_limits=True)
    robots.set_q(ARM_STATES)
    lower, upper = speed_box(robots, robots.n)
    JointPositionLimit(robots, influence=0.3, damper_rate=4.0).apply(DT, lower, upper)
    for w, q in enumerate(ARM_STATES):
        one = arm(q)
        alone = speed_box(one)
        JointPositionLimit(one, influence=0.3, damper_rate=4.0).apply(DT, *alone)
        np.testing.assert_array_equal(lower[w], alone[0][0])
        np.testing.assert_array_equal(upper[w], alone[1][0])


@pytest.mark.parametrize("parameters, match", [
    ({"influence": 1e308}, "influence"), ({"damper_rate": 1e308}, "damper rate"), ({"damper_rate": 0.0}, "damper"),
    ({"gain": 0.0}, "gain"), ({"gain": 1.5}, "gain"), ({"gain": float("nan")}, "gain"), ({"margin": -1e-9}, "margin"),
    ({"margin": 10.0}, "narrower"), ({"influence": "far"}, "influence")])
def test_position_limit_refuses_bad_parameters(parameters, match):
    with pytest.raises(InvalidInput, match=match):
        JointPositionLimit(arm(), **parameters)


def test_a_non_finite_joint_is_named_before_a_limit_reads_it():
    """The step's kinematics update refuses it, naming the world and the joint."""
    robots = batch.Robot.load("arm", n=3)
    controller = QPController(robots, [DampingTask(robots)], [JointPositionLimit(robots)], dt=DT)
    controller.compute_velocity()  # (the first step also checks the start against the ranges)
    robots.q[2, 1] = np.nan
    with pytest.raises(InvalidInput, match=r"not finite .* in worlds 2 \(world 2: joint theta2 at nan\)"):
        controller.compute_velocity()


def test_velocity_box_is_the_bounds_given_in_every_world():
    """{θ1: 1.5, d4: 0.25}: |q̇_0| <= 1.5, |q̇_3| <= 0.25, the other dofs left free, in one
    robot and in each of 4 worlds (its own one-world box); without values, the bounds the
    bundled arm declares (qpik_velocity_limit_*)."""
    values = {"theta1": 1.5, "d4": 0.25}
    expected = np.array([1.5, np.inf, np.inf, 0.25])
    for robot in (arm(), batch.Robot.load("arm", n=4)):
        lower, upper = np.full((robot.n, robot.nv), -np.inf), np.full((robot.n, robot.nv), np.inf)
        limit = JointVelocityLimit(robot, values)
        assert limit.constant and not limit.inequality_rows
        limit.apply(DT, lower, upper)
        np.testing.assert_array_equal(lower, np.tile(-expected, (robot.n, 1)))
        np.testing.assert_array_equal(upper, np.tile(expected, (robot.n, 1)))
    robot = arm()
    declared = np.array([float(robot.model.numeric(f"qpik_velocity_limit_{robot.model.joint(j).name}").data[0])
                         for j in range(robot.model.njnt)])
    lower, upper = speed_box(robot)
    lower[:], upper[:] = -np.inf, np.inf
    JointVelocityLimit(robot).apply(DT, lower, upper)
    np.testing.assert_array_equal(upper[0], declared)
    np.testing.assert_array_equal(lower[0], -declared)


@pytest.mark.parametrize("values, error, match", [
    ({"theta1": 1e308}, InvalidInput, "at most 1e"), ({"theta1": 0.0}, InvalidInput, "positive"),
    ({"theta1": float("nan")}, InvalidInput, "positive"), (np.ones(3), InvalidInput, "shape"),
    ({"theta1": [1.0, 2.0]}, InvalidInput, "one number"), ({"theta9": 1.0}, UnknownName, "theta9"),
    ({"theta1": "fast"}, InvalidInput, "numbers")])
def test_velocity_limit_refuses_bad_values(values, error, match):
    with pytest.raises(error, match=match):
        JointVelocityLimit(arm(), values)


def test_velocity_limit_needs_bounds_somewhere(chain_model):
    with pytest.raises(ModelError, match="no joint speed limit"):
        JointVelocityLimit(qpik.Robot(chain_model(3)))


def test_qp_rollout_keeps_the_joint_limits_and_each_step_is_its_qps_minimiser(lockstep):
    """A target out of reach drives the joints into their bounds at full speed: the box
    binds (the solver's steps and the held bounds' closed form). Every answer equals the
    minimiser of its QP solved independently (1e-9 of its norm), q stays in range and q̇
    in the speed box."""
    robot = arm(ARM_STATES[0])
    task = PositionTask(robot, "end_effector", gain=20.0)
    task.set_target([0.0, 2.5, 0.3])
    controller = QPController(robot, [task, DampingTask(robot, 1e-4)],
                              [JointPositionLimit(robot, influence=0.2), JointVelocityLimit(robot)], dt=DT)

    def after(k, qdot):
        assert np.all(np.abs(qdot) <= robot.velocity_limits * (1.0 + 1e-12))
        assert robot.joint_limits.violation(robot.q) <= 1e-9

    answers = lockstep(robot, controller, 300, DT, after=after)
    assert np.abs(answers).max() == pytest.approx(8.0)  # a joint did run at its speed bound
    assert controller.solver_calls > 0
