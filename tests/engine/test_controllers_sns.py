"""The engine's SNSController: one robot equals an independent SNS (tests/core/
sns_reference.py: the algorithm as it was written before the engine, on the same tasks'
rows and limits) on steps and at every state of rollouts with joints saturated, tasks
scaled and braking bounds; each of N = 4 worlds equals its own one-world run; bad input
is a typed error and a diverging world is named."""

from __future__ import annotations

import importlib.util
from pathlib import Path

import mujoco
import numpy as np
import pytest

import qpik
import qpik.limits as engine_limits
import qpik.tasks as engine_tasks
from qpik.controllers import SNSController
from qpik.errors import DivergenceError, InvalidInput, WorldsFailed
from qpik.robots.arm.scenarios import ARM_START, SEED_PATH, TOO_FAST_SPEEDS, three_tasks_start
from qpik.trajectories import Segment

_spec = importlib.util.spec_from_file_location("sns_reference", Path(__file__).parents[1] / "core" / "sns_reference.py")
_reference = importlib.util.module_from_spec(_spec)
_spec.loader.exec_module(_reference)
ReferenceSNSController = _reference.ReferenceSNSController

DT = 0.002  # s
# One robot's q̇ equals the reference SNS's to this relative to 1 + ‖q̇‖ (rad/s): the same
# passes on the same task rows, written by other code (the reference's SVDs from LAPACK's
# dgesvd, the engine's over worlds).
TOLERANCE = 1e-10
# A world of N equals its own one-world run to this, relative.
WORLD_TOLERANCE = 1e-10
NARROW = {"theta2": (-0.55, 0.55), "theta3": (-0.55, 0.55)}  # σ saturates θ2, θ3 from three_tasks_start()


def _arm(q=ARM_START) -> qpik.Robot:
    robot = qpik.Robot.load("arm")
    robot.set_q(np.asarray(q, dtype=float))
    robot.update_kinematics()
    return robot


def _configurations(count: int, seed: int = 0) -> np.ndarray:
    rng = np.random.default_rng(seed)
    return np.column_stack([rng.uniform(-2.0, 2.0, (count, 3)), rng.uniform(0.2, 0.8, count)])


def _sns(robot, *, speeds=None, ranges=None, max_acceleration=None, split: bool = False, weight=1.0, target=None,
         rate=(0.1, -0.05), reference: bool = False):
    """SNS on the arm: the path (x, y; or x over y, ``split``) over σ, with joint position
    limits (``ranges`` tightened) and speed limits (``speeds`` lowered); with
    ``reference``, the independent SNS on the same levels and limits as well (one robot)."""
    tasks = engine_tasks
    position = tasks.PositionTask(robot, "end_effector", axes="xy", gain=500.0, weight=weight)
    if target is None:
        robot.ensure_kinematics()
        target = np.array(position.measured()) + [1e-4, -2e-4]
    position.set_target(target, rate)
    sigma = tasks.ManipulabilityTask(robot, tasks.SigmaProxy(robot, ("theta2", "theta3")), gain=5.0)
    levels = [[position], [sigma]]
    if split:  # x, then y, then σ: three levels, the null space carried below the first
        x = tasks.PositionTask(robot, "end_effector", axes="x", gain=500.0)
        y = tasks.PositionTask(robot, "end_effector", axes="y", gain=500.0, weight=[2.0])
        x.set_target(np.asarray(target)[..., :1], None if rate is None else np.asarray(rate)[..., :1])
        y.set_target(np.asarray(target)[..., 1:], None if rate is None else np.asarray(rate)[..., 1:])
        levels = [[x], [y], [sigma]]
    vmax = robot.velocity_limits.copy()
    for joint, speed in (speeds or {}).items():
        vmax[robot.joint_dof_index(joint)] = speed
    bounds = [engine_limits.JointPositionLimit(robot, robot.joint_limits.tightened(ranges or {}), influence=0.8,
                                               damper_rate=2.0), engine_limits.JointVelocityLimit(robot, vmax)]
    controller = SNSController(robot, levels=levels, limits=bounds, dt=DT, max_acceleration=max_acceleration)
    tracked = (position if not split else levels[0][0], levels[1][0] if split else None)
    if reference:
        return controller, tracked, ReferenceSNSController(robot, levels=levels, limits=bounds, dt=DT,
                                                           max_acceleration=max_acceleration)
    return controller, tracked


def _close(a: np.ndarray, b: np.ndarray, tolerance: float = TOLERANCE) -> bool:
    return float(np.linalg.norm(a - b)) <= tolerance * (1.0 + float(np.linalg.norm(b)))


SETUPS = {
    "free": {},
    "uniform weight": {"weight": 3.0},  # one task of one weight: its own rows
    "weighted path": {"weight": [1.0, 3.0]},  # rows scaled by √w
    "slow joints": {"speeds": TOO_FAST_SPEEDS},
    "very slow joints": {"speeds": {"theta1": 0.05, "theta2": 0.05, "theta3": 0.05, "d4": 0.02}},
    "three levels": {"split": True, "speeds": TOO_FAST_SPEEDS},
    "braking": {"ranges": NARROW, "max_acceleration": [2.0, 1.0, 1.0, np.inf]},
}


def _assert_as_the_reference(ours, theirs, qdot) -> bool:
    """The answer, task scales, saturation counts and box of a step against the reference's
    on the same state (the reference answers after the engine: the same rows). Returns
    whether the scales were a tie: once the levels above leave q̇ at a vertex of the box
    (every joint at a bound) a level below can move no joint, and its scale's window is a
    point that rounding puts inside or just outside, in either code: the answer is that
    vertex either way, the scale undetermined (reported 0 or the point)."""
    assert _close(qdot, theirs.compute_velocity())
    np.testing.assert_array_equal(ours.saturated, theirs.saturated)
    np.testing.assert_array_equal(ours.lb, theirs.lb)
    np.testing.assert_array_equal(ours.ub, theirs.ub)
    if np.abs(ours.task_scale - theirs.task_scale).max() <= 1e-10:
        return False
    vertex = np.isclose(qdot, ours.lb, rtol=0, atol=1e-12) | np.isclose(qdot, ours.ub, rtol=0, atol=1e-12)
    assert vertex.all(), (ours.task_scale, theirs.task_scale, qdot)
    return True


@pytest.mark.parametrize("setup", SETUPS)
def test_one_robot_equals_the_reference_sns(setup):
    options = SETUPS[setup]
    q = _configurations(8)
    q[0] = three_tasks_start()
    for qi in q:
        robot = _arm(qi)
        if "ranges" in options:  # inside the narrow ranges
            robot.set_q(np.clip(qi, -0.5, 0.5) + [0.0, 0.0, 0.0, 0.2])
        ours, _, theirs = _sns(robot, rate=(1.0, -0.5), reference=True, **options)
        qdot = np.array(ours.compute_velocity())
        assert qdot.shape == (4,) and ours.task_scale.shape == (theirs.level_count,)
        assert not _assert_as_the_reference(ours, theirs, qdot)
        np.testing.assert_array_equal(ours.report()["task_scale"], ours.task_scale)


ROLLOUTS = {  # (options, start, duration, the most steps whose scales may tie at a vertex)
    # σ drives θ2 and θ3 into ±0.55: level 1 saturates them.
    "saturated sigma": ({"ranges": NARROW}, three_tasks_start(), 5.0, 0),
    # The path in 0.5 s with 1 rad/s joints: level 0 saturates joints, then is scaled.
    "scaled path": ({"speeds": TOO_FAST_SPEEDS}, ARM_START, 0.5, 0),
    # x over y over σ, joints slow: saturation inside a null space; from step 128 x alone
    # drives every joint to a bound on some steps, and y's scale is a tie there (23 steps
    # measured; which of them rounding tips either way is not a promise).
    "three levels": ({"speeds": TOO_FAST_SPEEDS, "split": True}, ARM_START, 0.5, 40),
    # Braking bounds before the narrow ranges.
    "braking": ({"ranges": NARROW, "max_acceleration": 2.0}, three_tasks_start(), 5.0, 0),
}


@pytest.mark.parametrize("rollout", ROLLOUTS)
def test_every_state_of_a_rollout_is_answered_as_the_reference(rollout):
    """200 steps of the seed path from the scenario's start, joints saturating: at every
    state of the engine's rollout the reference SNS gives the same answer, scales and
    saturations (the scales of a level below a vertex of the box excepted: a tie)."""
    options, start, duration, most_ties = ROLLOUTS[rollout]
    segment = Segment(SEED_PATH[0], SEED_PATH[1], duration, time_law="cubic")
    robot = _arm(start)
    controller, (first, second), reference = _sns(robot, target=SEED_PATH[0], rate=None, reference=True, **options)
    scales, ties = [], 0
    for k in range(200):
        x, dx = segment.sample(k * DT)
        if second is None:
            first.set_target(x, dx)
        else:
            first.set_target(x[:1], dx[:1])
            second.set_target(x[1:], dx[1:])
        qdot = np.array(controller.compute_velocity())
        ties += _assert_as_the_reference(controller, reference, qdot)
        robot.integrate(qdot, DT)
        scales.append(np.concatenate([controller.task_scale, controller.saturated]))
    scales = np.array(scales)
    assert (scales[:, -1] > 0).any() or (scales[:, :-1] < 1).any()  # something saturated
    assert ties <= most_ties


def _worlds(count: int = 4, offset: float = 1e-3, seed: int = 1):
    q = _configurations(count, seed)
    q[0], q[1] = three_tasks_start(), three_tasks_start(0.54)
    rng = np.random.default_rng(seed + 10)
    targets = [_sns(_arm(qi))[1][0].measured() + rng.uniform(-offset, offset, 2) for qi in q]
    return q, np.array(targets)


def _batch(q: np.ndarray) -> qpik.batch.Robot:
    robots = qpik.batch.Robot.load("arm", n=len(q), allow_outside_limits=True)
    robots.set_q(q)
    return robots


WORLD_SETUPS = {
    "narrow ranges, braking": ({"ranges": NARROW, "max_acceleration": 2.0}, 1e-3),
    "slow joints, three levels": ({"speeds": TOO_FAST_SPEEDS, "split": True}, 0.05),
}


@pytest.mark.parametrize("setup", WORLD_SETUPS)
def test_each_of_four_worlds_equals_its_own_one_world_run(setup):
    """N = 4 worlds of different states and targets, 20 steps, joints saturating in some."""
    options, offset = WORLD_SETUPS[setup]
    q, targets = _worlds(offset=offset)
    robots = _batch(q)
    batch, _ = _sns(robots, target=targets, **options)
    singles = [(robot, _sns(robot, target=target, **options)[0])
               for robot, target in ((_arm(qi), ti) for qi, ti in zip(q, targets))]
    saturated = 0
    for _ in range(20):
        qdots = batch.compute_velocity()
        assert qdots.shape == (4, 4) and batch.task_scale.shape == (4, batch.level_count)
        for w, (robot, single) in enumerate(singles):
            qdot = single.compute_velocity()
            assert _close(qdots[w], qdot, WORLD_TOLERANCE)
            np.testing.assert_array_equal(batch.task_scale[w], single.task_scale)
            np.testing.assert_array_equal(batch.saturated[w], single.saturated)
            np.testing.assert_array_equal(batch.lb[w], single.lb)
            robot.integrate(qdot, DT)
        saturated += int(batch.saturated.sum())
        robots.integrate(qdots, DT)
    assert saturated > 0


def test_bad_input_is_typed():
    robot = _arm()
    position = engine_tasks.PositionTask(robot, "end_effector", axes="xy", gain=500.0)
    limits = [engine_limits.JointPositionLimit(robot), engine_limits.JointVelocityLimit(robot)]

    class Row(engine_limits.Limit):
        inequality_rows = 1

    with pytest.raises(InvalidInput, match="general rows .*Row"):
        SNSController(robot, [position], [*limits, Row()], dt=DT)
    for bad in (0.0, -1.0, np.nan, -np.inf, 1e13, [1.0, 1.0], [1.0, 1.0, np.nan, 1.0], "fast"):
        with pytest.raises(InvalidInput, match="max_acceleration"):
            SNSController(robot, [position], limits, dt=DT, max_acceleration=bad)
    with pytest.raises(InvalidInput, match="joint position limit"):
        SNSController(robot, [position], [engine_limits.JointVelocityLimit(robot)], dt=DT, max_acceleration=1.0)
    with pytest.raises(InvalidInput, match="level 1 is empty"):
        SNSController(robot, levels=[[position], []], dt=DT)
    for dt in (None, 0.0, -1.0, np.inf):
        with pytest.raises(InvalidInput, match="dt"):
            SNSController(robot, [position], dt=dt)
    jointless = qpik.Robot(mujoco.MjModel.from_xml_string(
        '<mujoco><worldbody><body><geom size="0.1"/><site name="tip"/></body></worldbody></mujoco>'))
    tip = engine_tasks.PositionTask(jointless, "tip", gain=1.0)
    with pytest.raises(InvalidInput, match="degree of freedom"):
        SNSController(jointless, [tip], dt=DT)


class Spike(engine_tasks.Task):
    """A 1-row task whose Jacobian is 1e200 on θ1 where d4 > 0.7 m: its ‖J‖² overflows."""

    dim = 1

    def compute_error(self, robot):
        return np.array([1e-3])

    def compute_jacobian(self, robot):
        return np.array([[1e200 if robot.q[3] > 0.7 else 1.0, 1.0, 0.0, 0.0]])


def test_a_diverging_world_is_named_and_the_others_are_solved():
    q, targets = _worlds()
    q[2, 3] = 0.75  # world 2: the spike
    robot = _arm(q[2])
    with pytest.raises(DivergenceError, match="not finite"):
        SNSController(robot, [Spike(robot, gain=10.0)], dt=DT).compute_velocity()
    robots = _batch(q)
    position = engine_tasks.PositionTask(robots, "end_effector", axes="xy", gain=500.0)
    position.set_target(targets)
    batch = SNSController(robots, levels=[[position], [Spike(robots, gain=10.0)]], dt=DT)
    with pytest.raises(WorldsFailed) as failed:
        batch.compute_velocity()
    assert failed.value.worlds.tolist() == [2] and "DivergenceError" in failed.value.reasons[2]
    np.testing.assert_array_equal(failed.value.qdot[2], 0.0)
    for w in (0, 1, 3):
        one = _arm(q[w])
        single_position = engine_tasks.PositionTask(one, "end_effector", axes="xy", gain=500.0)
        single_position.set_target(targets[w])
        single = SNSController(one, levels=[[single_position], [Spike(one, gain=10.0)]], dt=DT)
        assert _close(failed.value.qdot[w], single.compute_velocity(), WORLD_TOLERANCE)
