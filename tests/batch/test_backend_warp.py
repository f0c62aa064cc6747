"""The warp back-end on Warp's CPU device against the CPU back-end (itself equal to
MuJoCo's serial routines: test_backend_cpu.py): frame poses, Jacobians, centres of mass,
loop-closure rows, integration and physics; and the engine's step on its worlds, which
runs on the host and says so once per controller.

MuJoCo Warp computes in float32: its kinematics match float64 to ~1e-7 relative, and
closed-loop rollouts drift from the CPU back-end's within the tolerances below.
"""

from __future__ import annotations

import warnings

import mujoco
import numpy as np
import pytest

pytest.importorskip("mujoco_warp", reason="the warp back-end needs the gpu extra (pip install -e \".[gpu]\")")

import qpik  # noqa: E402
from qpik import batch  # noqa: E402
from qpik.batch.backends.cpu import CpuBackend  # noqa: E402
from qpik.batch.backends.warp import WarpBackend, equality_row_index  # noqa: E402
from qpik.errors import InvalidInput, ModelError  # noqa: E402

N = 4
DT = 0.002
# float32 kinematics: pose, Jacobian and loop-row entries to this (absolute, models of ~1 m).
FLOAT32_KINEMATICS = 2e-6
# q after STEPS closed-loop steps, the warp back-end against the CPU back-end (rad, m):
# float32 kinematics feed back through q (measured: arm 1.5e-7, pusher 2.1e-6).
STEPS = 150
ROLLOUT_TOLERANCE = {"arm": 2e-6, "pusher": 2e-5}
PUSHER_START = np.array([0.2, 0.3, -0.2, -1.0, 0.3, -0.5, 0.2])


def _model(name: str, model_path, pusher_model=None) -> mujoco.MjModel:
    if name == "pusher":
        return pusher_model
    return qpik.Robot.load(model_path(name), allow_outside_limits=True).model


def _random_states(model: mujoco.MjModel, n: int, seed: int) -> np.ndarray:
    """Configurations near the start (inside the ranges), quaternions left alone."""
    template = qpik.Robot(model, allow_outside_limits=True)
    rng = np.random.default_rng(seed)
    q = np.tile(template.q, (n, 1))
    limits = template.joint_limits
    span = limits.upper - limits.lower
    q[:, limits.qpos_index] = np.clip(q[:, limits.qpos_index] + 0.05 * span * rng.standard_normal((n, len(span))),
                                      limits.lower, limits.upper)
    return q


@pytest.mark.parametrize("name", ["arm", "hexapod", "pusher"])
def test_kinematics_equal_the_cpu_back_end_to_float32(name, model_path, pusher_model):
    m = _model(name, model_path, pusher_model)
    warp, cpu = WarpBackend(m, N, device="cpu"), CpuBackend(m, N, nthread=1)
    frames = [("site", m.nsite - 1)] if m.nsite else []
    frames += [("body", m.nbody - 1), ("geom", m.ngeom - 1)]
    poses = {frame: (warp.frame_pose(*frame), cpu.frame_pose(*frame)) for frame in frames}
    states = _random_states(m, N, seed=1)
    warp.qpos[:], cpu.qpos[:] = states, states
    warp.forward()
    cpu.forward()
    for (kind, index), ((warp_p, warp_r), (cpu_p, cpu_r)) in poses.items():
        np.testing.assert_allclose(warp_p, cpu_p, rtol=0, atol=FLOAT32_KINEMATICS, err_msg=kind)
        np.testing.assert_allclose(warp_r, cpu_r, rtol=0, atol=FLOAT32_KINEMATICS, err_msg=kind)
        body = int(m.site_bodyid[index] if kind == "site" else m.geom_bodyid[index] if kind == "geom" else index)
        for got, expected in zip(warp.jacobian(body, cpu_p), cpu.jacobian(body, cpu_p)):
            np.testing.assert_allclose(got, expected, rtol=0, atol=FLOAT32_KINEMATICS, err_msg=kind)
    np.testing.assert_allclose(warp.subtree_com(1), cpu.subtree_com(1), rtol=0, atol=FLOAT32_KINEMATICS)
    np.testing.assert_allclose(warp.subtree_com_jacobian(1), cpu.subtree_com_jacobian(1), rtol=0,
                               atol=FLOAT32_KINEMATICS)
    velocity = np.random.default_rng(2).normal(size=(N, m.nv))
    warp.integrate(velocity, DT)
    cpu.integrate(velocity, DT)
    np.testing.assert_array_equal(warp.qpos, cpu.qpos)  # the same host integration


def test_loop_closure_rows_are_mujoco_warps_own_and_equal_the_cpu_back_ends():
    m = qpik.Robot.load("hexapod").model
    warp, cpu = WarpBackend(m, N, device="cpu"), CpuBackend(m, N, nthread=1)
    states = _random_states(m, N, seed=2)  # loops opened: residuals of mm
    warp.qpos[:], cpu.qpos[:] = states, states
    warp.forward()
    cpu.forward()
    equalities = np.arange(m.neq)
    residual, jacobian = warp.equality_rows(equalities)
    assert residual.shape == (N, 3 * m.neq) and jacobian.shape == (N, 3 * m.neq, m.nv)
    assert np.abs(residual).max() > 1e-4  # the rows measure open loops, not zeros
    expected_residual, expected_jacobian = cpu.equality_rows(equalities)
    np.testing.assert_allclose(residual, expected_residual, rtol=0, atol=FLOAT32_KINEMATICS)
    np.testing.assert_allclose(jacobian, expected_jacobian, rtol=0, atol=FLOAT32_KINEMATICS)
    # a subset, in the order asked
    sub_residual, _ = warp.equality_rows(np.array([1, 4]))
    np.testing.assert_array_equal(sub_residual, residual[:, [3, 4, 5, 12, 13, 14]])


def test_equality_rows_are_found_in_each_worlds_own_order():
    """On a GPU MuJoCo Warp numbers the rows with atomic counters: each world may hold the
    equalities' blocks in another order, with other rows between them."""
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


def _problem(name: str, robots, rng):
    """The arm's x-y target 0.5-1 m away or the pusher's tip 0.2-0.9 m away, a posture
    task, joint ranges and speed limits: the speed limits bind."""
    if name == "arm":
        task = batch.PositionTask(robots, "end_effector", "site", axes="xy", gain=50.0)
        radius, angle = rng.uniform(0.9, 1.6, N), rng.uniform(0.3, 2.8, N)
        task.set_target(np.column_stack([radius * np.cos(angle), radius * np.sin(angle)]))
        speeds = None
    else:
        robots.set_q(PUSHER_START)
        task = batch.PositionTask(robots, "tips_arm", "body", gain=20.0)
        task.set_target(np.column_stack([rng.uniform(0.2, 1.0, N), rng.uniform(-0.9, 0.3, N),
                                         rng.uniform(-0.6, 0.4, N)]))
        speeds = np.full(robots.nv, 1.5)
    limits = [batch.JointPositionLimit(robots), batch.JointVelocityLimit(robots, speeds)]
    return batch.QPController(robots, [task, batch.PostureTask(robots, gain=1.0, weight=1e-3)], limits, dt=DT)


@pytest.mark.parametrize("name", ["arm", "pusher"])
def test_the_engines_step_on_warp_worlds_follows_the_cpu_back_end_and_says_it_runs_on_the_host(name,
                                                                                                 pusher_model):
    def robots_on(backend, **options):
        if name == "pusher":
            return batch.Robot(pusher_model, N, name="pusher_arm", backend=backend, **options)
        return batch.Robot.load(name, N, backend=backend, **options)

    cpu_robots = robots_on("cpu")
    cpu = _problem(name, cpu_robots, np.random.default_rng(7))
    warp_robots = robots_on("warp", device="cpu")
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        warp = _problem(name, warp_robots, np.random.default_rng(7))
        bound_steps = 0
        for _ in range(STEPS):
            qdot = warp.compute_velocity()
            bound_steps += bool((np.isclose(qdot, warp.lb, rtol=0, atol=1e-12)
                                 | np.isclose(qdot, warp.ub, rtol=0, atol=1e-12)).any())
            warp_robots.integrate(qdot, DT)
            cpu_robots.integrate(cpu.compute_velocity(), DT)
    host_steps = [w for w in caught if issubclass(w.category, batch.HostStepWarning)]
    assert len(host_steps) == 1, [str(w.message) for w in caught]  # once per controller, none per step
    assert "run on the host" in str(host_steps[0].message) and host_steps[0].filename == __file__
    assert bound_steps > STEPS // 5  # the speed limits bound on many steps
    np.testing.assert_allclose(warp_robots.q, cpu_robots.q, rtol=0, atol=ROLLOUT_TOLERANCE[name])
    limits = warp_robots.joint_limits
    q = warp_robots.q[:, limits.qpos_index]
    assert (q >= limits.lower - 1e-9).all() and (q <= limits.upper + 1e-9).all()


def test_a_controller_on_the_cpu_back_end_gives_no_host_step_warning():
    robots = batch.Robot.load("arm", 2)
    with warnings.catch_warnings():
        warnings.simplefilter("error", batch.HostStepWarning)
        batch.QPController(robots, [batch.DampingTask(robots)], dt=DT).compute_velocity()


def test_an_infeasible_world_on_warp_worlds_is_named_and_the_others_are_solved():
    robots = batch.Robot.load("arm", 3, backend="warp", device="cpu")
    task = batch.PositionTask(robots, "end_effector", axes="xy", gain=500.0, hard=True)
    # the start read from a frame just made: the home keyframe's, as on the CPU back-end
    home = batch.PositionTask(batch.Robot.load("arm", 3), "end_effector", axes="xy").target
    np.testing.assert_allclose(task.target, home, rtol=0, atol=FLOAT32_KINEMATICS)
    task.set_target(task.target + np.array([[0.001, 0.0], [1.0, 0.0], [0.0, -0.001]]))
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", batch.HostStepWarning)
        controller = batch.QPController(robots, [task, batch.DampingTask(robots)],
                                        [batch.JointVelocityLimit(robots)], dt=DT)
    with pytest.raises(batch.WorldsFailed) as failed:
        controller.compute_velocity()
    assert failed.value.worlds.tolist() == [1]
    qdot = failed.value.qdot
    assert not qdot[1].any() and np.isfinite(qdot).all() and np.abs(qdot[[0, 2]]).max() > 0.1


def test_physics_on_the_device_follows_mujoco():
    m = qpik.Robot.load("arm").model
    backend = WarpBackend(m, 2, device="cpu")
    qpos = np.tile(qpik.Robot.load("arm").q, (2, 1))
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
        np.testing.assert_allclose(moved[w], data.qpos, atol=1e-4)  # float32 dynamics, 50 steps


def test_unknown_device_is_a_typed_error():
    with pytest.raises(InvalidInput, match="unknown Warp device 'cuda:7'"):
        batch.Robot.load("arm", 2, backend="warp", device="cuda:7")
