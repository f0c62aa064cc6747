"""The engine's LookAtTask and AxisAlignTask (written over N worlds with ``measure_rows``):
on one robot equal to their formulas written out on MuJoCo's own poses and Jacobians; on
4 worlds with their own states and targets,
each world equal to its own one-world run; J against finite differences of what they
measure, on a fixed and a free-floating chain; bad input is a typed error naming the worlds.

The chains are the core tests' (tests/core/test_peer_tasks.py, loaded from there)."""

from __future__ import annotations

import importlib.util
from pathlib import Path

import numpy as np
import pytest

from qpik import InvalidInput
from qpik import tasks as engine
from qpik.errors import InvalidWorlds


def _load(name: str, path: Path):
    spec = importlib.util.spec_from_file_location(name, path)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


support = _load("tasks_support", Path(__file__).with_name("tasks_support.py"))
references = _load("references", Path(__file__).with_name("references.py"))
core = _load("core_peer_tasks", Path(__file__).parents[1] / "core" / "test_peer_tasks.py")

# Central differences of unit vectors on a 1 m chain (the core tests' bound): 1e-7.
FD_TOLERANCE = 1e-7


def chain(free_base: bool):
    robot = core.generated_chain(free_base=free_base)
    return robot.model, robot.q.copy()


def look_at(robot, t, frame="tip"):
    task = engine.LookAtTask(robot, frame, axis=(1.0, 0.5, 0.2), gain=10.0, lm_damping=0.1)
    task.set_target(t["point"])
    return task


def look_at_dead_beat(robot, t, frame="tip"):
    task = engine.LookAtTask(robot, frame, weight=[1.0, 2.0, 3.0])
    task.set_target(t["point"] * 2.0)
    return task


def axis_align(robot, t, frame="tip"):
    task = engine.AxisAlignTask(robot, frame, axis=(0.0, 1.0, 1.0), gain=[1.0, 2.0, 3.0])
    task.set_target(t["direction"])
    return task


def axis_align_dead_beat(robot, t, frame="tip"):
    return engine.AxisAlignTask(robot, frame, priority=1)  # met at construction


CASES = [look_at, look_at_dead_beat, axis_align, axis_align_dead_beat]


def targets(rng, n: int) -> dict:
    return dict(point=rng.normal(scale=0.5, size=(n, 3)), direction=rng.normal(size=(n, 3)))


def _unit(v) -> np.ndarray:
    v = np.asarray(v, dtype=float)
    return v / np.linalg.norm(v)


def look_at_rows(model, q, frame, axis, point, gain):
    """r = Rᵀ(p* − p), d = r/‖r‖: e = a − d, J = ∂d/∂q = −(I − ddᵀ)(RᵀJ_p − [r]× RᵀJ_ω)/‖r‖,
    v = K e (MuJoCo's pose and Jacobians at q)."""
    p, R, Jp, Jr = references.frame_state(model, q, frame)
    r = R.T @ (np.asarray(point) - p)
    norm = np.linalg.norm(r)
    d = r / norm
    e = _unit(axis) - d
    J = -(np.eye(3) - np.outer(d, d)) @ (R.T @ Jp - references.skew(r) @ R.T @ Jr) / norm
    return e, J, np.asarray(gain) * e


def axis_align_rows(model, q, frame, axis, direction, gain):
    """x = Rᵀt: e = a − x, J = ∂x/∂q = [x]× RᵀJ_ω, v = K e."""
    _, R, _, Jr = references.frame_state(model, q, frame)
    x = R.T @ _unit(direction)
    e = _unit(axis) - x
    return e, references.skew(x) @ R.T @ Jr, np.asarray(gain) * e


def expected_rows(case, model, q, t, frame="tip"):
    """The case's rows written out (dead-beat gains 1/Δt; the default axis +z)."""
    dead_beat = 1.0 / support.DT
    if case is look_at:
        return look_at_rows(model, q, frame, (1.0, 0.5, 0.2), t["point"], 10.0)
    if case is look_at_dead_beat:
        return look_at_rows(model, q, frame, (0.0, 0.0, 1.0), t["point"] * 2.0, dead_beat)
    if case is axis_align:
        return axis_align_rows(model, q, frame, (0.0, 1.0, 1.0), t["direction"], [1.0, 2.0, 3.0])
    _, R, _, _ = references.frame_state(model, q, frame)
    return axis_align_rows(model, q, frame, (0.0, 0.0, 1.0), R[:, 2], dead_beat)  # its own z axis: met


@pytest.mark.parametrize("free_base", [False, True])
def test_one_robot_equals_the_formulas_on_mujocos_kinematics(free_base):
    model, q = chain(free_base)
    t = {k: v[0] for k, v in targets(np.random.default_rng(1), 1).items()}
    for case in CASES:
        support.assert_rows(case(support.one_robot(model, q), t), expected_rows(case, model, q, t))


def test_one_robot_equals_the_formulas_on_the_jaco(jaco_path):
    robot = support.one_robot(jaco_path)
    q = support.displaced(robot.model, robot.q, seed=2)
    t = {k: v[0] for k, v in targets(np.random.default_rng(3), 1).items()}
    for case in CASES:
        support.assert_rows(case(support.one_robot(jaco_path, q), t, "wristsite"),
                            expected_rows(case, robot.model, q, t, "wristsite"))


@pytest.mark.parametrize("free_base", [False, True])
def test_each_of_four_worlds_is_its_own_one_world_run(free_base):
    model, q = chain(free_base)
    robots = support.worlds(model, n=4, seed=4, scale=0.3)
    t = targets(np.random.default_rng(5), robots.n)
    for case in CASES:
        support.assert_each_world(robots, lambda robot, w, case=case: case(
            robot, t if w is None else {k: v[w] for k, v in t.items()}))


@pytest.mark.parametrize("free_base", [False, True])
def test_jacobians_are_the_derivatives_of_what_they_measure(free_base):
    model, q = chain(free_base)
    robot = support.one_robot(model, q)
    look = engine.LookAtTask(robot, "tip", axis=(1.0, 0.5, 0.2), gain=10.0)
    look.set_target([0.4, -0.3, 0.5])
    align = engine.AxisAlignTask(robot, "tip", axis=(0.0, 1.0, 1.0), gain=10.0)
    align.set_target([0.2, -1.0, 0.3])
    for task in (look, align):
        task.update()
        jacobian = task.jacobian.copy()
        fd = support.finite_differences(robot, task.measured)
        np.testing.assert_allclose(jacobian, fd, rtol=0, atol=FD_TOLERANCE)
        np.testing.assert_allclose(task.error, task.axis - task.measured(), rtol=0, atol=0)
    # Rank 2: the roll about the axis is free.
    assert np.linalg.matrix_rank(align.jacobian, tol=1e-9) == 2


def test_the_worlds_measure_their_own_directions():
    model, q = chain(False)
    robots = support.worlds(model, n=4, seed=6)
    t = targets(np.random.default_rng(7), robots.n)
    look, align = look_at(robots, t), axis_align(robots, t)
    for w in range(robots.n):
        robot = support.world_robot(robots, w)
        frame = robot.frame("tip")
        sight = frame.rotation.T @ (t["point"][w] - frame.position)
        assert support.relative(look.measured()[w], sight / np.linalg.norm(sight)) <= support.REFERENCE
        direction = t["direction"][w] / np.linalg.norm(t["direction"][w])
        assert support.relative(align.measured()[w], frame.rotation.T @ direction) <= support.REFERENCE
        assert support.relative(align.direction[w], direction) <= support.REFERENCE


def test_bad_input_is_a_typed_error():
    model, q = chain(False)
    robots = support.worlds(model, n=4)
    look, align = engine.LookAtTask(robots, "tip"), engine.AxisAlignTask(robots, "tip")
    directions = np.ones((4, 3))
    directions[2] = 0.0
    with pytest.raises(InvalidWorlds, match="worlds 2") as caught:
        align.set_target(directions)
    np.testing.assert_array_equal(caught.value.worlds, [2])
    points = np.ones((4, 3))
    points[[0, 3], 1] = np.nan
    with pytest.raises(InvalidWorlds, match="worlds 0, 3"):
        look.set_target(points)
    with pytest.raises(InvalidInput, match="velocity"):
        look.set_target(np.ones(3), velocity=np.zeros(3))
    with pytest.raises(InvalidInput, match="velocity"):
        align.set_target(np.ones(3), velocity=np.zeros(3))
    with pytest.raises(InvalidInput, match="non-zero"):
        engine.LookAtTask(robots, "tip", axis=(0.0, 0.0, 0.0))
    one = support.one_robot(model, q)
    with pytest.raises(InvalidInput, match="non-zero"):
        engine.AxisAlignTask(one, "tip").set_target([0.0, 0.0, 0.0])
    with pytest.raises(InvalidInput, match="NaN"):
        engine.LookAtTask(one, "tip").set_target([0.0, np.nan, 0.0])
