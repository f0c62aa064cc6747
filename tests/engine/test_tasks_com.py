"""The engine's ComTask (the whole model's CoM and a subtree's, masked): on one robot equal
to its formula written out on MuJoCo's own CoM and CoM Jacobian (``subtree_com``,
``mj_jacSubtreeCom``); on 4 worlds with their own states and targets, each world equal to
its own one-world run; J against finite differences; the CoM against the bodies'
mass-weighted mean; bad input is a typed error naming the worlds."""

from __future__ import annotations

import importlib.util
from pathlib import Path

import mujoco
import numpy as np
import pytest

from qpik import InvalidInput, ModelError, UnknownName
from qpik import tasks as engine
from qpik.errors import InvalidWorlds


def _load(name: str):
    spec = importlib.util.spec_from_file_location(name, Path(__file__).with_name(f"{name}.py"))
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


support, references = _load("tasks_support"), _load("references")

SUBTREES = {"arm": "link2", "hexapod": "platform", "jaco": "b_3", "humanoid": "lfemur", "pusher": "r_upper_arm_link"}


def whole(robot, t):
    task = engine.ComTask(robot, gain=5.0, weight=[1.0, 2.0, 3.0], lm_damping=0.2)
    task.set_target(task.target + t[..., :3], t[..., 3:])
    return task


def subtree_xz(robot, t, name):
    task = engine.ComTask(robot, subtree=SUBTREES[name], axes="xz")  # dead-beat
    task.set_target(task.target + t[..., :2], t[..., 3:5])
    return task


def cases(name):
    return [whole, lambda robot, t: subtree_xz(robot, t, name)]


def com_rows(model, q, body: int, rows: list[int], target_offset, rate, gain):
    """e = c_d − c on the kept rows (c_d: the CoM at q plus the offset), J = MuJoCo's
    ∂c/∂q rows, v = K e + ċ_d."""
    data = references.mujoco_data(model, q)
    jacobian = np.zeros((3, model.nv))
    mujoco.mj_jacSubtreeCom(model, data, jacobian, body)
    com = data.subtree_com[body]
    e = com[rows] + target_offset - com[rows]
    return e, jacobian[rows], gain * e + rate


@pytest.mark.parametrize("name", sorted(SUBTREES))
def test_one_robot_equals_mujocos_com_rows(model_path, name):
    path = model_path(name)
    start = support.one_robot(path)
    q = support.displaced(start.model, start.q, seed=1)
    t = np.random.default_rng(2).normal(scale=0.05, size=6)
    robot = support.one_robot(path, q)
    support.assert_rows(whole(robot, t), com_rows(robot.model, q, 0, [0, 1, 2], t[:3], t[3:], 5.0))
    robot = support.one_robot(path, q)
    body = robot.model.body(SUBTREES[name]).id
    support.assert_rows(subtree_xz(robot, t, name), com_rows(robot.model, q, body, [0, 2], t[:2], t[3:5],
                                                             1.0 / support.DT))


@pytest.mark.parametrize("name", ["arm", "hexapod", "humanoid"])
def test_each_of_four_worlds_is_its_own_one_world_run(model_path, name):
    robots = support.worlds(model_path(name), n=4, seed=3)
    t = np.random.default_rng(4).normal(scale=0.05, size=(robots.n, 6))
    for case in cases(name):
        # Targets relative to each world's own CoM: the batch task's target is (N, dim).
        support.assert_each_world(robots, lambda robot, w, case=case: case(robot, t if w is None else t[w]))


@pytest.mark.parametrize("name", ["arm", "hexapod", "jaco", "humanoid"])
def test_jacobians_are_the_derivatives_of_the_com(model_path, name):
    robot = support.one_robot(model_path(name))
    robot.q[:] = support.displaced(robot.model, robot.q, seed=5)
    robot.update_kinematics()
    away = engine.ComTask(robot)
    away.set_target(away.target + 0.05)  # exact away from the target too
    support.assert_jacobian_is_the_derivative(away)
    support.assert_jacobian_is_the_derivative(engine.ComTask(robot, subtree=SUBTREES[name], axes="xz"))


def test_the_com_is_the_mass_weighted_mean_of_the_bodies(humanoid_path):
    robots = support.worlds(humanoid_path, n=4, seed=6)
    task = engine.ComTask(robots)
    model = robots.model
    for w in range(robots.n):
        data = mujoco.MjData(model)
        data.qpos[:] = robots.q[w]
        mujoco.mj_kinematics(model, data)
        mean = (model.body_mass[:, None] * data.xipos).sum(axis=0) / model.body_mass.sum()
        # Sums of ~60 products of O(1) masses and positions in another order: 1e-12 m.
        np.testing.assert_allclose(task.target[w], mean, rtol=0, atol=1e-12)
        np.testing.assert_allclose(task.measured()[w], mean, rtol=0, atol=1e-12)


def test_bad_input_is_a_typed_error():
    robots = support.worlds("arm", n=4)
    task = engine.ComTask(robots, axes="xy")
    targets = np.array(task.targets)
    targets[2] = np.inf
    with pytest.raises(InvalidWorlds, match="worlds 2") as caught:
        task.set_target(targets)
    np.testing.assert_array_equal(caught.value.worlds, [2])
    velocities = np.zeros((4, 2))
    velocities[0, 0] = np.nan
    with pytest.raises(InvalidWorlds, match="worlds 0"):
        task.set_target(task.targets[0], velocities)
    with pytest.raises(InvalidInput, match="shape"):
        task.set_target(np.zeros(3))  # the mask keeps two rows
    with pytest.raises(UnknownName, match="link2"):
        engine.ComTask(robots, subtree="link22")
    massless = mujoco.MjModel.from_xml_string(
        '<mujoco><worldbody><body name="marker" pos="1 0 0"/><body><joint/><geom size=".1"/></body>'
        '</worldbody></mujoco>')
    with pytest.raises(ModelError, match="no mass"):
        engine.ComTask(support.one_robot(massless), subtree="marker")
    with pytest.raises(InvalidInput, match="NaN"):
        engine.ComTask(support.one_robot("arm")).set_target([0.0, np.nan, 0.0])
