"""The warp back-end on Warp's CPU device, against the CPU back-end, serial MuJoCo, the
serial controller and quadprog (an independent exact Goldfarb–Idnani solver).

MuJoCo Warp computes in float32: its kinematics match MuJoCo's float64 to ~1e-7
relative, and closed-loop rollouts stay within the tolerances measured in docs/batch.md
(GPU section). The device QP is float64 and matches quadprog to 1e-9.
"""

from __future__ import annotations

import importlib.util
import sys
from pathlib import Path

import mujoco
import numpy as np
import pytest

pytest.importorskip("mujoco_warp", reason="the warp back-end needs the gpu extra (pip install -e \".[gpu]\")")

import qpik  # noqa: E402
from qpik import batch  # noqa: E402
from qpik.batch.backends.base import QPStatus  # noqa: E402
from qpik.batch.backends.warp import WarpBackend, WarpQP  # noqa: E402
from qpik.errors import InvalidInput, ModelError  # noqa: E402

_spec = importlib.util.spec_from_file_location("warp_rollouts", Path(__file__).with_name("warp_rollouts.py"))
rollouts = importlib.util.module_from_spec(_spec)
sys.modules.setdefault("warp_rollouts", rollouts)  # its dataclass looks its module up
_spec.loader.exec_module(rollouts)

N = 4
# float32 kinematics: pose and Jacobian entries to this (absolute, models of ~1 m).
FLOAT32_KINEMATICS = 2e-6
# q after 0.5 s, the warp back-end against the CPU back-end (measured: arm 2.3e-7,
# hexapod 2.2e-6, pusher 1.3e-5 after 1 s).
ROLLOUT_TOLERANCE = {"arm": 2e-6, "hexapod": 2e-5, "pusher": 1e-4}
STEPS = 250


def _random_states(model: mujoco.MjModel, template: qpik.Robot, n: int, seed: int) -> np.ndarray:
    """Configurations near the start (inside the ranges), quaternions left alone."""
    rng = np.random.default_rng(seed)
    q = np.tile(template.q, (n, 1))
    limits = template.joint_limits
    span = limits.upper - limits.lower
    q[:, limits.qpos_index] = np.clip(q[:, limits.qpos_index] + 0.05 * span * rng.standard_normal((n, len(span))),
                                      limits.lower, limits.upper)
    return q


@pytest.mark.parametrize("name", ["arm", "hexapod", "pusher"])
def test_kinematics_equal_serial_mujoco_to_float32(name, model_path):
    template = qpik.Robot.load(model_path(name), allow_outside_limits=True)
    m = template.model
    backend = WarpBackend(m, N, device="cpu")
    frame_type, frame_id = ("site", m.nsite - 1) if m.nsite else ("body", m.nbody - 1)
    position, rotation = backend.frame_pose(frame_type, frame_id)
    backend.qpos[:] = _random_states(m, template, N, seed=1)
    backend.forward()
    body = int(m.site_bodyid[frame_id]) if frame_type == "site" else frame_id
    jacp, jacr = backend.jacobian(body, position)
    com_jacobian = backend.subtree_com_jacobian(1)
    data = mujoco.MjData(m)
    for w in range(N):
        data.qpos[:] = backend.qpos[w]
        mujoco.mj_kinematics(m, data)
        mujoco.mj_comPos(m, data)
        xpos = data.site_xpos if frame_type == "site" else data.xpos
        xmat = data.site_xmat if frame_type == "site" else data.xmat
        np.testing.assert_allclose(position[w], xpos[frame_id], atol=FLOAT32_KINEMATICS)
        np.testing.assert_allclose(rotation[w].reshape(9), xmat[frame_id], atol=FLOAT32_KINEMATICS)
        expected_p, expected_r = np.zeros((3, m.nv)), np.zeros((3, m.nv))
        mujoco.mj_jac(m, data, expected_p, expected_r, xpos[frame_id], body)
        np.testing.assert_allclose(jacp[w], expected_p, atol=FLOAT32_KINEMATICS)
        np.testing.assert_allclose(jacr[w], expected_r, atol=FLOAT32_KINEMATICS)
        expected_com = np.zeros((3, m.nv))
        mujoco.mj_jacSubtreeCom(m, data, expected_com, 1)
        np.testing.assert_allclose(backend.subtree_com(1)[w], data.subtree_com[1], atol=FLOAT32_KINEMATICS)
        np.testing.assert_allclose(com_jacobian[w], expected_com, atol=FLOAT32_KINEMATICS)


def test_loop_closure_rows_are_mujoco_warps_own_and_equal_mujoco():
    template = qpik.Robot.load("hexapod")
    m = template.model
    backend = WarpBackend(m, N, device="cpu")
    backend.qpos[:] = _random_states(m, template, N, seed=2)  # loops opened: residuals of mm
    backend.forward()
    equalities = np.arange(m.neq)
    residual, jacobian = backend.equality_rows(equalities)
    assert residual.shape == (N, 3 * m.neq) and jacobian.shape == (N, 3 * m.neq, m.nv)
    assert np.abs(residual).max() > 1e-4  # the rows measure open loops, not zeros
    serial = qpik.Robot(m, allow_outside_limits=True)
    task = qpik.EqualityTask(serial)
    for w in range(N):
        serial.data.qpos[:] = backend.qpos[w]
        serial.update_kinematics()
        task.update()
        np.testing.assert_allclose(residual[w], task.error, atol=FLOAT32_KINEMATICS)
        np.testing.assert_allclose(jacobian[w], task.jacobian, atol=FLOAT32_KINEMATICS)
    # a subset, in the order asked
    sub_residual, _ = backend.equality_rows(np.array([1, 4]))
    np.testing.assert_array_equal(sub_residual, residual[:, [3, 4, 5, 12, 13, 14]])


def test_equality_rows_are_found_in_each_worlds_own_order():
    """On a GPU MuJoCo Warp numbers the rows with atomic counters: each world may hold the
    equalities' blocks in another order, with other rows between them."""
    from qpik.batch.backends.warp import equality_row_index

    m = qpik.Robot.load("hexapod").model
    eq, other = int(mujoco.mjtConstraint.mjCNSTR_EQUALITY), int(mujoco.mjtConstraint.mjCNSTR_LIMIT_JOINT)
    # world 0: eq 0, eq 1, a joint-limit row; world 1: the limit row, eq 1, eq 0 (3 rows each)
    kind = np.array([[eq] * 6 + [other], [other] + [eq] * 6])
    ids = np.array([[0, 0, 0, 1, 1, 1, 0], [0, 1, 1, 1, 0, 0, 0]])
    index = equality_row_index(kind, ids, np.array([0, 1]), m)
    np.testing.assert_array_equal(index, [[0, 1, 2, 3, 4, 5], [4, 5, 6, 1, 2, 3]])
    np.testing.assert_array_equal(equality_row_index(kind, ids, np.array([1]), m), [[3, 4, 5], [1, 2, 3]])
    kind[1, 1] = other  # equality 1 loses a row in world 1
    with pytest.raises(ModelError, match="rows for equality"):
        equality_row_index(kind, ids, np.array([1]), m)


def _random_qps(n_world: int, nv: int, meq: int, seed: int):
    rng = np.random.default_rng(seed)
    M = rng.standard_normal((n_world, nv, nv))
    H = M @ M.transpose(0, 2, 1) + 0.1 * np.eye(nv)
    c = 3.0 * rng.standard_normal((n_world, nv))
    A = rng.standard_normal((n_world, meq, nv))
    b = rng.standard_normal((n_world, meq))
    lb, ub = -rng.uniform(0.1, 1.0, (n_world, nv)), rng.uniform(0.1, 1.0, (n_world, nv))
    lb[:, 0], ub[:, 1] = -np.inf, np.inf
    return H, c, A, b, lb, ub


def _quadprog_or_none(H, c, A, b, lb, ub):
    try:
        return rollouts.quadprog_solve(H[None], c[None], A[None], b[None], lb[None], ub[None])[0]
    except ValueError:  # quadprog: "constraints are inconsistent, no solution"
        return None


@pytest.mark.parametrize("meq", [0, 2])
def test_device_qp_equals_quadprog_and_agrees_on_infeasibility(meq):
    H, c, A, b, lb, ub = _random_qps(200, 7, meq, seed=meq)
    qp = WarpQP(200, 7, meq, device="cpu")
    result = qp.solve(H, c, A, b, lb, ub)
    infeasible = 0
    for w in range(200):
        reference = _quadprog_or_none(H[w], c[w], A[w], b[w], lb[w], ub[w])
        if reference is None:
            infeasible += 1
            assert result.status[w] == QPStatus.INFEASIBLE and w in result.reasons
            assert not result.x[w].any()
            continue
        assert result.status[w] == QPStatus.SOLVED, result.reasons.get(w)
        np.testing.assert_allclose(result.x[w], reference, atol=1e-9 * (1 + np.abs(reference).max()))
        assert np.all(result.x[w] >= lb[w]) and np.all(result.x[w] <= ub[w])
    assert (infeasible > 0) == (meq > 0)  # random equality rows and boxes clash in some worlds
    assert not result.fallback[result.status == QPStatus.SOLVED].any()  # the device decided every solved world
    assert result.closed_form.sum() < 200 - infeasible  # bounds were active


def test_device_qp_warm_start_and_reset():
    H, c, A, b, lb, ub = _random_qps(50, 6, 1, seed=5)
    qp = WarpQP(50, 6, 1, device="cpu")
    cold = qp.solve(H, c, A, b, lb, ub)
    first_x, first_iterations = cold.x.copy(), cold.iterations
    assert first_iterations > 0
    warm = qp.solve(H, c, A, b, lb, ub)  # the last active set is the answer: nothing to add
    assert warm.iterations == 0
    np.testing.assert_allclose(warm.x, first_x, atol=1e-12)
    qp.reset()
    assert qp.solve(H, c, A, b, lb, ub).iterations == first_iterations


def test_device_qp_bad_worlds_do_not_stop_the_others():
    H, c, A, b, lb, ub = _random_qps(6, 5, 1, seed=9)
    lb[:, 0], ub[:, 1] = -1.0, 1.0
    b[:] = 0.0  # x = 0 is feasible in every world
    c[1, 2] = np.nan
    lb[2, 3], ub[2, 3] = 0.5, 0.2
    active = np.array([True, True, True, False, True, True])
    result = WarpQP(6, 5, 1, device="cpu").solve(H, c, A, b, lb, ub, active)
    assert result.status.tolist() == [QPStatus.SOLVED, QPStatus.FAILED, QPStatus.INFEASIBLE, QPStatus.SKIPPED,
                                      QPStatus.SOLVED, QPStatus.SOLVED]
    assert "NaN" in result.reasons[1] and "variable 3" in result.reasons[2] and set(result.reasons) == {1, 2}
    assert np.isfinite(result.x).all() and not result.x[1:4].any()
    for w in (0, 4, 5):
        np.testing.assert_allclose(result.x[w], _quadprog_or_none(H[w], c[w], A[w], b[w], lb[w], ub[w]), atol=1e-9)


def test_shared_hessian_equals_per_world_hessians():
    H, c, A, b, lb, ub = _random_qps(20, 5, 1, seed=11)
    shared = WarpQP(20, 5, 1, device="cpu").solve(H[0], c, A, b, lb, ub)
    each = WarpQP(20, 5, 1, device="cpu").solve(np.broadcast_to(H[0], H.shape).copy(), c, A, b, lb, ub)
    np.testing.assert_array_equal(shared.status, each.status)
    np.testing.assert_array_equal(shared.x, each.x)


@pytest.mark.parametrize("name", ["arm", "hexapod", "pusher"])
def test_rollouts_equal_the_cpu_back_end_and_cross_no_limit(name, pusher_model):
    robots, ctrl = rollouts.controller(name, N, pusher_model)
    reference = rollouts.rollout(robots, ctrl, STEPS)

    # The device QP on the CPU back-end's kinematics: the same trajectory (it is exact).
    robots, ctrl = rollouts.controller(name, N, pusher_model)
    ctrl.qp = WarpQP(N, robots.nv, ctrl.meq, device="cpu")
    exact = rollouts.rollout(robots, ctrl, STEPS)
    np.testing.assert_allclose(exact["q"], reference["q"], rtol=0, atol=1e-9)

    # The whole warp back-end: float32 kinematics, the device QP.
    robots, ctrl = rollouts.controller(name, N, pusher_model, backend="warp", device="cpu")
    assert isinstance(ctrl.qp, WarpQP)
    warp = rollouts.rollout(robots, ctrl, STEPS)
    assert warp["bound_steps"] > STEPS // 5  # limits bound on many steps
    np.testing.assert_allclose(warp["q"], reference["q"], rtol=0, atol=ROLLOUT_TOLERANCE[name])

    limits = robots.joint_limits
    q = warp["q"][..., limits.qpos_index]
    assert (q >= limits.lower - 1e-9).all() and (q <= limits.upper + 1e-9).all()
    for qdot, (lb, ub) in zip(warp["qdot"], warp["boxes"]):
        assert (qdot >= lb).all() and (qdot <= ub).all()
    if name == "hexapod":  # the loops stay closed
        serial = qpik.Robot(robots.model, allow_outside_limits=True)
        task = qpik.EqualityTask(serial)
        for w in range(N):
            serial.data.qpos[:] = warp["q"][-1, w]
            assert task.max_residual(serial) < 1e-5


def test_a_nan_target_fails_its_world_only():
    robots = batch.Robot.load("arm", 3, backend="warp", device="cpu")
    task = batch.PositionTask(robots, "end_effector", "site", axes="xy", gain=50.0)
    ctrl = batch.QPController(robots, [task, batch.DampingTask(robots)],
                              [batch.JointPositionLimit(robots), batch.JointVelocityLimit(robots)], dt=rollouts.DT)
    targets = np.array([[1.0, 1.0], [np.nan, 1.0], [0.5, 1.5]])
    with pytest.raises(batch.WorldsFailed) as failed:
        task.set_target(targets)
        ctrl.compute_velocity()
    assert failed.value.worlds.tolist() == [1]
    cpu_robots = batch.Robot.load("arm", 3)
    cpu_task = batch.PositionTask(cpu_robots, "end_effector", "site", axes="xy", gain=50.0)
    cpu_task.set_target(targets[[0, 0, 2]])
    cpu = batch.QPController(cpu_robots, [cpu_task, batch.DampingTask(cpu_robots)],
                             [batch.JointPositionLimit(cpu_robots), batch.JointVelocityLimit(cpu_robots)],
                             dt=rollouts.DT).compute_velocity()
    qdot = failed.value.qdot
    assert not qdot[1].any() and np.isfinite(qdot).all()
    np.testing.assert_allclose(qdot[[0, 2]], cpu[[0, 2]], rtol=0, atol=1e-5)


def test_physics_on_the_device_follows_mujoco():
    template = qpik.Robot.load("arm")
    m = template.model
    backend = WarpBackend(m, 2, device="cpu")
    qpos = np.tile(template.q, (2, 1))
    ctrl = np.zeros((2, m.nu))
    ctrl[1] = 0.1
    backend.physics_reset(qpos, ctrl)
    moved, unstable = backend.physics_step(ctrl, 50)
    assert not unstable.any()
    data = mujoco.MjData(m)
    for w in range(2):
        mujoco.mj_resetData(m, data)
        data.qpos[:], data.ctrl[:] = qpos[w], ctrl[w]
        mujoco.mj_step(m, data, nstep=50)
        np.testing.assert_allclose(moved[w], data.qpos, atol=1e-4)


def test_unknown_device_is_a_typed_error():
    with pytest.raises(InvalidInput, match="unknown Warp device 'cuda:7'"):
        batch.Robot.load("arm", 2, backend="warp", device="cuda:7")
