"""The engine's joint position and velocity limits: the serial classes' boxes at N = 1,
each of N worlds its own one-world box, typed errors, and a QP rollout that keeps them
and answers as the serial controller does."""

from __future__ import annotations

import numpy as np
import pytest

import qpik
from qpik import batch
from qpik.controllers import QPController as EngineQP
from qpik.limits import JointPositionLimit, JointVelocityLimit
from qpik.tasks import DampingTask as EngineDamping
from qpik.tasks import PositionTask as EnginePosition
from qpik.errors import InvalidInput, ModelError, UnknownName
from qpik.limits import JointPositionLimit as SerialPositionLimit
from qpik.limits import JointVelocityLimit as SerialVelocityLimit

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
def test_position_box_equals_the_serial_limits(influence):
    """The arrays path of the serial limit and the engine's write the same box (the same
    operations in the same order: equal to the last bit)."""
    robot = arm()
    serial = SerialPositionLimit(robot, influence=influence, damper_rate=4.0, gain=0.9)
    engine = JointPositionLimit(robot, influence=influence, damper_rate=4.0, gain=0.9)
    for q in ARM_STATES:
        robot.set_q(q)
        lower, upper = speed_box(robot)
        lb, ub = lower[0].copy(), upper[0].copy()
        serial.apply(DT, lb, ub)
        engine.apply(DT, lower, upper)
        np.testing.assert_array_equal(lower[0], lb)
        np.testing.assert_array_equal(upper[0], ub)


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


def test_position_limit_names_a_non_finite_joint():
    robots = batch.Robot.load("arm", n=3)
    limit = JointPositionLimit(robots)
    robots.q[2, 1] = np.nan
    with pytest.raises(InvalidInput, match="theta2 has a non-finite position in world 2"):
        limit.apply(DT, *speed_box(robots, 3))


def test_velocity_box_equals_the_serial_limits_in_every_world():
    robot, robots = arm(), batch.Robot.load("arm", n=4)
    values = {"theta1": 1.5, "d4": 0.25}
    lb, ub = np.full(robot.nv, -np.inf), np.full(robot.nv, np.inf)
    SerialVelocityLimit(robot, values).apply(DT, lb, ub)
    lower, upper = np.full((4, robot.nv), -np.inf), np.full((4, robot.nv), np.inf)
    JointVelocityLimit(robots, values).apply(DT, lower, upper)
    np.testing.assert_array_equal(lower, np.tile(lb, (4, 1)))
    np.testing.assert_array_equal(upper, np.tile(ub, (4, 1)))
    assert JointVelocityLimit(robot).constant


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


def test_qp_rollout_keeps_the_joint_limits_and_answers_as_the_serial_controller(lockstep):
    """A target out of reach drives the joints into their bounds at full speed: the box
    binds (the solver's steps and the held bounds' closed form). On the serial rollout's
    states every engine answer equals the serial one to 1e-10 of its norm; the engine's
    own rollout keeps q in range and q̇ in the speed box."""
    target = [0.0, 2.5, 0.3]

    def build(engine: bool):
        robot = arm(ARM_STATES[0])
        Position, Damping, QP = (EnginePosition, EngineDamping, EngineQP) if engine else \
            (qpik.PositionTask, qpik.DampingTask, qpik.QPController)
        Limits = (JointPositionLimit, JointVelocityLimit) if engine else (SerialPositionLimit, SerialVelocityLimit)
        task = Position(robot, "end_effector", gain=20.0)
        task.set_target(target)
        return robot, QP(robot, [task, Damping(robot, 1e-4)], [Limits[0](robot, influence=0.2), Limits[1](robot)],
                         dt=DT)

    answers = lockstep(build(False), build(True), 300, DT)
    assert np.abs(answers).max() == pytest.approx(8.0)  # a joint did run at its speed bound
    robot, controller = build(True)
    for _ in range(300):
        qdot = controller.compute_velocity()
        assert np.all(np.abs(qdot) <= robot.velocity_limits * (1.0 + 1e-12))
        robot.integrate(qdot, DT)
        assert robot.joint_limits.violation(robot.q) <= 1e-9
    assert controller.solver_calls > 0
