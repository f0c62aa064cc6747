"""JointPositionLimit: the box it writes into the (N, nv) box of one robot (N = 1) and of
N = 4 worlds, against the rule written joint by joint, world by world."""

from __future__ import annotations

import numpy as np
import pytest

from qpik import DampingTask, InvalidInput, JointPositionLimit, QPController, Robot, batch

DT = 0.002


def worlds(scene: str, n: int):
    """One robot (N = 1) or a batch of n worlds of ``scene``."""
    return Robot.load(scene) if n == 1 else batch.Robot.load(scene, n=n)


def reference_box(limit: JointPositionLimit, q: np.ndarray, dt: float, lb: list, ub: list) -> tuple[list, list]:
    """The limit's rule, joint by joint in floats: the step q + q̇Δt in the range pulled in
    by the margin (a fraction ``gain`` of the distance per step), the damper's rate within
    the influence distance, and a joint outside its range brought back no faster than the
    velocity box allows."""
    lb, ub = list(lb), list(ub)
    step_rate = limit.gain / dt
    damped = min(limit.damper_rate / limit.influence, step_rate) if limit.influence > 0 else step_rate
    ranges = limit.limits
    for qi, di, low_end, high_end in zip(ranges.qpos_index, ranges.dof_index, ranges.lower, ranges.upper):
        low, high = low_end + limit.margin - q[qi], high_end - limit.margin - q[qi]
        low *= damped if abs(low) < limit.influence else step_rate
        high *= damped if abs(high) < limit.influence else step_rate
        low, high = min(low, ub[di]), max(high, lb[di])  # recovery never asks for more than the box
        lb[di], ub[di] = max(lb[di], low), min(ub[di], high)
    return lb, ub


def reference_boxes(limit, robot, lower: np.ndarray, upper: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The rule's box of every world, each from its own configuration and incoming box."""
    boxes = [reference_box(limit, q, DT, lb.tolist(), ub.tolist()) for q, lb, ub in zip(robot.qpos, lower, upper)]
    return np.array([b[0] for b in boxes]), np.array([b[1] for b in boxes])


@pytest.mark.parametrize("n", [1, 4])
@pytest.mark.parametrize("scene", ["arm", "hexapod"])
@pytest.mark.parametrize("influence", [0.0, 0.05, 0.8])
def test_the_box_follows_the_rule_joint_by_joint(scene, influence, n):
    robot = worlds(scene, n)
    limit = JointPositionLimit(robot, influence=influence, damper_rate=2.0, gain=0.7)
    rng = np.random.default_rng(1)
    ranges = robot.joint_limits
    qi, di = ranges.qpos_index, ranges.dof_index
    for _ in range(200 // n):  # inside, near and outside the ranges, different in every world
        robot.qpos[:, qi] = rng.uniform(ranges.lower - 0.3, ranges.upper + 0.3, (n, len(qi)))
        speed = rng.uniform(0.5, 5.0, (n, robot.nv))
        lb, ub = -speed, speed.copy()
        expected = reference_boxes(limit, robot, lb, ub)
        limit.apply(DT, lb, ub)
        # The same scalar operations in the same order as the rule above (no BLAS, no
        # reduction): equal to the last bit on every machine, 1e-15 leaves one rounding.
        np.testing.assert_allclose(lb, expected[0], rtol=1e-15, atol=0)
        np.testing.assert_allclose(ub, expected[1], rtol=1e-15, atol=0)
        q = robot.qpos[:, qi]
        # A bound is never stepped past from inside the range (the margin absorbs rounding).
        inside_upper, inside_lower = q <= ranges.upper, q >= ranges.lower
        assert np.all((q + DT * ub[:, di])[inside_upper] <= np.broadcast_to(ranges.upper, q.shape)[inside_upper])
        assert np.all((q + DT * lb[:, di])[inside_lower] >= np.broadcast_to(ranges.lower, q.shape)[inside_lower])


@pytest.mark.parametrize("n", [1, 4])
@pytest.mark.parametrize("scene", ["arm", "hexapod"])
def test_the_box_is_the_rule_s_along_walks_that_reach_the_bounds(scene, n):
    """Step after step, as a controller calls it: along walks to and from the bounds,
    after jumps of q, a changed incoming box or gain, the box is the rule's exactly."""
    robot = worlds(scene, n)
    limit = JointPositionLimit(robot, gain=0.5)
    rng = np.random.default_rng(3)
    ranges = robot.joint_limits
    qi, di = ranges.qpos_index, ranges.dof_index
    speed = np.full((n, robot.nv), 2.0)
    tightened = []  # per step: whether some bound tightened the incoming box
    for k in range(600):
        if k % 150 == 0:  # a jump: anywhere inside, or 4 to 10 mm (mrad) from a bound
            q = rng.uniform(ranges.lower + 0.004, ranges.upper - 0.004, (n, len(qi)))
            if k % 300:
                near = rng.uniform(0.004, 0.01, q.shape)
                q = np.where(rng.random(q.shape) < 0.5, ranges.lower + near, ranges.upper - near)
            robot.qpos[:, qi] = q
        if k == 300:
            speed = np.full((n, robot.nv), 1.5)  # another incoming box
        if k == 450:
            limit.gain = 0.9
        lb, ub = -speed, speed.copy()
        expected = reference_boxes(limit, robot, lb, ub)
        limit.apply(DT, lb, ub)
        np.testing.assert_array_equal(lb, expected[0])
        np.testing.assert_array_equal(ub, expected[1])
        tightened.append(bool(np.any((lb[:, di] > -speed[:, di]) | (ub[:, di] < speed[:, di]))))
        velocity = rng.uniform(lb, ub)  # toward the bounds as often as not
        robot.qpos[:, qi] += DT * velocity[:, di]
    assert 0 < sum(tightened) < len(tightened)  # steps clear of the bounds, and steps at them


@pytest.mark.parametrize("n", [1, 4])
@pytest.mark.parametrize("scene", ["arm", "hexapod"])
@pytest.mark.parametrize("influence", [0.0, 0.8])
def test_an_empty_incoming_box_stays_empty(scene, influence, n):
    """A box an earlier limit left empty (lb > ub on some dofs) is not made feasible by
    the clipping into it: the solver layer must still see it empty and say so."""
    robot = worlds(scene, n)
    limit = JointPositionLimit(robot, influence=influence, damper_rate=2.0)
    rng = np.random.default_rng(2)
    ranges = robot.joint_limits
    qi = ranges.qpos_index
    emptied = 0
    for _ in range(200 // n):
        robot.qpos[:, qi] = rng.uniform(ranges.lower - 0.3, ranges.upper + 0.3, (n, len(qi)))
        lb, ub = -rng.uniform(0.5, 500.0, (n, robot.nv)), rng.uniform(0.5, 500.0, (n, robot.nv))
        empty = rng.random((n, robot.nv)) < 0.5
        lb[empty], ub[empty] = rng.uniform(-500.0, 500.0, (2, int(empty.sum())))
        empty = lb > ub
        emptied += int(empty.sum())
        expected = reference_boxes(limit, robot, lb, ub)
        limit.apply(DT, lb, ub)
        np.testing.assert_array_equal(lb, expected[0])
        np.testing.assert_array_equal(ub, expected[1])
        assert np.all(lb[empty] > ub[empty])
    assert emptied > 100  # about a quarter of the dofs came in empty


@pytest.mark.parametrize("value", [np.nan, np.inf, -np.inf])
def test_non_finite_position_is_an_error(value):
    """Refused by the step's kinematics update, before any limit reads q."""
    robot = Robot.load("arm")
    controller = QPController(robot, [DampingTask(robot)], [JointPositionLimit(robot)], dt=DT)
    controller.compute_velocity()  # (the first step also checks the start against the ranges)
    robot.q[1] = value
    with pytest.raises(InvalidInput, match="not finite.*joint theta2"):
        controller.compute_velocity()


@pytest.mark.parametrize("argument, value", [
    ("influence", "0.1 rad"), ("influence", [0.1, 0.2]), ("influence", None), ("influence", -0.1),
    ("damper_rate", "fast"), ("damper_rate", [20.0]), ("damper_rate", 0.0), ("damper_rate", np.nan),
    ("gain", "1"), ("gain", [0.5]), ("gain", 0.0), ("gain", 1.5),
    ("margin", "tiny"), ("margin", [1e-10]), ("margin", np.inf)])
def test_a_bad_parameter_is_a_typed_error_naming_it(argument, value):
    """Strings and lists used to escape as TypeError/ValueError from a comparison."""
    with pytest.raises(InvalidInput, match=argument.replace("_", " ").split()[0]):
        JointPositionLimit(Robot.load("arm"), **{argument: value})


def test_numbers_of_any_type_are_accepted_as_floats():
    limit = JointPositionLimit(Robot.load("arm"), gain=np.float32(0.5), influence=1, damper_rate=np.int64(10))
    assert (limit.gain, limit.influence, limit.damper_rate) == (0.5, 1.0, 10.0)
    assert all(type(v) is float for v in (limit.gain, limit.influence, limit.damper_rate))
