"""The engine's AccelerationLimit: its box at N = 1 against the rule written out (the
previous velocity mj_differentiatePos of the configurations it saw, over Δt, through ball
and free joints too; a reset's velocity instead), each of N worlds its own, reset per
world, typed errors, and a QP rollout that keeps it, each step the minimiser of its QP
solved independently."""

from __future__ import annotations

import mujoco
import numpy as np
import pytest

import qpik
from qpik import batch
from qpik.controllers import QPController
from qpik.errors import InvalidInput, InvalidWorlds
from qpik.limits import AccelerationLimit
from qpik.tasks import DampingTask, PositionTask

DT = 0.002
AMAX = 20.0


def moves(nv: int, steps: int, seed: int) -> np.ndarray:
    return np.random.default_rng(seed).uniform(-2.0, 2.0, (steps, nv))


def unbounded(n: int, nv: int) -> tuple[np.ndarray, np.ndarray]:
    return np.full((n, nv), -np.inf), np.full((n, nv), np.inf)


def test_box_follows_the_rule_along_a_motion(chain_model, assert_same):
    """A free-floating chain (the free joint's quaternion differentiated too) moved by
    random velocities; reset with a velocity halfway. The rule: the previous velocity is
    (q_k ⊖ q_{k−1})/Δt (MuJoCo's mj_differentiatePos at Δt, the reset's velocity on the
    step after a reset, zero on the first), the box its ±a Δt intersected with the
    incoming one. The limit differentiates with its dt = 1 difference over Δt: equal to
    rounding (1e-13 of the box's norm)."""
    model = chain_model(4, free_base=True)
    robot = qpik.Robot(model)
    bounds = np.linspace(5.0, 30.0, model.nv)
    limit = AccelerationLimit(robot, bounds)
    previous_q, previous = robot.q.copy(), np.zeros(model.nv)
    for k, qdot in enumerate(moves(model.nv, 12, 0)):
        if k == 6:
            start = np.linspace(-1.0, 1.0, model.nv)
            limit.reset(start)
        if k and k != 6:
            mujoco.mj_differentiatePos(model, previous, DT, previous_q, robot.q)
        elif k == 6:
            previous = start.copy()
        expected = (np.maximum(-3.0, previous - bounds * DT), np.minimum(3.0, previous + bounds * DT))
        lower, upper = np.full((1, model.nv), -3.0), np.full((1, model.nv), 3.0)
        limit.apply(DT, lower, upper)
        assert_same(lower[0], expected[0], 1e-13)
        assert_same(upper[0], expected[1], 1e-13)
        assert_same(limit.previous_velocity, previous, 1e-13)
        assert np.any(expected[0] > -3.0) and np.any(expected[1] < 3.0)  # the rule binds
        previous_q = robot.q.copy()
        robot.integrate(qdot, DT)


def test_each_world_is_its_own_run(chain_model, assert_same):
    """Four worlds moved differently, started from different velocities (one reset on
    its own later): each world's box is its one-world run's, to 1e-10 of its norm (N
    worlds integrate and differentiate the free joint's quaternion in NumPy, one world
    in MuJoCo: equal to rounding)."""
    model, n = chain_model(4, free_base=True), 4
    robots = batch.Robot(model, n)
    limit = AccelerationLimit(robots, AMAX)
    starts = np.random.default_rng(1).uniform(-1.0, 1.0, (n, model.nv))
    limit.reset(starts)
    alone = []
    for w in range(n):
        robot = qpik.Robot(model)
        alone.append((robot, AccelerationLimit(robot, AMAX)))
        alone[w][1].reset(starts[w])
    velocities = np.stack([moves(model.nv, 8, 2 + w) for w in range(n)], axis=1)  # (steps, N, nv)
    for k, qdot in enumerate(velocities):
        if k == 4:
            limit.reset(np.ones(model.nv), worlds=[2])
            alone[2][1].reset(np.ones(model.nv))
        lower, upper = unbounded(n, model.nv)
        limit.apply(DT, lower, upper)
        for w, (robot, one) in enumerate(alone):
            box = unbounded(1, model.nv)
            one.apply(DT, *box)
            assert_same(lower[w], box[0][0])
            assert_same(upper[w], box[1][0])
            robot.integrate(qdot[w], DT)
        robots.integrate(qdot, DT)


@pytest.mark.parametrize("bound, match", [(0.0, "positive"), (-1.0, "positive"), (float("nan"), "positive"),
                                          (1e308, "at most 1e"), ([1.0, 2.0], "one per dof"), ("fast", "one per dof")])
def test_refuses_bad_bounds(chain_model, bound, match):
    with pytest.raises(InvalidInput, match=match):
        AccelerationLimit(qpik.Robot(chain_model(3)), bound)


def test_reset_checks_the_velocity(chain_model):
    model = chain_model(3)
    with pytest.raises(InvalidInput, match="shape"):
        AccelerationLimit(qpik.Robot(model), AMAX).reset(np.zeros(2))
    with pytest.raises(InvalidInput, match="NaN"):
        AccelerationLimit(qpik.Robot(model), AMAX).reset([0.0, np.nan, 0.0])
    bad = np.zeros((3, 3))
    bad[1, 0] = np.inf
    with pytest.raises(InvalidWorlds, match="worlds 1"):
        AccelerationLimit(batch.Robot(model, 3), AMAX).reset(bad)
    assert np.isinf(AccelerationLimit(qpik.Robot(model), [1.0, np.inf, 2.0]).max_acceleration[1])  # inf: free


def test_qp_rollout_bounds_every_change_of_velocity(chain_model, lockstep):
    """A target that jumps every 0.1 s (a step the dead-beat gain asks to cover at once):
    every answer is the minimiser of its QP solved independently, its box the rule's
    written out (the previous answer ± aΔt, the limit differentiating what the robot did),
    and no velocity changes by more than aΔt (to rounding of q̇)."""
    model = chain_model()
    robot = qpik.Robot(model)
    robot.set_q(np.linspace(0.3, -0.4, model.nq))
    reach = PositionTask(robot, "tip")
    controller = QPController(robot, [reach, DampingTask(robot, 1e-4)], [AccelerationLimit(robot, AMAX)], dt=DT)
    base = np.array(reach.target)
    answers = [np.zeros(model.nv)]  # the limit starts at rest

    def jump(k: int) -> None:
        if k % 50 == 0:
            reach.set_target(base + (0.1 if (k // 50) % 2 else -0.1) * np.array([1.0, -0.5, 0.3]))

    def box(k: int):
        return answers[-1] - AMAX * DT, answers[-1] + AMAX * DT

    rollout = lockstep(robot, controller, 200, DT, jump, after=lambda k, qdot: answers.append(qdot), box=box)
    steps = np.diff(np.vstack([np.zeros(model.nv), rollout]), axis=0)
    assert np.abs(steps).max() <= AMAX * DT + 1e-9
    assert np.isclose(np.abs(steps).max(axis=1), AMAX * DT, rtol=1e-9).sum() > 20  # the bound did bind
