"""The engine's FloatingBaseVelocityLimit: its box written out at N = 1 and in each of N
worlds (its own one-world box), typed errors, and a QP rollout that bounds the base, each
step the minimiser of its QP solved independently."""

from __future__ import annotations

import numpy as np
import pytest

import qpik
from qpik import batch
from qpik.controllers import QPController
from qpik.errors import InvalidInput, ModelError, UnknownName
from qpik.limits import FloatingBaseVelocityLimit, JointVelocityLimit
from qpik.tasks import DampingTask, FrameTask

DT = 0.002
LINEAR, ANGULAR = [1.0, 1.0, 0.5], 2.0


def test_box_is_the_base_bounds_in_every_world(chain_model):
    """Into an incoming box that is tighter on some base axes, looser on others: the free
    joint's six dofs (the first six) become max(lower, −bound), min(upper, bound), the
    hinges keep the incoming box; in one robot and in each of 4 worlds."""
    model = chain_model(3, free_base=True)
    incoming = np.linspace(-3.0, 3.0, model.nv)
    bound = np.concatenate([LINEAR, np.full(3, ANGULAR)])
    expected_lower, expected_upper = -np.abs(incoming), np.abs(incoming) + 0.1
    expected_lower[:6] = np.maximum(expected_lower[:6], -bound)
    expected_upper[:6] = np.minimum(expected_upper[:6], bound)
    assert np.any(expected_upper[:6] == bound) and np.any(expected_upper[:6] < bound)  # both cases
    for target in (qpik.Robot(model), batch.Robot(model, 4)):
        lower, upper = np.tile(-np.abs(incoming), (target.n, 1)), np.tile(np.abs(incoming) + 0.1, (target.n, 1))
        limit = FloatingBaseVelocityLimit(target, LINEAR, ANGULAR)
        assert limit.constant and not limit.inequality_rows
        limit.apply(DT, lower, upper)
        np.testing.assert_array_equal(lower, np.tile(expected_lower, (target.n, 1)))
        np.testing.assert_array_equal(upper, np.tile(expected_upper, (target.n, 1)))


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


def test_qp_rollout_bounds_the_base_and_each_step_is_its_qps_minimiser(chain_model, lockstep):
    """A far pose asked for in one step (dead-beat): the joint speed limit leaves the base
    free, this limit holds it per axis; every answer is the minimiser of its QP solved
    independently, and the base stays within its bounds."""
    model = chain_model(3, free_base=True)
    robot = qpik.Robot(model)
    hand = FrameTask(robot, "tip")
    hand.set_target([0.8, -0.5, 0.9], np.eye(3)[[1, 2, 0]])
    limits = [JointVelocityLimit(robot, {"j0": 5.0, "j1": 5.0, "j2": 5.0}), FloatingBaseVelocityLimit(robot, LINEAR,
                                                                                                      ANGULAR)]
    controller = QPController(robot, [hand, DampingTask(robot, 1e-3, joints=["root", "j0", "j1", "j2"])], limits,
                              dt=DT)
    bound = np.concatenate([LINEAR, np.full(3, ANGULAR)])

    def after(k, qdot):
        assert np.all(np.abs(qdot[:6]) <= bound * (1.0 + 1e-12))

    answers = lockstep(robot, controller, 200, DT, after=after)
    assert np.abs(answers[:, :3]).max() > 0.99  # the base did move, at its bound
