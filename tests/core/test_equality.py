"""EqualityTask: MuJoCo's connect, weld, joint and tendon equalities as task rows, hard or soft.

References: MuJoCo's full constraint pipeline (``mj_forward``), finite differences of the
residual, the site Jacobians of a ``connect`` written out, and QP rollouts that must hold
every equality."""

from __future__ import annotations

import mujoco
import numpy as np
import pytest

from qpik import DampingTask, EqualityTask, InvalidInput, ModelError, PostureTask, QPController, Robot, UnknownName

# A 4-hinge arm whose tip is pinned to the world (connect), a free box welded to the arm's
# third link, and a 3-hinge chain whose joints are coupled (joint) and whose spatial
# tendon has a prescribed length (tendon: 0.02 longer than at qpos0, so violated there).
# p1's range (qpos0 lies outside) and friction loss give limit and friction rows in MuJoCo's
# own pipeline, which the task leaves out.
EQUALITIES = """
<mujoco model="equalities">
  <compiler angle="radian"/>
  <option{option}/>
  <worldbody>
    <site name="pin" pos="0.45 0.1 0.35"/>
    <site name="anchor" pos="0 0.9 0.1"/>
    <body name="l1">
      <joint name="a1" axis="0 0 1" range="-2 2"/>
      <geom type="capsule" fromto="0 0 0 0 0 0.2" size="0.02"/>
      <body name="l2" pos="0 0 0.2">
        <joint name="a2" axis="0 1 0" range="-2 2"/>
        <geom type="capsule" fromto="0 0 0 0.2 0 0" size="0.02"/>
        <body name="l3" pos="0.2 0 0">
          <joint name="a3" axis="0 1 0"/>
          <geom type="capsule" fromto="0 0 0 0.2 0 0" size="0.02"/>
          <body name="l4" pos="0.2 0 0">
            <joint name="a4" axis="1 0 0"/>
            <geom type="capsule" fromto="0 0 0 0.05 0.1 0.15" size="0.02"/>
            <site name="tip" pos="0.05 0.1 0.15"/>
          </body>
        </body>
      </body>
    </body>
    <body name="box" pos="0.3 0.1 0.2">
      <freejoint name="box"/>
      <geom type="box" size="0.03 0.03 0.03"/>
    </body>
    <body name="c1" pos="0 0.5 0">
      <joint name="p1" axis="0 0 1" range="0.5 1" frictionloss="0.1"/>
      <geom type="capsule" fromto="0 0 0 0.2 0 0" size="0.02"/>
      <body name="c2" pos="0.2 0 0">
        <joint name="p2" axis="0 0 1"/>
        <geom type="capsule" fromto="0 0 0 0.2 0 0" size="0.02"/>
        <body name="c3" pos="0.2 0 0">
          <joint name="p3" axis="0 1 0"/>
          <geom type="capsule" fromto="0 0 0 0.1 0 0.1" size="0.02"/>
          <site name="end" pos="0.1 0 0.1"/>
        </body>
      </body>
    </body>
  </worldbody>
  <tendon>
    <spatial name="cord"><site site="anchor"/><site site="end"/></spatial>
  </tendon>
  <equality>
    <connect name="pin" site1="tip" site2="pin"/>
    <weld name="glue" body1="box" body2="l3"/>
    <joint name="couple" joint1="p2" joint2="p1" polycoef="0 -0.5 0.3 0 0"/>
    <tendon name="cord" tendon1="cord" polycoef="0.02 0 0 0 0"/>
    <weld name="spare" body1="c3" active="false"/>
  </equality>
</mujoco>
"""
NAMES = ("pin", "glue", "couple", "cord")
ROWS = {"pin": 3, "glue": 6, "couple": 1, "cord": 1}


def equality_robot(option: str = "", seed: int | None = 0) -> Robot:
    model = mujoco.MjModel.from_xml_string(EQUALITIES.format(option=option))
    robot = Robot(model, allow_outside_limits=True)  # moved away at random: p1 may leave its range
    # Place the pin where the tip is at qpos0, then move away: every equality is violated.
    robot.update_kinematics()
    model.site_pos[model.site("pin").id] = robot.data.site("tip").xpos
    if seed is not None:
        rng = np.random.default_rng(seed)
        mujoco.mj_integratePos(model, robot.q, rng.normal(scale=0.05, size=model.nv), 1.0)
    robot.update_kinematics()
    return robot


def mujoco_equality_rows(robot: Robot) -> tuple[np.ndarray, np.ndarray]:
    """The equality rows of MuJoCo's whole pipeline (with contacts and limits) on a copy."""
    data = mujoco.MjData(robot.model)
    data.qpos[:] = robot.q
    mujoco.mj_forward(robot.model, data)
    jac = np.zeros((data.nefc, robot.nv))
    if mujoco.mj_isSparse(robot.model):
        mujoco.mju_sparse2dense(jac, data.efc_J, data.efc_J_rownnz, data.efc_J_rowadr, data.efc_J_colind)
    else:
        jac[:] = data.efc_J.reshape(data.nefc, robot.nv)
    rows = data.efc_type == mujoco.mjtConstraint.mjCNSTR_EQUALITY
    assert {int(mujoco.mjtConstraint.mjCNSTR_LIMIT_JOINT), int(mujoco.mjtConstraint.mjCNSTR_FRICTION_DOF)} <= set(
        data.efc_type.tolist())  # the pipeline had other rows
    return data.efc_pos[rows], jac[rows]


def test_rows_are_mujocos_equality_rows():
    robot = equality_robot()
    task = EqualityTask(robot, gain=2.0)
    flags = (robot.model.opt.disableflags, robot.model.opt.enableflags)
    task.update()
    assert (robot.model.opt.disableflags, robot.model.opt.enableflags) == flags  # restored
    assert task.dim == sum(ROWS.values()) and task.hard
    assert task.equalities == tuple(robot.equality_id(n) for n in NAMES)  # "spare" is inactive
    error, jacobian = mujoco_equality_rows(robot)
    np.testing.assert_allclose(task.error, error, atol=1e-15, rtol=0)
    np.testing.assert_allclose(task.jacobian, jacobian, atol=1e-15, rtol=0)
    np.testing.assert_array_equal(task.target_velocity, -2.0 * task.error)
    assert np.all(np.abs(task.error) > 1e-6)  # every row violated at this configuration


def test_sparse_model_gives_the_dense_models_rows():
    dense, sparse = equality_robot(' jacobian="dense"'), equality_robot(' jacobian="sparse"')
    assert mujoco.mj_isSparse(sparse.model) and not mujoco.mj_isSparse(dense.model)
    for names in (None, ["cord", "glue"]):
        a, b = EqualityTask(dense, names), EqualityTask(sparse, names)
        a.update()
        b.update()
        np.testing.assert_allclose(b.error, a.error, atol=1e-15, rtol=0)
        np.testing.assert_allclose(b.jacobian, a.jacobian, atol=1e-15, rtol=0)


@pytest.mark.parametrize("option", ['', ' jacobian="sparse"'])
def test_jacobian_is_the_derivative_of_the_residual(option):
    robot = equality_robot(option, seed=1)
    task = EqualityTask(robot)
    task.update()
    jacobian, q0 = task.jacobian.copy(), robot.q.copy()
    fd = np.zeros_like(jacobian)
    step = 1e-6
    for k in range(robot.nv):
        residuals = []
        for h in (step, -step):
            robot.q[:] = q0
            mujoco.mj_integratePos(robot.model, robot.q, np.eye(robot.nv)[k] * h, 1.0)
            robot.update_kinematics()
            task.update()
            residuals.append(task.error.copy())
        fd[:, k] = (residuals[0] - residuals[1]) / (2 * step)
    # Every row, the weld's quaternion-based rotation rows included, is the exact derivative
    # of its residual (agreement ~1e-11, rounding of the differences).
    np.testing.assert_allclose(fd, jacobian, atol=1e-8, rtol=0)
    assert np.abs(task.error[6:9]).max() > 1e-2  # the weld's rotation residual is not small


def test_connect_rows_are_the_difference_of_the_site_jacobians():
    """The hexapod's loops: e = p1 − p2, J = J(p1) − J(p2) (what the former loop task computed)."""
    robot = Robot.load("hexapod")
    rng = np.random.default_rng(4)
    robot.q[:18] += rng.normal(0.0, 0.02, 18)  # open the loops
    robot.update_kinematics()
    task = EqualityTask(robot, [f"loop{i}" for i in range(1, 7)])
    task.update()
    m, d = robot.model, robot.data
    jac1, jac2 = np.zeros((3, m.nv)), np.zeros((3, m.nv))
    for k, eq in enumerate(task.equalities):
        site1, site2 = m.eq_obj1id[eq], m.eq_obj2id[eq]
        mujoco.mj_jacSite(m, d, jac1, None, site1)
        mujoco.mj_jacSite(m, d, jac2, None, site2)
        np.testing.assert_allclose(task.error[3 * k:3 * k + 3], d.site_xpos[site1] - d.site_xpos[site2], atol=1e-16)
        np.testing.assert_allclose(task.jacobian[3 * k:3 * k + 3], jac1 - jac2, atol=1e-15)
    gaps = np.linalg.norm((d.site_xpos[m.eq_obj1id] - d.site_xpos[m.eq_obj2id]), axis=1)
    # The same three differences squared and summed (no BLAS kernel on a 3-vector's norm
    # here): a few roundings of a well-conditioned O(1e-3) value, 1e-14 on every machine.
    np.testing.assert_allclose(task.residuals(), gaps, rtol=1e-14)
    assert task.max_residual() > 1e-3


@pytest.mark.parametrize("option", ['', ' jacobian="sparse"'])
def test_hard_equalities_hold_in_a_qp_rollout(option):
    """From a configuration violating every equality, a posture task pulls the robot across
    its workspace; the hard rows close the residuals and keep every one below 1e-8."""
    robot = equality_robot(option, seed=2)
    dt = 0.002
    equalities = EqualityTask(robot, gain=0.5 / dt)
    target = robot.q.copy()
    target[robot.joint_dofs("p3")] += 0.6  # the tendon, the coupling and the pin must follow
    target[robot.joint_dofs("a3")] -= 0.5
    posture = PostureTask(robot, target=target, gain=2.0, weight=1.0)
    controller = QPController(robot, [equalities, posture, DampingTask(robot, 1e-6, joints=robot.joint_names)],
                              dt=dt, solver="daqp")
    start = robot.q.copy()
    initial = equalities.residuals().copy()
    for _ in range(1500):
        robot.update_kinematics()
        robot.integrate(controller.compute_velocity(), dt)
    robot.update_kinematics()
    residuals = equalities.residuals()
    assert np.all(initial > 1e-4)
    assert np.all(residuals < 1e-8), dict(zip(NAMES, residuals))
    assert np.max(np.abs(robot.q - start)) > 0.1  # it did move


def test_soft_equalities_approach_the_hard_solution():
    robot = equality_robot(seed=3)
    posture = PostureTask(robot, target=robot.q + 0.1, gain=1.0, weight=1.0)
    hard = QPController(robot, [EqualityTask(robot, gain=10.0), posture], dt=0.002).compute_velocity().copy()
    soft_task = EqualityTask(robot, gain=10.0, hard=False, weight=1e8)
    soft = QPController(robot, [soft_task, posture], dt=0.002).compute_velocity().copy()
    weak = QPController(robot, [EqualityTask(robot, gain=10.0, hard=False, weight=1e-2), posture], dt=0.002).compute_velocity()
    assert np.max(np.abs(soft - hard)) < 1e-4 * np.max(np.abs(hard))
    assert np.max(np.abs(weak - hard)) > 1e-2 * np.max(np.abs(hard))


def test_a_subset_of_equalities_and_bad_names():
    robot = equality_robot()
    task = EqualityTask(robot, ["cord", "pin"])
    task.update()
    full = EqualityTask(robot)
    full.update()
    np.testing.assert_array_equal(task.error, full.error[np.r_[0:3, 10:11]])
    np.testing.assert_array_equal(task.jacobian, full.jacobian[np.r_[0:3, 10:11]])
    assert task.equalities == (robot.equality_id("pin"), robot.equality_id("cord"))  # row order: ids
    with pytest.raises(UnknownName, match=r"unknown equality 'glu'.*'glue'"):
        EqualityTask(robot, ["glu"])
    with pytest.raises(ModelError, match="inactive"):
        EqualityTask(robot, ["spare"])
    with pytest.raises(InvalidInput, match="list"):
        EqualityTask(robot, "pin")
    with pytest.raises(ModelError, match="no active equality"):
        EqualityTask(Robot.load("arm"))
    robot.data.eq_active[robot.equality_id("glue")] = 0
    with pytest.raises(ModelError, match="changed"):
        task.update()


# A fixed tendon coupling two hinges and a joint equality on a slide, both active; and a
# weld of a jointless body to the world (it acts on no dof: MuJoCo makes no row for it).
TENDON_AND_JOINT = """<mujoco><worldbody>
<body name="a"><joint name="j1"/><geom size=".1"/>
 <body name="b" pos="0 0 1"><joint name="j2"/><geom size=".1"/></body></body>
<body name="c" pos="1 0 0"><joint name="j3" type="slide" axis="1 0 0"/><geom size=".1"/></body>
</worldbody>
<tendon><fixed name="t1"><joint joint="j1" coef="1"/><joint joint="j2" coef="1"/></fixed></tendon>
<equality><tendon name="sum" tendon1="t1"/><joint name="slide" joint1="j3"/></equality></mujoco>"""
STATIC_WELD = """<mujoco><worldbody>
<body name="fixed" pos="0 0 1"><geom size=".1"/></body>
<body name="a"><joint name="j1" axis="0 0 1"/><geom size=".1" pos="0.2 0 0"/></body>
</worldbody>
<equality><weld name="glued" body1="fixed"/><joint name="hinge" joint1="j1"/></equality></mujoco>"""


def _mujoco_rows(robot: Robot, equality: int) -> tuple[np.ndarray, np.ndarray]:
    """(residual, Jacobian) of one equality from MuJoCo's full pipeline (mj_forward)."""
    data = mujoco.MjData(robot.model)
    data.qpos[:] = robot.q
    mujoco.mj_forward(robot.model, data)
    rows = np.flatnonzero(data.efc_id[: data.ne] == equality)
    jacobian = data.efc_J[: data.nefc * robot.nv].reshape(data.nefc, robot.nv)
    return data.efc_pos[rows], jacobian[rows]


@pytest.mark.parametrize("first", ["kinematics", "forward"])
def test_an_active_tendon_equality_left_out_of_the_task_leaves_its_rows_intact(first):
    """The task on the slide's equality only, with a tendon equality active beside it:
    MuJoCo makes the tendon's row from the tendon Jacobian of the last ``mj_tendon``
    (none: no row; an earlier ``mj_forward``: a row), so the task must compute the tendons
    whenever an active equality of the model needs them (it failed to reshape efc_J)."""
    robot = Robot(mujoco.MjModel.from_xml_string(TENDON_AND_JOINT))
    robot.q[:] = [0.3, -0.1, 0.2]
    if first == "forward":
        mujoco.mj_forward(robot.model, robot.data)
    task = EqualityTask(robot, ["slide"], gain=50.0)
    controller = QPController(robot, [task, DampingTask(robot, weight=1e-6)], dt=0.01)
    for _ in range(20):
        qdot = controller.compute_velocity()
        error, jacobian = _mujoco_rows(robot, robot.equality_id("slide"))
        np.testing.assert_allclose(task.error, error, atol=1e-15)
        np.testing.assert_allclose(task.jacobian, jacobian, atol=1e-15)
        robot.integrate(qdot, 0.01)
    assert abs(robot.q[2]) < 0.2 * (1 - 0.5) ** 20 + 1e-12  # e(k+1) = (1 − KΔt) e(k)


def test_a_weld_that_acts_on_no_dof_is_left_out_by_default_and_refused_by_name():
    robot = Robot(mujoco.MjModel.from_xml_string(STATIC_WELD))
    robot.q[:] = [0.4]
    task = EqualityTask(robot)
    assert task.equalities == (robot.equality_id("hinge"),) and task.dim == 1
    qdot = QPController(robot, [task], dt=0.01).compute_velocity()
    # Dead-beat on the hinge: one row on one dof, x = b/a, a few roundings of O(1) values.
    np.testing.assert_allclose(qdot, [-0.4 / 0.01], rtol=1e-12)
    with pytest.raises(ModelError, match=r"'glued'.*no dof"):
        EqualityTask(robot, ["glued", "hinge"])
    with pytest.raises(ModelError, match="no dof"):
        EqualityTask(robot, ["glued"])


@pytest.mark.parametrize("gain", ["fast", [1.0, 2.0], np.nan, -1.0, np.inf])
def test_a_bad_equality_gain_is_a_typed_error(gain):
    with pytest.raises(InvalidInput, match="gain"):
        EqualityTask(equality_robot(), gain=gain)
