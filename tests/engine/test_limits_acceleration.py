"""The engine's AccelerationLimit: the serial limit's box at N = 1 (the previous velocity
differentiated from the configurations it sees, through ball and free joints too), each
of N worlds its own, reset per world, typed errors, and a QP rollout that keeps it."""

from __future__ import annotations

import numpy as np
import pytest

import qpik
from qpik import batch
from qpik.controllers import QPController as EngineQP
from qpik.limits import AccelerationLimit
from qpik.tasks import DampingTask as EngineDamping
from qpik.tasks import PositionTask as EnginePosition
from qpik.errors import InvalidInput, InvalidWorlds
from qpik.limits import AccelerationLimit as SerialAccelerationLimit

DT = 0.002
AMAX = 20.0


def moves(nv: int, steps: int, seed: int) -> np.ndarray:
    return np.random.default_rng(seed).uniform(-2.0, 2.0, (steps, nv))


def unbounded(n: int, nv: int) -> tuple[np.ndarray, np.ndarray]:
    return np.full((n, nv), -np.inf), np.full((n, nv), np.inf)


def test_box_equals_the_serial_limits_along_a_motion(chain_model, assert_same):
    """A free-floating chain (the free joint's quaternion differentiated too) moved by
    random velocities; reset with a velocity halfway. The serial limit differentiates
    with mj_differentiatePos(dt), the engine with its dt = 1 difference over dt: equal
    to rounding (1e-13 of the box's norm)."""
    model = chain_model(4, free_base=True)
    serial_robot, engine_robot = qpik.Robot(model), qpik.Robot(model)
    serial = SerialAccelerationLimit(serial_robot, np.linspace(5.0, 30.0, model.nv))
    engine = AccelerationLimit(engine_robot, np.linspace(5.0, 30.0, model.nv))
    for k, qdot in enumerate(moves(model.nv, 12, 0)):
        if k == 6:
            start = np.linspace(-1.0, 1.0, model.nv)
            serial.reset(start)
            engine.reset(start)
        lb, ub = np.full(model.nv, -3.0), np.full(model.nv, 3.0)
        lower, upper = lb[None].copy(), ub[None].copy()
        serial.apply(DT, lb, ub)
        engine.apply(DT, lower, upper)
        assert_same(lower[0], lb, 1e-13)
        assert_same(upper[0], ub, 1e-13)
        assert_same(engine.previous_velocity, serial.previous_velocity, 1e-13)
        for robot in (serial_robot, engine_robot):
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
    on the serial rollout's states the engine answers as the serial controller; its own
    rollout changes no velocity by more than aΔt (to rounding of q̇)."""
    model = chain_model()

    def build(engine: bool):
        robot = qpik.Robot(model)
        robot.set_q(np.linspace(0.3, -0.4, model.nq))
        Position, Damping, QP, Limit = (EnginePosition, EngineDamping, EngineQP, AccelerationLimit) if engine else \
            (qpik.PositionTask, qpik.DampingTask, qpik.QPController, SerialAccelerationLimit)
        reach = Position(robot, "tip")
        return robot, QP(robot, [reach, Damping(robot, 1e-4)], [Limit(robot, AMAX)], dt=DT), reach

    serial, engine = build(False), build(True)
    base = np.array(serial[2].target)

    def jump(k: int, tasks=(serial[2], engine[2])) -> None:
        if k % 50 == 0:
            for task in tasks:
                task.set_target(base + (0.1 if (k // 50) % 2 else -0.1) * np.array([1.0, -0.5, 0.3]))

    answers = lockstep(serial[:2], engine[:2], 200, DT, jump)
    assert np.abs(np.diff(answers, axis=0)).max() <= AMAX * DT + 1e-9
    robot, controller, task = engine
    robot.set_q(np.linspace(0.3, -0.4, model.nq))
    controller.limits[0].reset()
    previous = np.zeros(model.nv)
    for k in range(200):
        jump(k, (task,))
        qdot = np.array(controller.compute_velocity())
        assert np.abs(qdot - previous).max() <= AMAX * DT + 1e-9
        robot.integrate(qdot, DT)
        previous = qdot
