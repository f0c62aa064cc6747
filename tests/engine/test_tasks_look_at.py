"""The engine's LookAtTask and AxisAlignTask (written over N worlds with ``measure_rows``):
on one robot equal to the serial classes; on 4 worlds with their own states and targets,
each world equal to its own one-world run; J against finite differences of what they
measure, on a fixed and a free-floating chain; bad input is a typed error naming the worlds.

The chains are the serial tests' (tests/core/test_peer_tasks.py, loaded from there)."""

from __future__ import annotations

import importlib.util
from pathlib import Path

import numpy as np
import pytest

from qpik import InvalidInput, tasks as serial
from qpik.engine import tasks as engine
from qpik.errors import InvalidWorlds


def _load(name: str, path: Path):
    spec = importlib.util.spec_from_file_location(name, path)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


support = _load("tasks_support", Path(__file__).with_name("tasks_support.py"))
core = _load("core_peer_tasks", Path(__file__).parents[1] / "core" / "test_peer_tasks.py")

# Central differences of unit vectors on a 1 m chain (the serial tests' bound): 1e-7.
FD_TOLERANCE = 1e-7


def chain(free_base: bool):
    robot = core.generated_chain(free_base=free_base)
    return robot.model, robot.q.copy()


def look_at(T, robot, t, frame="tip"):
    task = T.LookAtTask(robot, frame, axis=(1.0, 0.5, 0.2), gain=10.0, lm_damping=0.1)
    task.set_target(t["point"])
    return task


def look_at_dead_beat(T, robot, t, frame="tip"):
    task = T.LookAtTask(robot, frame, weight=[1.0, 2.0, 3.0])
    task.set_target(t["point"] * 2.0)
    return task


def axis_align(T, robot, t, frame="tip"):
    task = T.AxisAlignTask(robot, frame, axis=(0.0, 1.0, 1.0), gain=[1.0, 2.0, 3.0])
    task.set_target(t["direction"])
    return task


def axis_align_dead_beat(T, robot, t, frame="tip"):
    return T.AxisAlignTask(robot, frame, priority=1)  # met at construction


CASES = [look_at, look_at_dead_beat, axis_align, axis_align_dead_beat]


def targets(rng, n: int) -> dict:
    return dict(point=rng.normal(scale=0.5, size=(n, 3)), direction=rng.normal(size=(n, 3)))


@pytest.mark.parametrize("free_base", [False, True])
def test_one_robot_equals_the_serial_class(free_base):
    model, q = chain(free_base)
    t = {k: v[0] for k, v in targets(np.random.default_rng(1), 1).items()}
    for case in CASES:
        support.assert_same_rows(case(engine, support.one_robot(model, q), t), case(serial, support.one_robot(model, q), t))


def test_one_robot_equals_the_serial_class_on_the_jaco(jaco_path):
    robot = support.one_robot(jaco_path)
    q = support.displaced(robot.model, robot.q, seed=2)
    t = {k: v[0] for k, v in targets(np.random.default_rng(3), 1).items()}
    for case in CASES:
        support.assert_same_rows(case(engine, support.one_robot(jaco_path, q), t, "wristsite"),
                                 case(serial, support.one_robot(jaco_path, q), t, "wristsite"))


@pytest.mark.parametrize("free_base", [False, True])
def test_each_of_four_worlds_is_its_own_one_world_run(free_base):
    model, q = chain(free_base)
    robots = support.worlds(model, n=4, seed=4, scale=0.3)
    t = targets(np.random.default_rng(5), robots.n)
    for case in CASES:
        support.assert_each_world(robots, lambda robot, w, case=case: case(
            engine, robot, t if w is None else {k: v[w] for k, v in t.items()}))


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
    look, align = look_at(engine, robots, t), axis_align(engine, robots, t)
    for w in range(robots.n):
        robot = support.world_robot(robots, w)
        frame = robot.frame("tip")
        sight = frame.rotation.T @ (t["point"][w] - frame.position)
        assert support.relative(look.measured()[w], sight / np.linalg.norm(sight)) <= support.SERIAL
        direction = t["direction"][w] / np.linalg.norm(t["direction"][w])
        assert support.relative(align.measured()[w], frame.rotation.T @ direction) <= support.SERIAL
        assert support.relative(align.direction[w], direction) <= support.SERIAL


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
