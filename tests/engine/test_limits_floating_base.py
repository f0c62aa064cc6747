"""The engine's FloatingBaseVelocityLimit: the serial limit's box at N = 1 and in every
world, typed errors, and a QP rollout that bounds the base as the serial controller does."""

from __future__ import annotations

import numpy as np
import pytest

import qpik
from qpik import batch
from qpik.controllers import QPController as EngineQP
from qpik.limits import FloatingBaseVelocityLimit, JointVelocityLimit
from qpik.tasks import DampingTask as EngineDamping
from qpik.tasks import FrameTask as EngineFrame
from qpik.errors import InvalidInput, ModelError, UnknownName
from qpik.limits import FloatingBaseVelocityLimit as SerialFloatingBaseLimit
from qpik.limits import JointVelocityLimit as SerialVelocityLimit

DT = 0.002
LINEAR, ANGULAR = [1.0, 1.0, 0.5], 2.0


def test_box_equals_the_serial_limits_in_every_world(chain_model):
    """Into an incoming box that is tighter on some base axes, looser on others."""
    model = chain_model(3, free_base=True)
    robot, robots = qpik.Robot(model), batch.Robot(model, 4)
    incoming = np.linspace(-3.0, 3.0, model.nv)
    lb, ub = -np.abs(incoming), np.abs(incoming) + 0.1
    SerialFloatingBaseLimit(robot, LINEAR, ANGULAR).apply(DT, lb, ub)
    for target in (robot, robots):
        lower, upper = np.tile(-np.abs(incoming), (target.n, 1)), np.tile(np.abs(incoming) + 0.1, (target.n, 1))
        limit = FloatingBaseVelocityLimit(target, LINEAR, ANGULAR)
        assert limit.constant and not limit.inequality_rows
        limit.apply(DT, lower, upper)
        np.testing.assert_array_equal(lower, np.tile(lb, (target.n, 1)))
        np.testing.assert_array_equal(upper, np.tile(ub, (target.n, 1)))


@pytest.mark.parametrize("arguments, error, match", [
    ({}, InvalidInput, "give a linear"), ({"linear": -1.0}, InvalidInput, "positive"),
    ({"linear": 1e308}, InvalidInput, "at most 1e"), ({"angular": [1.0, 2.0]}, InvalidInput, "3 numbers"),
    ({"angular": float("nan")}, InvalidInput, "positive"), ({"linear": 1.0, "joint": "j0"}, InvalidInput, "not a free"),
    ({"linear": 1.0, "joint": "jj"}, UnknownName, "jj")])
def test_refuses_bad_arguments(chain_model, arguments, error, match):
    with pytest.raises(error, match=match):
        FloatingBaseVelocityLimit(qpik.Robot(chain_model(3, free_base=True)), **arguments)


def test_needs_a_free_joint(chain_model):
    with pytest.raises(ModelError, match="no free joint"):
        FloatingBaseVelocityLimit(batch.Robot(chain_model(3), 2), linear=1.0)


def test_qp_rollout_bounds_the_base_as_the_serial_controller(chain_model, lockstep):
    """A far pose asked for in one step (dead-beat): the joint speed limit leaves the base
    free, this limit holds it per axis; the engine answers as the serial controller on
    the serial rollout's states, and its own rollout keeps the base within its bounds."""
    model = chain_model(3, free_base=True)
    speeds = {"j0": 5.0, "j1": 5.0, "j2": 5.0}

    def build(engine: bool):
        robot = qpik.Robot(model)
        Frame, Damping, QP = (EngineFrame, EngineDamping, EngineQP) if engine else \
            (qpik.FrameTask, qpik.DampingTask, qpik.QPController)
        Limits = (JointVelocityLimit, FloatingBaseVelocityLimit) if engine else \
            (SerialVelocityLimit, SerialFloatingBaseLimit)
        hand = Frame(robot, "tip")
        hand.set_target([0.8, -0.5, 0.9], np.eye(3)[[1, 2, 0]])
        return robot, QP(robot, [hand, Damping(robot, 1e-3, joints=["root", "j0", "j1", "j2"])],
                         [Limits[0](robot, speeds), Limits[1](robot, LINEAR, ANGULAR)], dt=DT)

    answers = lockstep(build(False), build(True), 200, DT)
    assert np.abs(answers[:, :3]).max() > 0.99  # the base did move, at its bound
    robot, controller = build(True)
    bound = np.concatenate([LINEAR, np.full(3, ANGULAR)])
    for _ in range(200):
        qdot = controller.compute_velocity()
        assert np.all(np.abs(qdot[:6]) <= bound * (1.0 + 1e-12))
        robot.integrate(qdot, DT)
