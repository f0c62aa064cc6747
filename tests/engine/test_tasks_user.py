"""A task written as a mink user writes one (``dim``, ``compute_error``, ``compute_jacobian``)
on the engine: on one robot the rows the base class makes of its methods equal the
distance's rows written out on MuJoCo's site position and Jacobian (v = K e, the
dead-beat gain 1/Δt once attached); on 4 worlds,
evaluated world by world, each world equal to its own one-world run; written over the
world axis (``vectorized = True``), the same numbers; J against finite differences;
methods that return the wrong shape, NaN or no numbers are told (InvalidInput)."""

from __future__ import annotations

import importlib.util
from pathlib import Path

import mujoco
import numpy as np
import pytest

from qpik import InvalidInput
from qpik import tasks as engine
from qpik.errors import InvalidWorlds

def _load(name: str):
    spec = importlib.util.spec_from_file_location(name, Path(__file__).with_name(f"{name}.py"))
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


support, references = _load("tasks_support"), _load("references")

CENTRE = np.array([0.1, -0.2, 0.05])


class TipDistance:
    """1-D: the distance of the arm's end effector from ``CENTRE`` (x = ‖p − c‖, e = x_d − x),
    on one world's MjData, as a mink user writes it."""

    dim = 1

    def __init__(self, robot, **options):
        super().__init__(robot, **options)
        self.site = robot.model.site("end_effector").id

    def compute_error(self, robot):
        return self.target - np.linalg.norm(robot.data.site_xpos[self.site] - CENTRE)

    def compute_jacobian(self, robot):
        offset = robot.data.site_xpos[self.site] - CENTRE
        jacp = np.zeros((3, robot.nv))
        mujoco.mj_jacSite(robot.model, robot.data, jacp, None, self.site)
        return (offset / np.linalg.norm(offset)) @ jacp[None]


class EngineTipDistance(TipDistance, engine.Task):
    pass


class VectorizedTipDistance(engine.Task):
    """The same rows written over the world axis with the robots' engine interface."""

    dim = 1
    vectorized = True

    def __init__(self, robot, **options):
        super().__init__(robot, **options)
        self.frame = robot.frame("end_effector")
        self.jacp = np.zeros((robot.n, 3, robot.nv))

    def compute_error(self, robot):
        target = np.reshape(self.target, (robot.n, self.dim))  # (N, 1); (1,) on one robot
        return target - np.linalg.norm(self.frame.positions - CENTRE, axis=1, keepdims=True)

    def compute_jacobian(self, robot):
        self.frame.jacobians(self.jacp)
        offset = self.frame.positions - CENTRE
        unit = offset / np.linalg.norm(offset, axis=1, keepdims=True)
        return np.matmul(unit[:, None, :], self.jacp)


def build(cls, robot, target, gain=20.0):
    task = cls(robot, gain=gain, weight=2.0, lm_damping=0.1)
    task.set_target(target)
    return task


def distances(robots) -> np.ndarray:
    """(N, 1) each world's present distance."""
    return np.linalg.norm(robots.frame("end_effector").positions - CENTRE, axis=1, keepdims=True)


def test_one_robot_gives_the_rows_written_out():
    model = support.one_robot("arm").model
    q = support.displaced(model, support.one_robot("arm").q, seed=1)
    p, _, Jp, _ = references.frame_state(model, q, "end_effector")
    offset = p - CENTRE
    e = np.array([0.3 - np.linalg.norm(offset)])
    J = (offset / np.linalg.norm(offset))[None] @ Jp
    for gain, K in ((20.0, 20.0), (None, 1.0 / support.DT)):
        support.assert_rows(build(EngineTipDistance, support.one_robot("arm", q), [0.3], gain), (e, J, K * e))


def test_each_of_four_worlds_is_its_own_one_world_run():
    robots = support.worlds("arm", n=4, seed=2)
    targets = distances(robots) + np.random.default_rng(3).normal(scale=0.02, size=(4, 1))
    task = support.assert_each_world(robots, lambda robot, w: build(
        EngineTipDistance, robot, targets if w is None else targets[w]))
    assert task.error.shape == (4, 1) and task.jacobian.shape == (4, 1, 4)


def test_a_vectorized_task_gives_the_same_numbers():
    robots = support.worlds("arm", n=4, seed=4)
    targets = distances(robots) + np.random.default_rng(5).normal(scale=0.02, size=(4, 1))
    by_world = support.measured(build(EngineTipDistance, robots, targets))
    at_once = support.measured(build(VectorizedTipDistance, robots, targets))
    for a, b in zip(at_once, by_world):
        assert support.relative(a, b) <= support.WORLDS  # the same formulas, stacked
    # Each world of the vectorized task is its own one-world run (on one robot the
    # vectorized task returns (1, dim), (1, dim, nv)).
    support.assert_each_world(robots, lambda robot, w: build(VectorizedTipDistance, robot,
                                                             targets if w is None else targets[w]))


def test_the_jacobian_is_the_derivative_of_what_the_error_measures():
    robot = support.one_robot("arm", support.displaced(support.one_robot("arm").model, support.one_robot("arm").q, 6))
    task = build(EngineTipDistance, robot, [0.3])
    support.assert_jacobian_is_the_derivative(task)


class Lying(engine.Task):
    dim = 2
    answer = None

    def compute_error(self, robot):
        return type(self).answer

    def compute_jacobian(self, robot):
        return np.zeros((2, robot.nv))


class LyingVectorized(Lying):
    vectorized = True

    def compute_jacobian(self, robot):
        return np.zeros((robot.n, 2, robot.nv))


def wrong_width(good):
    return np.zeros(good.shape[:-1] + (3,))


def with_nan(good):
    bad = good.copy()
    bad.flat[-1] = np.nan
    return bad


def words(good):
    return np.full(good.shape, "a", dtype=object)


@pytest.mark.parametrize("spoil, message", [(wrong_width, "must return shape"), (with_nan, "NaN or inf"),
                                            (words, "must return numbers")])
def test_bad_returns_are_told(spoil, message):
    robots = support.worlds("arm", n=4)
    for cls, robot, good in ((Lying, support.one_robot("arm"), np.zeros(2)), (Lying, robots, np.zeros(2)),
                             (LyingVectorized, robots, np.zeros((4, 2)))):
        cls.answer = good
        task = cls(robot, gain=1.0)
        task.update()  # the good answer passes
        cls.answer = spoil(good)
        with pytest.raises(InvalidInput, match=message):
            task.update()


def test_the_contract_is_checked_when_built():
    robots = support.worlds("arm", n=2)

    class NoJacobian(engine.Task):
        dim = 1

        def compute_error(self, robot):
            return np.zeros(1)

    class NoDim(engine.Task):
        compute_error = compute_jacobian = None

    with pytest.raises(InvalidInput, match="compute_jacobian"):
        NoJacobian(robots)
    with pytest.raises(InvalidInput, match="dim"):
        Lying(robots, dim=0)
    with pytest.raises(InvalidInput):
        NoDim(robots)
    task = build(EngineTipDistance, robots, [0.3])
    with pytest.raises(InvalidWorlds, match="worlds 1"):
        task.set_target([[0.3], [np.nan]])
    with pytest.raises(InvalidInput, match="gain"):
        EngineTipDistance(robots, gain=-1.0)
