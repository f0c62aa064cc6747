"""JointPositionLimit: its box (on arrays, and on lists of floats) against the rule written
joint by joint."""

from __future__ import annotations

import numpy as np
import pytest

from qpik import InvalidInput, JointPositionLimit, Robot


def reference_box(limit: JointPositionLimit, q: np.ndarray, dt: float, lb: list, ub: list) -> tuple[list, list]:
    """The limit's rule, joint by joint: the step q + q̇Δt in the range pulled in by the
    margin (a fraction ``gain`` of the distance per step), the damper's rate within the
    influence distance, and a joint outside its range brought back no faster than the
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


@pytest.mark.parametrize("scene", ["arm", "hexapod"])
@pytest.mark.parametrize("influence", [0.0, 0.05, 0.8])
def test_the_box_follows_the_rule_joint_by_joint(scene, influence):
    robot = Robot.load(scene)
    limit = JointPositionLimit(robot, influence=influence, damper_rate=2.0, gain=0.7)
    rng = np.random.default_rng(1)
    ranges = robot.joint_limits
    for _ in range(200):  # inside, near and outside the ranges
        robot.q[ranges.qpos_index] = rng.uniform(ranges.lower - 0.3, ranges.upper + 0.3)
        speed = rng.uniform(0.5, 5.0, robot.nv)
        lb, ub = -speed, speed.copy()
        expected = reference_box(limit, robot.q, 0.002, lb.tolist(), ub.tolist())
        lists = (lb.tolist(), ub.tolist())  # the box as lists (a controller's box in floats)
        limit.apply(0.002, *lists)
        limit.apply(0.002, lb, ub)
        # The same scalar operations in the same order as the rule above (no BLAS, no
        # reduction): equal to the last bit on every machine, 1e-15 leaves one rounding.
        np.testing.assert_allclose(lb, expected[0], rtol=1e-15, atol=0)
        np.testing.assert_allclose(ub, expected[1], rtol=1e-15, atol=0)
        assert lists == (lb.tolist(), ub.tolist())  # the same operations in floats
        q_next = robot.q[ranges.qpos_index] + 0.002 * ub[ranges.dof_index]
        inside = (robot.q[ranges.qpos_index] <= ranges.upper)
        assert np.all(q_next[inside] <= ranges.upper[inside])  # the upper bound is never stepped past


@pytest.mark.parametrize("scene", ["arm", "hexapod"])
def test_a_box_kept_while_q_stays_clear_of_the_bounds_is_the_rule_s_box(scene):
    """The float pass keeps the incoming box unchanged without a pass over the joints while
    q stays within the distance where no bound can tighten it: along walks that reach the
    bounds, after jumps of q, a changed incoming box or gain, the box is the rule's."""
    robot = Robot.load(scene)
    limit = JointPositionLimit(robot, gain=0.5)
    limit._watched = True  # the arm has fewer joints than it takes to pay off
    passes = []
    remember = limit._remember
    limit._remember = lambda *arguments: (passes.append(1), remember(*arguments))
    rng = np.random.default_rng(3)
    ranges = robot.joint_limits
    speed = np.full(robot.nv, 2.0)
    steps = 600
    for k in range(steps):
        if k % 150 == 0:  # a jump: inside, or near a bound
            robot.q[ranges.qpos_index] = rng.uniform(ranges.lower + 0.004, ranges.upper - 0.004)
        if k == 300:
            speed = np.full(robot.nv, 1.5)  # another incoming box
        if k == 450:
            limit.gain = 0.9
        lb, ub = (-speed).tolist(), speed.tolist()
        expected = reference_box(limit, robot.q, 0.002, lb, ub)
        limit.apply(0.002, lb, ub)
        assert (lb, ub) == expected
        velocity = rng.uniform(np.array(lb), np.array(ub))  # toward the bounds as often as not
        robot.q[ranges.qpos_index] += 0.002 * velocity[ranges.dof_index]
    assert 0 < len(passes) < steps  # some steps kept the box, some needed the pass


@pytest.mark.parametrize("scene", ["arm", "hexapod"])
@pytest.mark.parametrize("influence", [0.0, 0.8])
def test_an_empty_incoming_box_stays_empty_in_floats_and_in_arrays(scene, influence):
    """A box an earlier limit left empty (lb > ub on some dofs) is not made feasible by
    the clipping into it: the solver layer must still see it empty and say so."""
    robot = Robot.load(scene)
    limit = JointPositionLimit(robot, influence=influence, damper_rate=2.0)
    rng = np.random.default_rng(2)
    ranges = robot.joint_limits
    for _ in range(200):
        robot.q[ranges.qpos_index] = rng.uniform(ranges.lower - 0.3, ranges.upper + 0.3)
        lb, ub = -rng.uniform(0.5, 500.0, robot.nv), rng.uniform(0.5, 500.0, robot.nv)
        empty = rng.random(robot.nv) < 0.5
        lb[empty], ub[empty] = rng.uniform(-500.0, 500.0, (2, int(empty.sum())))
        empty = lb > ub
        expected = reference_box(limit, robot.q, 0.002, lb.tolist(), ub.tolist())
        lists = (lb.tolist(), ub.tolist())
        limit.apply(0.002, *lists)
        limit.apply(0.002, lb, ub)
        assert lists == (lb.tolist(), ub.tolist()) == expected
        assert np.all(lb[empty] > ub[empty])


@pytest.mark.parametrize("value", [np.nan, np.inf, -np.inf])
def test_non_finite_position_is_an_error(value):
    robot = Robot.load("arm")
    limit = JointPositionLimit(robot)
    robot.q[1] = value
    with pytest.raises(InvalidInput, match="theta2"):
        limit.apply(0.002, np.full(4, -1.0), np.full(4, 1.0))


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
