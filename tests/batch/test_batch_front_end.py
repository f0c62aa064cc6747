"""qpik.batch, the engine's N-world front end: every world of a batched controller equals
its own one-world run of the same classes (on a qpik.Robot) and the minimiser of its own
QP solved independently (the QP written out from the world's task rows and limits, DAQP
called directly: tests/engine/references.py), step after step of a closed loop in which
the limits bind — on the bundled arm and a third-party 7-DoF arm. A failing world is
named while the others are solved; bad input is a typed error; the rollouts run; the
exports are the engine's classes."""

from __future__ import annotations

import importlib.util
from pathlib import Path

import numpy as np
import pytest

import qpik
from qpik import batch
from qpik.errors import InvalidInput, QpikError

_spec = importlib.util.spec_from_file_location("references", Path(__file__).parents[1] / "engine" / "references.py")
references = importlib.util.module_from_spec(_spec)
_spec.loader.exec_module(references)

DT = 0.002
STEPS = 300
N = 4
PUSHER_START = np.array([0.2, 0.3, -0.2, -1.0, 0.3, -0.5, 0.2])
PUSHER_SPEED = 2.0  # rad/s on every joint (its MJCF declares none)
# Norm-wise, relative to max(|q̇|, 1 rad/s), after up to STEPS closed-loop steps whose
# roundings feed back through q: a world against its own one-world run (the same
# formulas, the engine's N = 1 primitives in C against its N > 1 NumPy ones; measured
# 3e-13 on the arm, 8e-14 on the pusher).
SAME_ENGINE = 1e-10
# Each world's answer against the minimiser of its own QP at the batch's state, solved
# independently (the figure), relative to max(|q̇|, 1e-3 rad/s).
INDEPENDENT = 1e-9


def _arm(lib, robot, targets, start):
    """A soft x-y position task (LM-damped) to targets out of reach, the σ task, joint
    ranges with their damper and speed limits: the speed limits bind while it moves."""
    robot.set_q(start)
    robot.ensure_kinematics()
    task = lib.PositionTask(robot, "end_effector", axes="xy", gain=500.0, lm_damping=10.0)
    task.set_target(targets)
    sigma = lib.ManipulabilityTask(robot, lib.SigmaProxy(robot, ["theta2", "theta3"]), gain=5.0)
    limits = [lib.JointPositionLimit(robot, influence=0.1, damper_rate=2.0), lib.JointVelocityLimit(robot)]
    return lib.QPController(robot, [task, sigma], limits, dt=DT)


def _pusher(lib, robot, offsets, start):
    """The tip's pose 0.3 m away with a posture task, joint ranges and 2 rad/s speed limits."""
    robot.set_q(start)
    robot.ensure_kinematics()
    hand = lib.FrameTask(robot, "tips_arm", "body", position_gain=50.0, orientation_gain=50.0)
    hand.set_target(np.asarray(hand.target_position) + offsets, hand.target_rotation)
    posture = lib.PostureTask(robot, gain=1.0, weight=1e-2)
    limits = [lib.JointPositionLimit(robot), lib.JointVelocityLimit(robot, np.full(7, PUSHER_SPEED))]
    return lib.QPController(robot, [hand, posture], limits, dt=DT)


def _relative(a: np.ndarray, b: np.ndarray) -> float:
    return float(np.linalg.norm(a - b) / max(np.linalg.norm(b), 1.0))


def _compare_closed_loops(make, robots, one_world, inputs, starts):
    """Step the batch and each world's one-world run in closed loop; at every step each
    world's answer is also checked against the minimiser of its QP solved independently.
    The worst relative difference from the one-world runs, and on how many steps a bound
    was active."""
    controller = make(batch, robots, inputs, starts)
    ones = [(r, make(batch, r, inputs[w], starts[w])) for w, r in enumerate(one_world())]
    worst_one = 0.0
    bound_steps = 0
    for _ in range(STEPS):
        qdot = controller.compute_velocity()
        lower, upper, _, _ = references.limits_box(controller.limits, DT, robots.n, robots.nv)
        for w in range(robots.n):
            expected = references.qp_answer(controller.tasks, w, robots.nv, (lower[w], upper[w]))
            assert references.close(qdot[w], expected, INDEPENDENT), (w, qdot[w], expected)
        at_bound = np.isclose(qdot, controller.lb, rtol=0, atol=1e-12) | np.isclose(qdot, controller.ub, rtol=0,
                                                                                      atol=1e-12)
        bound_steps += bool(at_bound.any())
        robots.integrate(qdot, DT)
        for w, (one, c1) in enumerate(ones):
            v1 = c1.compute_velocity()
            worst_one = max(worst_one, _relative(qdot[w], v1))
            one.integrate(v1, DT)
    return worst_one, bound_steps


def _starts(robots, rng, spread):
    limits = robots.joint_limits
    q = np.tile(robots.q[0], (robots.n, 1))
    span = limits.upper - limits.lower
    q[:, limits.qpos_index] = np.clip(q[:, limits.qpos_index] + spread * span * rng.uniform(-1, 1, (robots.n, len(span))),
                                      limits.lower + 1e-3 * span, limits.upper - 1e-3 * span)
    return q


def test_arm_worlds_equal_their_one_world_runs_and_their_qps_minimisers_with_limits_binding():
    rng = np.random.default_rng(1)
    robots = batch.Robot.load("arm", N)
    starts = _starts(robots, rng, 0.2)
    targets = rng.uniform(-2.2, 2.2, (N, 2))  # far: the speed and range limits bind
    worst_one, bound = _compare_closed_loops(_arm, robots, lambda: [qpik.Robot.load("arm") for _ in range(N)],
                                             targets, starts)
    assert worst_one <= SAME_ENGINE, worst_one
    assert bound > STEPS // 4  # the limits bound on many steps


def test_pusher_worlds_equal_their_one_world_runs_and_their_qps_minimisers_with_limits_binding(pusher_model):
    rng = np.random.default_rng(3)
    robots = batch.Robot(pusher_model, N, name="pusher_arm")
    robots.set_q(PUSHER_START)
    starts = _starts(robots, rng, 0.05)
    offsets = rng.uniform(-0.3, 0.3, (N, 3))
    worst_one, bound = _compare_closed_loops(
        _pusher, robots, lambda: [qpik.Robot(pusher_model, name="pusher_arm") for _ in range(N)], offsets, starts)
    assert worst_one <= SAME_ENGINE, worst_one
    assert bound > STEPS // 4


def test_an_infeasible_world_is_named_and_the_others_are_solved_as_alone():
    robots = batch.Robot.load("arm", N)
    task = batch.PositionTask(robots, "end_effector", axes="xy", gain=500.0, hard=True)
    targets = task.target + np.array([[0.001, 0.0], [0.0, 0.001], [1.0, 0.0], [-0.001, 0.001]])
    task.set_target(targets)  # world 2: 500 m/s asked with an 8 rad/s box: no point meets both
    controller = batch.QPController(robots, [task, batch.DampingTask(robots)], [batch.JointVelocityLimit(robots)],
                                    dt=DT)
    with pytest.raises(batch.WorldsFailed) as caught:
        controller.compute_velocity()
    error = caught.value
    assert isinstance(error, QpikError)
    assert error.worlds.tolist() == [2]
    assert "world 2" in str(error) and "infeasible" in error.reasons[2]
    assert not error.qdot[2].any() and np.isfinite(error.qdot).all()
    for w in (0, 1, 3):  # the healthy worlds: each its own one-world answer
        robot = qpik.Robot.load("arm")
        alone = batch.PositionTask(robot, "end_effector", axes="xy", gain=500.0, hard=True)
        alone.set_target(targets[w])
        expected = batch.QPController(robot, [alone, batch.DampingTask(robot)], [batch.JointVelocityLimit(robot)],
                                      dt=DT).compute_velocity()
        assert _relative(error.qdot[w], expected) <= SAME_ENGINE


def test_bad_input_is_a_typed_error_naming_the_worlds():
    robots = batch.Robot.load("arm", 3)
    with pytest.raises(InvalidInput):
        batch.Robot.load("arm", 0)
    with pytest.raises(InvalidInput):
        robots.set_q(np.zeros((2, 4)))
    bad = np.tile(robots.q[0], (3, 1))
    bad[1, 0] = np.inf
    with pytest.raises(batch.InvalidWorlds, match="worlds 1") as caught:
        robots.set_q(bad)
    assert caught.value.worlds.tolist() == [1]
    outside = np.tile(robots.q[0], (3, 1))
    outside[2, 3] = 5.0  # the ram's stroke is [0, 1] m
    with pytest.raises(batch.InvalidWorlds) as caught:
        robots.set_q(outside)
    assert caught.value.worlds.tolist() == [2]
    task = batch.PositionTask(robots, "end_effector", axes="xy", gain=10.0)
    target = np.zeros((3, 2))
    target[0, 1] = np.nan
    with pytest.raises(batch.InvalidWorlds) as caught:
        task.set_target(target)
    assert caught.value.worlds.tolist() == [0]
    frame = batch.FrameTask(robots, "end_effector")
    with pytest.raises(InvalidInput, match="reflection"):  # one for every world: no world to single out
        frame.set_target(np.zeros(3), np.diag([1.0, 1.0, -1.0]))
    velocity = np.zeros((3, 4))
    velocity[2, 1] = np.nan
    with pytest.raises(batch.InvalidWorlds) as caught:
        robots.integrate(velocity, DT)
    assert caught.value.worlds.tolist() == [2]
    with pytest.raises(InvalidInput):
        robots.integrate(np.zeros((3, 4)), -1.0)


def test_a_target_is_checked_entry_by_entry_where_all_its_entries_together_pass_the_limit():
    """The check's one pass is the norm of every world's entries: targets each far within
    TARGET_MAGNITUDE_LIMIT (1e150) whose norm is past it are taken, a strided view as an
    array; one entry past it in one world names that world."""
    from qpik.tasks.inputs import TARGET_MAGNITUDE_LIMIT

    robots = batch.Robot.load("arm", 3)
    task = batch.PositionTask(robots, "end_effector", axes="xy", gain=10.0)
    large = np.full((3, 2), 0.9 * TARGET_MAGNITUDE_LIMIT)  # norm 2.2e150
    task.set_target(large)
    np.testing.assert_array_equal(task.target, large)
    wide = np.arange(9.0).reshape(3, 3)
    task.set_target(wide[:, :2], wide[:, 1:])  # strided views of one array
    np.testing.assert_array_equal(task.target, wide[:, :2])
    large[1, 0] = 1.1 * TARGET_MAGNITUDE_LIMIT
    with pytest.raises(batch.InvalidWorlds, match="worlds 1") as caught:
        task.set_target(large)
    assert caught.value.worlds.tolist() == [1]
    np.testing.assert_array_equal(task.target, wide[:, :2])  # a refused target leaves the last one


def test_a_frames_rotations_are_read_at_the_configuration_of_their_first_read():
    """A position task binds no rotation (MuJoCo copies out only what is read); the first
    read of a frame's rotations, before or after the worlds moved, gives each world's own."""
    robots = batch.Robot.load("arm", 3)
    frame = robots.frame("end_effector")
    robots.set_q(robots.q + np.array([[0.1, 0.0, 0.0, 0.0], [0.0, -0.2, 0.1, 0.0], [0.3, 0.1, 0.0, 0.2]]))
    robots.ensure_kinematics()
    for w in range(3):
        one = robots.world(w).frame("end_effector")
        np.testing.assert_allclose(frame.positions[w], one.position, rtol=0, atol=1e-12)
        np.testing.assert_allclose(frame.rotations[w], one.rotation, rtol=0, atol=1e-12)
    robots.integrate(np.tile([1.0, -1.0, 0.5, 0.1], (3, 1)), DT)
    robots.ensure_kinematics()
    later = batch.Robot.load("arm", 3)
    later.set_q(robots.q)
    fresh = later.frame("end_effector")
    later.ensure_kinematics()
    np.testing.assert_array_equal(fresh.rotations, frame.rotations)


def test_a_task_or_limit_of_another_robot_is_refused_with_a_clear_message():
    robots, twin, one = batch.Robot.load("arm", 2), batch.Robot.load("arm", 2), qpik.Robot.load("arm")
    mine = batch.PositionTask(robots, "end_effector", axes="xy", gain=10.0)
    with pytest.raises(InvalidInput, match=r"task 'position task.*' was built on another batch.Robot instance of "
                                           r"the same model 'arm' \(its own worlds"):
        batch.QPController(robots, [mine, batch.PositionTask(twin, "end_effector", axes="xy", gain=10.0)], dt=DT)
    with pytest.raises(InvalidInput, match="limit 'JointPositionLimit' was built on a Robot of the same model 'arm', "
                                           "not on the controller's batch.Robot 'arm'"):
        batch.QPController(robots, [mine], [batch.JointPositionLimit(one)], dt=DT)
    with pytest.raises(InvalidInput, match="was built on a batch.Robot of the same model 'arm', not on the "
                                           "controller's Robot 'arm'"):
        batch.QPController(one, [mine], dt=DT)
    hexapods = batch.Robot.load("hexapod", 2)
    with pytest.raises(InvalidInput, match="built on robot 'hexapod'"):
        batch.QPController(robots, [mine, batch.PostureTask(hexapods)], dt=DT)


def test_kinematic_rollout_equals_the_loop_it_replaces_and_physics_tracks_the_command():
    rng = np.random.default_rng(6)

    def problem(robots):
        task = batch.PositionTask(robots, "end_effector", axes="xy", gain=50.0)
        task.set_target(task.target + offsets)
        limits = [batch.JointPositionLimit(robots), batch.JointVelocityLimit(robots)]
        return task, batch.QPController(robots, [task, batch.DampingTask(robots)], limits, dt=DT)

    offsets = rng.uniform(-0.1, 0.1, (N, 2))
    robots, by_hand = batch.Robot.load("arm", N), batch.Robot.load("arm", N)
    _, controller = problem(robots)
    _, reference = problem(by_hand)
    moved = []
    final = batch.rollout(controller, 50, on_step=moved.append, progress=False)
    for _ in range(50):
        by_hand.integrate(reference.compute_velocity(), DT)
    assert moved == list(range(50))
    np.testing.assert_array_equal(final, by_hand.q)

    robots = batch.Robot.load("arm", N)
    task, controller = problem(robots)
    measured = batch.rollout(controller, 250, mode="physics", progress=False)
    assert np.abs(measured - robots.q).max() < 1e-2  # the servos follow the command (rad, m)
    robots.ensure_kinematics()
    task.update()
    assert np.abs(task.error).max() < 1e-3  # and the commanded hand reached its target (m)
    with pytest.raises(InvalidInput, match="mode"):
        batch.rollout(controller, 1, mode="dynamic")
    with pytest.raises(InvalidInput, match="qpik.simulate"):
        one = qpik.Robot.load("arm")
        batch.rollout(batch.QPController(one, [batch.DampingTask(one)], dt=DT), 1)


def test_the_exports_are_the_engines_classes_and_the_shared_errors():
    import qpik.controllers
    import qpik.limits
    import qpik.tasks
    import qpik.errors

    engine = (qpik.tasks, qpik.limits, qpik.controllers)
    for name in batch.__all__:
        value = getattr(batch, name)
        owner = next((module for module in engine if name in module.__all__), None)
        if owner is not None:
            assert value is getattr(owner, name), name
    for name in ("WorldsFailed", "InvalidWorlds", "HostStepWarning"):
        assert getattr(batch, name) is getattr(qpik.errors, name)
    for gone in ("ActiveSetQP", "serial_twin"):
        assert not hasattr(batch, gone)
    every_engine_class = {name for module in engine for name in module.__all__} - {"order_limits"}
    assert every_engine_class <= set(batch.__all__), every_engine_class - set(batch.__all__)


def test_batch_import_is_light(run_without_modules):
    result = run_without_modules("import sys, qpik; from qpik import batch; print(batch.Robot.__name__); "
                                 "assert 'qpik.engine' not in sys.modules", ("scipy",))
    assert result.returncode == 0, result.stderr
    assert "Robot" in result.stdout
