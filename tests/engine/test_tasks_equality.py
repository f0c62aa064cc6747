"""The engine's EqualityTask and the robots' ``equality_rows``: MuJoCo's connect, weld, joint
and tendon rows. On one robot equal to MuJoCo's whole pipeline (``mj_forward``: the
equality rows of ``efc_pos``/``efc_J``, v = −K e written out); on 4 worlds with their own states, each world equal to its own one-world
run, whichever path (the back-end's batched rows, MuJoCo's C world by world) wrote its
rows; J against finite differences of the residual; residuals per world; bad input typed.

The models are the core tests' (tests/core/test_equality.py, loaded from there)."""

from __future__ import annotations

import importlib.util
from pathlib import Path

import mujoco
import numpy as np
import pytest

from qpik import InvalidInput, ModelError, UnknownName
from qpik import tasks as engine


def _load(name: str, path: Path):
    spec = importlib.util.spec_from_file_location(name, path)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


support = _load("tasks_support", Path(__file__).with_name("tasks_support.py"))
core = _load("core_equality", Path(__file__).parents[1] / "core" / "test_equality.py")

OPTIONS = ["", ' jacobian="sparse"']


def equality_model(option: str = "") -> mujoco.MjModel:
    """The core tests' model, its pin placed where the tip is at qpos0."""
    return core.equality_robot(option, seed=None).model


def builders(gain=2.0):
    """Tasks on every active equality, on a subset, soft, and dead-beat: (build, the
    equalities it names (None: the active ones), K once attached)."""
    return [(lambda robot: engine.EqualityTask(robot, gain=gain), None, gain),
            (lambda robot: engine.EqualityTask(robot, ["cord", "pin"], gain=gain), ["cord", "pin"], gain),
            (lambda robot: engine.EqualityTask(robot, ["glue", "couple"], hard=False, weight=3.0, gain=gain),
             ["glue", "couple"], gain),
            (lambda robot: engine.EqualityTask(robot), None, 1.0 / support.DT)]


def mujoco_rows(model, q, names, gain: float):
    """(e, J, v) of the named equalities (None: the active ones, here all but "spare") from
    MuJoCo's whole pipeline on a fresh MjData: the equality rows of efc_pos and efc_J
    (``mj_forward``, in the equalities' id order), v = −K e."""
    data = mujoco.MjData(model)
    data.qpos[:] = q
    mujoco.mj_forward(model, data)
    jacobian = np.zeros((data.nefc, model.nv))
    if mujoco.mj_isSparse(model):
        mujoco.mju_sparse2dense(jacobian, data.efc_J, data.efc_J_rownnz, data.efc_J_rowadr, data.efc_J_colind)
    else:
        jacobian[:] = data.efc_J.reshape(data.nefc, model.nv)
    ids = [model.equality(name).id for name in (core.NAMES if names is None else names)]
    rows = (data.efc_type == mujoco.mjtConstraint.mjCNSTR_EQUALITY) & np.isin(data.efc_id, ids)
    assert rows.sum() == sum(core.ROWS[model.equality(i).name] for i in ids)
    return data.efc_pos[rows], jacobian[rows], -gain * data.efc_pos[rows]


@pytest.mark.parametrize("option", OPTIONS)
def test_one_robot_equals_mujocos_rows(option):
    model = equality_model(option)
    q = support.displaced(model, model.qpos0, seed=1, scale=0.05)
    for build, names, gain in builders():
        # The same C calls on the same q (the task's on a pipeline pared to the equality
        # rows): equal to rounding, 1e-12 relative.
        support.assert_rows(build(support.one_robot(model, q)), mujoco_rows(model, q, names, gain))
    robot = support.one_robot(model, q)
    task = engine.EqualityTask(robot, gain=2.0)
    error, jacobian, velocity = support.measured(task)
    assert task.equalities == tuple(robot.equality_id(n) for n in core.NAMES) and task.hard  # "spare" is inactive
    reference_error, reference_jacobian = core.mujoco_equality_rows(robot)
    np.testing.assert_allclose(error, reference_error, atol=1e-15, rtol=0)  # the same C calls
    np.testing.assert_allclose(jacobian, reference_jacobian, atol=1e-15, rtol=0)
    np.testing.assert_array_equal(velocity, -2.0 * error)
    assert np.all(np.abs(error) > 1e-6)  # every row violated here


@pytest.mark.parametrize("option", OPTIONS)
def test_each_of_four_worlds_is_its_own_one_world_run(option):
    robots = support.worlds(equality_model(option), n=4, seed=2, scale=0.05)
    for build, _, _ in builders():
        support.assert_each_world(robots, lambda robot, w, build=build: build(robot))


def test_the_hexapods_loops_on_four_worlds():
    """Six connect equalities (the back-end's batched rows): each world its own run, and
    each row the difference of the two sites' positions and Jacobians (MuJoCo's)."""
    robots = support.worlds("hexapod", n=4, seed=3, scale=0.02)
    task = support.assert_each_world(robots, lambda robot, w: engine.EqualityTask(robot))
    m = robots.model
    for w in range(robots.n):
        robot = support.world_robot(robots, w)
        jac1, jac2 = np.zeros((3, m.nv)), np.zeros((3, m.nv))
        for k, eq in enumerate(task.equalities):
            site1, site2 = m.eq_obj1id[eq], m.eq_obj2id[eq]
            mujoco.mj_jacSite(m, robot.data, jac1, None, site1)
            mujoco.mj_jacSite(m, robot.data, jac2, None, site2)
            gap = robot.data.site_xpos[site1] - robot.data.site_xpos[site2]
            # O(1) positions and Jacobians, formed from cdof across worlds: rounding ~1e-16.
            np.testing.assert_allclose(task.error[w, 3 * k:3 * k + 3], gap, rtol=0, atol=1e-15)
            np.testing.assert_allclose(task.jacobian[w, 3 * k:3 * k + 3], jac1 - jac2, rtol=0, atol=1e-14)


def test_each_type_takes_its_path_on_the_cpu_back_end():
    """connect and joint: the back-end, batched; weld and tendon: MuJoCo's C, world by world."""
    robots = support.worlds(equality_model(), n=4, seed=4, scale=0.05)
    asked, batched = [], robots.backend.equality_rows
    robots.backend.equality_rows = lambda ids: asked.append(list(ids)) or batched(ids)
    ids = tuple(robots.equality_id(n) for n in core.NAMES)
    residual, jacobian = robots.equality_rows(ids)
    assert asked[-1] == [robots.equality_id("pin"), robots.equality_id("couple")]
    for w in range(robots.n):
        alone = support.world_robot(robots, w)
        reference_residual, reference_jacobian = alone.equality_rows(ids)
        assert support.relative(residual[w], reference_residual[0]) <= support.WORLDS
        assert support.relative(jacobian[w], reference_jacobian[0]) <= support.WORLDS
    assert residual.shape == (4, sum(core.ROWS.values())) and jacobian.shape == (4, residual.shape[1], robots.nv)


@pytest.mark.parametrize("option", OPTIONS)
def test_jacobian_is_the_derivative_of_the_residual(option):
    model = equality_model(option)
    robot = support.one_robot(model, support.displaced(model, model.qpos0, seed=5, scale=0.05))
    support.assert_jacobian_is_the_derivative(engine.EqualityTask(robot), sign=1.0)


def test_residuals_are_per_world():
    robots = support.worlds(equality_model(), n=4, seed=6, scale=0.05)
    task = engine.EqualityTask(robots, gain=2.0)
    residuals, largest = task.residuals(), task.max_residual()
    assert residuals.shape == (4, len(core.NAMES)) and largest.shape == (4,)
    for w in range(robots.n):
        error, _, _ = mujoco_rows(robots.model, robots.q[w], None, 2.0)
        starts = np.cumsum([0] + [core.ROWS[name] for name in core.NAMES])
        reference = np.array([np.linalg.norm(error[a:b]) for a, b in zip(starts[:-1], starts[1:])])
        # Norms of the same O(1e-2) residuals (MuJoCo's pipeline on the world's q), summed
        # in another order: 1e-14 relative (the batch forms connect and joint rows in NumPy).
        np.testing.assert_allclose(residuals[w], reference, rtol=1e-14, atol=0)
        assert largest[w] == pytest.approx(reference.max(), rel=1e-14)
    one = engine.EqualityTask(support.world_robot(robots, 1), gain=2.0)
    np.testing.assert_allclose(one.residuals(), residuals[1], rtol=1e-14)
    assert np.ndim(one.max_residual()) == 0


def test_a_weld_that_acts_on_no_dof_is_left_out_by_default_and_refused_by_name():
    robots = support.worlds(mujoco.MjModel.from_xml_string(core.STATIC_WELD), n=4, seed=7)
    task = engine.EqualityTask(robots)
    assert task.equalities == (robots.equality_id("hinge"),) and task.dim == 1
    with pytest.raises(ModelError, match=r"'glued'.*no dof"):
        engine.EqualityTask(robots, ["glued", "hinge"])


def test_an_active_tendon_equality_left_out_keeps_the_row_count():
    """A task on the slide's joint equality only, a tendon equality active beside it: the
    tendons are computed before every make, on one robot and in every world."""
    robots = support.worlds(mujoco.MjModel.from_xml_string(core.TENDON_AND_JOINT), n=4, seed=8)
    support.assert_each_world(robots, lambda robot, w: engine.EqualityTask(robot, ["slide"], gain=50.0))


def test_bad_input_is_a_typed_error():
    robot = support.one_robot(equality_model(), support.displaced(equality_model(), equality_model().qpos0, seed=9))
    with pytest.raises(UnknownName, match=r"unknown equality 'glu'.*'glue'"):
        engine.EqualityTask(robot, ["glu"])
    with pytest.raises(ModelError, match="inactive"):
        engine.EqualityTask(robot, ["spare"])
    with pytest.raises(InvalidInput, match="list"):
        engine.EqualityTask(robot, "pin")
    with pytest.raises(InvalidInput, match="twice"):
        engine.EqualityTask(robot, ["pin", "pin"])
    with pytest.raises(ModelError, match="no active equality"):
        engine.EqualityTask(support.worlds("arm", n=2))
    for gain in ("fast", [1.0, 2.0], np.nan, -1.0, np.inf):
        with pytest.raises(InvalidInput, match="gain"):
            engine.EqualityTask(robot, gain=gain)
    task = engine.EqualityTask(robot)
    assert task.needs_period and task.dead_beat
    task.attach(0.01)
    assert task.gain == pytest.approx(100.0) and not task.needs_period
    robot.data.eq_active[robot.equality_id("glue")] = 0
    with pytest.raises(ModelError, match="changed"):
        task.update()
