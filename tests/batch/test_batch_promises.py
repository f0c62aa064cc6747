"""qpik.batch's promises: limits never crossed, one bad world never stops the others, the
batched QP equals DAQP world by world, the back-end equals MuJoCo's own routines."""

from __future__ import annotations

from ctypes import c_int

import daqp
import mujoco
import numpy as np
import pytest

from qpik import batch
from qpik.batch.backends.base import QPStatus
from qpik.batch.backends.cpu import CpuBackend
from qpik.batch.qp import ActiveSetQP
from qpik.errors import InvalidInput, QpikError

DT = 0.002


def test_far_targets_never_cross_a_position_or_velocity_limit():
    rng = np.random.default_rng(11)
    robots = batch.Robot.load("arm", 32)
    task = batch.PositionTask(robots, "end_effector", axes="xy", gain=500.0, lm_damping=10.0)
    task.set_target(rng.uniform(-50.0, 50.0, (robots.n, 2)))  # far out of reach
    limits = [batch.JointPositionLimit(robots), batch.JointVelocityLimit(robots)]
    controller = batch.QPController(robots, [task, batch.DampingTask(robots)], limits, dt=DT)
    joint, vmax = robots.joint_limits, robots.velocity_limits
    worst_position = worst_speed = 0.0
    for _ in range(400):
        qdot = controller.compute_velocity()
        worst_speed = max(worst_speed, float(np.max(np.abs(qdot) - vmax)))
        robots.integrate(qdot, DT)
        q = robots.q[:, joint.qpos_index]
        worst_position = max(worst_position, float(np.max(joint.lower - q)), float(np.max(q - joint.upper)))
    assert worst_speed <= 1e-9
    assert worst_position <= 1e-9
    assert controller.qp.stats["active_set"] + controller.qp.stats["daqp"] > 0


def test_a_nan_target_in_one_world_names_it_and_the_others_are_solved():
    robots = batch.Robot.load("arm", 6)
    task = batch.PositionTask(robots, "end_effector", axes="xy", gain=100.0, hard=True)
    target = task.target + 0.01
    target[3, 1] = np.nan
    task.set_target(target)
    controller = batch.QPController(robots, [task, batch.DampingTask(robots)], [batch.JointVelocityLimit(robots)], dt=DT)
    with pytest.raises(batch.WorldsFailed) as caught:
        controller.compute_velocity()
    error = caught.value
    assert isinstance(error, QpikError)
    assert error.worlds.tolist() == [3]
    assert "world 3" in str(error) and "position task" in error.reasons[3]
    assert np.all(error.qdot[3] == 0.0) and np.isfinite(error.qdot).all()
    # The healthy worlds' answers meet their hard rows.
    healthy = [w for w in range(robots.n) if w != 3]
    residual = np.einsum("nij,nj->ni", task.jacobian[healthy], error.qdot[healthy]) - task.target_velocity[healthy]
    assert np.abs(residual).max() < 1e-9


def test_an_infeasible_world_is_reported_after_the_others():
    robots = batch.Robot.load("arm", 4)
    task = batch.PositionTask(robots, "end_effector", axes="xy", gain=500.0, hard=True)
    target = task.target.copy()
    target[2] += 1.0  # 500 m/s asked with an 8 rad/s box: no point meets both
    task.set_target(target)
    controller = batch.QPController(robots, [task, batch.DampingTask(robots)], [batch.JointVelocityLimit(robots)], dt=DT)
    with pytest.raises(batch.WorldsFailed) as caught:
        controller.compute_velocity()
    assert caught.value.worlds.tolist() == [2]
    assert "infeasible" in caught.value.reasons[2]


def test_collision_avoidance_and_weld_equalities_say_they_are_not_batched():
    robots = batch.Robot.load("arm", 2)
    with pytest.raises(batch.NotBatched, match="not batched yet"):
        batch.CollisionAvoidanceLimit(robots, [(["link1"], ["link3"])])
    spec = mujoco.MjSpec()
    body = spec.worldbody.add_body(name="b", pos=[0, 0, 1])
    body.add_joint(name="j", type=mujoco.mjtJoint.mjJNT_HINGE, axis=[0, 1, 0])
    body.add_geom(size=[0.1, 0, 0], mass=1.0)
    spec.add_equality(type=mujoco.mjtEq.mjEQ_WELD, name1="b", objtype=mujoco.mjtObj.mjOBJ_BODY)
    welded = batch.Robot(spec.compile(), 2)
    with pytest.raises(batch.NotBatched, match="weld"):
        batch.EqualityTask(welded)


def test_bad_input_is_a_typed_error():
    robots = batch.Robot.load("arm", 3)
    with pytest.raises(InvalidInput):
        batch.Robot.load("arm", 0)
    with pytest.raises(InvalidInput):
        robots.set_q(np.zeros((2, 4)))
    with pytest.raises(batch.InvalidWorlds) as caught:
        bad = np.tile(robots.q[0], (3, 1))
        bad[1, 0] = np.inf
        robots.set_q(bad)
    assert caught.value.worlds.tolist() == [1]
    with pytest.raises(batch.InvalidWorlds):
        outside = np.tile(robots.q[0], (3, 1))
        outside[2, 3] = 5.0  # the ram's stroke is [0, 1] m
        robots.set_q(outside)
    task = batch.FrameTask(robots, "end_effector")
    with pytest.raises(batch.InvalidWorlds):
        task.set_target(np.zeros(3), np.diag([1.0, 1.0, -1.0]))  # a reflection
    with pytest.raises(InvalidInput):
        robots.integrate(np.zeros((3, 4)), -1.0)


@pytest.mark.parametrize("nv, meq, hessian", [(4, 2, "diagonal"), (7, 0, "per world"), (7, 3, "per world"),
                                             (12, 6, "per world"), (5, 5, "diagonal"), (6, 1, "dense"),
                                             (6, 2, "per world"), (8, 4, "dense"), (4, 0, "diagonal")])
def test_batched_qp_equals_daqp_world_by_world(nv, meq, hessian):
    rng = np.random.default_rng(nv * 10 + meq)
    n = 120
    shared = hessian != "per world"
    if hessian == "diagonal":
        H = np.diag(rng.uniform(0.5, 2.0, nv))
    elif hessian == "dense":
        M = rng.normal(size=(nv, nv))
        H = M @ M.T + 0.1 * np.eye(nv)
    else:
        M = rng.normal(size=(n, nv, nv))
        H = M @ M.transpose(0, 2, 1) + 0.1 * np.eye(nv)
    c = 3.0 * rng.normal(size=(n, nv))
    A, b = rng.normal(size=(n, meq, nv)), rng.normal(size=(n, meq))
    lb, ub = -rng.uniform(0.1, 1.0, (n, nv)), rng.uniform(0.1, 1.0, (n, nv))
    lb[:20], ub[:20] = -np.inf, np.inf
    qp = ActiveSetQP(n, nv, meq)
    result = qp.solve(H, c, A, b, lb, ub)
    sense = np.zeros(nv + meq, dtype=c_int)
    sense[nv:] = 5
    for w in range(n):
        Hw = np.ascontiguousarray(H if shared else H[w])
        x, _, exitflag, _ = daqp.solve(Hw, c[w].copy(), np.ascontiguousarray(A[w]), np.concatenate([ub[w], b[w]]),
                                       np.concatenate([lb[w], b[w]]), sense.copy())
        if exitflag == -1:
            assert result.status[w] == QPStatus.INFEASIBLE and not result.x[w].any()
            continue
        assert result.status[w] == QPStatus.SOLVED
        np.testing.assert_allclose(result.x[w], x, rtol=0, atol=1e-9)
        assert np.all(result.x[w] >= lb[w]) and np.all(result.x[w] <= ub[w])
    # Warm start: the same problems again are solved from the last active sets.
    again = qp.solve(H, c, A, b, lb, ub)
    np.testing.assert_array_equal(again.status, result.status)
    np.testing.assert_allclose(again.x, result.x, rtol=0, atol=1e-12)


@pytest.mark.parametrize("name", ["arm", "hexapod", "humanoid"])
def test_cpu_backend_equals_mujoco(name, model_path):
    model = mujoco.MjModel.from_xml_path(_scene(name) if name in ("arm", "hexapod") else str(model_path(name)))
    rng = np.random.default_rng(5)
    n = 4
    backend = CpuBackend(model, n, nthread=2)
    data = mujoco.MjData(model)
    states = np.tile(model.qpos0, (n, 1))
    for i in range(n):
        mujoco.mj_integratePos(model, states[i], rng.normal(size=model.nv), 0.3)
    backend.qpos[:] = states
    backend.forward()
    velocity = rng.normal(size=(n, model.nv))
    for body in range(1, model.nbody):
        position, rotation = backend.frame_pose("body", body)
        jacp, jacr = backend.jacobian(body, position)
        com = backend.subtree_com_jacobian(body) if model.body_subtreemass[body] > 0 else None
        for i in range(n):
            data.qpos[:] = states[i]
            mujoco.mj_kinematics(model, data)
            mujoco.mj_comPos(model, data)
            p, r = np.zeros((3, model.nv)), np.zeros((3, model.nv))
            mujoco.mj_jacBody(model, data, p, r, body)
            np.testing.assert_allclose(jacp[i], p, rtol=0, atol=1e-12)
            np.testing.assert_allclose(jacr[i], r, rtol=0, atol=1e-12)
            np.testing.assert_allclose(position[i], data.xpos[body], rtol=0, atol=1e-12)
            if com is not None:
                mujoco.mj_jacSubtreeCom(model, data, p, body)
                np.testing.assert_allclose(com[i], p, rtol=0, atol=1e-12)
    expected = states.copy()
    for i in range(n):
        mujoco.mj_integratePos(model, expected[i], velocity[i], 0.01)
    backend.integrate(velocity, 0.01)
    np.testing.assert_allclose(backend.qpos, expected, rtol=0, atol=1e-12)


@pytest.mark.parametrize("name", ["arm", "hexapod", "pusher", "humanoid"])
def test_pared_kinematic_model_changes_no_value_a_task_reads(name, model_path):
    """The back-end's kinematic copy (no contacts, no constraints, no geoms listed on its
    bodies) gives every pose, cdof and centre of mass of MuJoCo on the full model, and
    geom frames as mj_kinematics writes them."""
    if name == "pusher":
        from qpik.models import pusher_arm

        model = pusher_arm()
    else:
        model = mujoco.MjModel.from_xml_path(_scene(name) if name in ("arm", "hexapod") else str(model_path(name)))
    rng = np.random.default_rng(8)
    n = 5
    backend = CpuBackend(model, n, nthread=1)
    states = np.tile(model.qpos0, (n, 1))
    for i in range(n):
        mujoco.mj_integratePos(model, states[i], rng.normal(size=model.nv), 0.5)
    backend.qpos[:] = states
    frames = {(kind, i): backend.frame_pose(kind, i) for kind, count in
              (("site", model.nsite), ("body", model.nbody), ("geom", model.ngeom)) for i in range(count)}
    backend.forward()
    fields = {"site": ("site_xpos", "site_xmat"), "body": ("xpos", "xmat"), "geom": ("geom_xpos", "geom_xmat")}
    data = mujoco.MjData(model)
    for i in range(n):
        data.qpos[:] = states[i]
        mujoco.mj_fwdPosition(model, data)  # the full model's position stage: geoms, contacts, all
        for (kind, k), (position, rotation) in frames.items():
            # MuJoCo's own outputs bit for bit; a geom's pose, formed here from its
            # body's, to 1e-15 (MuJoCo's compiled products may round the last bit otherwise)
            atol = 1e-15 if kind == "geom" else 0.0
            np.testing.assert_allclose(position[i], getattr(data, fields[kind][0])[k], rtol=0, atol=atol,
                                       err_msg=f"{kind} {k}")
            np.testing.assert_allclose(rotation[i].ravel(), getattr(data, fields[kind][1])[k], rtol=0, atol=atol,
                                       err_msg=f"{kind} {k}")
        np.testing.assert_array_equal(backend._cdof[i], data.cdof)
        np.testing.assert_array_equal(backend._subtree_com[i], data.subtree_com)


def _scene(name: str) -> str:
    from qpik.robot import scene_path

    return str(scene_path(name))


def test_physics_rollout_tracks_the_command():
    rng = np.random.default_rng(6)
    robots = batch.Robot.load("arm", 4)
    task = batch.PositionTask(robots, "end_effector", axes="xy", gain=50.0)
    task.set_target(task.target + rng.uniform(-0.1, 0.1, (robots.n, 2)))
    controller = batch.QPController(robots, [task, batch.DampingTask(robots)],
                                    [batch.JointPositionLimit(robots), batch.JointVelocityLimit(robots)], dt=DT)
    measured = batch.rollout(controller, 250, mode="physics", progress=False)
    commanded = robots.q
    assert np.abs(measured - commanded).max() < 1e-2  # the servos follow the command
    robots.ensure_kinematics()
    task.update()
    assert np.abs(task.error).max() < 1e-3  # and the commanded hand reached its target


def test_batch_import_is_light(run_without_modules):
    result = run_without_modules("import qpik; from qpik import batch; import sys; "
                                 "assert 'qpik.batch.qp' not in sys.modules; print(batch.Robot.__name__)", ("scipy",))
    assert result.returncode == 0, result.stderr
    assert "Robot" in result.stdout


def test_forward_leaves_mujocos_timer_callback_as_it_was():
    """The back-end runs MuJoCo's stages with the profiling timer callback replaced by a
    constant; the caller's callback is back after each call and times MuJoCo again."""
    model = mujoco.MjModel.from_xml_path(_scene("arm"))
    backend = CpuBackend(model, 8, nthread=1)
    ticks = []

    def timer():
        ticks.append(None)
        return float(len(ticks))

    mujoco.set_mjcb_time(timer)
    try:
        backend.forward()
        assert mujoco.get_mjcb_time() is timer and not ticks  # restored; not called by the batch
        data = mujoco.MjData(model)
        mujoco.mj_forward(model, data)
        assert ticks  # the caller's timer times MuJoCo again
    finally:
        mujoco.set_mjcb_time(None)
    backend.forward()
    assert mujoco.get_mjcb_time() is None  # the bindings' own default, as before
