"""The warp back-end's device-resident step (QPController.step), on Warp's CPU device:
its kernels against the host code they restate (the same float32 kinematics: rows and
QPs to rounding) and against the serial tasks (float64 MuJoCo: to the float32
kinematics' precision); closed-loop rollouts against the host path and the CPU
back-end; the worlds the device leaves to the host; the fall-back to the host path for
tasks without a device kernel.
"""

from __future__ import annotations

import importlib.util
import subprocess
import sys
from pathlib import Path

import mujoco
import numpy as np
import pytest

pytest.importorskip("mujoco_warp", reason="the warp back-end needs the gpu extra (pip install -e \".[gpu]\")")

from qpik import batch  # noqa: E402
from qpik.batch.backends.cpu import _Integration  # noqa: E402
from qpik.batch.backends.warp_step import DeviceStep  # noqa: E402

_spec = importlib.util.spec_from_file_location("warp_rollouts", Path(__file__).with_name("warp_rollouts.py"))
rollouts = importlib.util.module_from_spec(_spec)
sys.modules.setdefault("warp_rollouts", rollouts)
_spec.loader.exec_module(rollouts)

N = 4
DT = rollouts.DT
# float32 kinematics against float64 MuJoCo (entries of ~1 m), as test_backend_warp.
FLOAT32_KINEMATICS = 2e-6
# The device kernels against the host code on the same float32 kinematics: both float64
# from there on, only the order of a few operations differs.
SAME_KINEMATICS = 1e-12
STEPS = 250
# q after 0.5 s against the CPU back-end (float64 kinematics), as test_backend_warp.
ROLLOUT_TOLERANCE = {"arm": 2e-6, "hexapod": 2e-5, "pusher": 1e-4}
FRAMES = {"arm": ("end_effector", "site"), "hexapod": ("platform_center", "site"), "pusher": ("tips_arm", "body")}
# A free-floating body carrying a ball-jointed link: the quaternion paths.
BALL_MODEL = """
<mujoco>
  <worldbody>
    <body name="base" pos="0 0 1">
      <freejoint/>
      <geom size="0.1" mass="1"/>
      <body name="link" pos="0 0 0.2">
        <joint name="ball" type="ball"/>
        <geom type="capsule" fromto="0 0 0 0.4 0 0" size="0.03" mass="0.5"/>
        <body name="tip" pos="0.4 0 0">
          <joint name="bend" type="hinge" axis="0 1 0" range="-2 2"/>
          <geom type="capsule" fromto="0 0 0 0.3 0 0" size="0.03" mass="0.3"/>
          <site name="tip" pos="0.3 0 0"/>
        </body>
      </body>
    </body>
  </worldbody>
</mujoco>
"""


def _robots(name: str, pusher_model, backend="warp"):
    options = {"device": "cpu"} if backend == "warp" else {}
    if name == "pusher":
        robots = batch.Robot(pusher_model, N, name="pusher_arm", backend=backend, **options)
        robots.set_q(rollouts.PUSHER_START)
        return robots
    if name == "ball":
        return batch.Robot(mujoco.MjModel.from_xml_string(BALL_MODEL), N, backend=backend, **options)
    return batch.Robot.load(name, N, backend=backend, **options)


def _random_states(robots, rng, spread=0.3) -> np.ndarray:
    """Configurations around the start (mj_integratePos, so quaternions stay unit),
    inside the joint ranges."""
    q = np.tile(robots.q[0], (robots.n, 1))
    for w in range(robots.n):
        mujoco.mj_integratePos(robots.model, q[w], rng.uniform(-spread, spread, robots.nv), 1.0)
    limits = robots.joint_limits
    if len(limits.names):
        inner = 1e-3 * (limits.upper - limits.lower)
        q[:, limits.qpos_index] = np.clip(q[:, limits.qpos_index], limits.lower + inner, limits.upper - inner)
    return q


def _every_device_task(robots, name, rng):
    """Every task kind the device step covers, masks and axes frames mixed, random targets."""
    frame, frame_type = FRAMES.get(name, ("tip", "site"))
    n = robots.n
    rotation = np.linalg.qr(rng.normal(size=(n, 3, 3)))[0]
    rotation *= np.sign(np.linalg.det(rotation))[:, None, None]
    tasks = [batch.FrameTask(robots, frame, frame_type, position_gain=300.0, orientation_gain=200.0, lm_damping=2.0),
             batch.FrameTask(robots, frame, frame_type, position_gain=30.0, orientation_gain=20.0, weight=[1, 2, 3, 4],
                             position_axes="xz", orientation_axes="yz", axes_frame="local", lm_damping=3e5),
             batch.PositionTask(robots, frame, frame_type, axes="xy", gain=100.0),
             batch.PositionTask(robots, frame, frame_type, axes="yz", gain=100.0, axes_frame="local"),
             batch.OrientationTask(robots, frame, frame_type, axes="xz", gain=50.0),
             batch.OrientationTask(robots, frame, frame_type, gain=50.0, axes_frame="local"),
             batch.PostureTask(robots, gain=3.0, weight=0.5),
             batch.DampingTask(robots, weight=1e-3)]
    tasks[0].set_target(rng.normal(size=(n, 3)), rotation, rng.normal(size=(n, 3)), rng.normal(size=(n, 3)))
    tasks[1].set_target(rng.normal(size=(n, 3)), rotation[::-1].copy(), rng.normal(size=(n, 3)),
                        rng.normal(size=(n, 3)))
    tasks[2].set_target(rng.normal(size=(n, 2)), rng.normal(size=(n, 2)))
    tasks[3].set_target(rng.normal(size=(n, 3)), rng.normal(size=(n, 3)))
    tasks[4].set_target(rotation, rng.normal(size=(n, 3)))
    tasks[5].set_target(rotation[::-1].copy(), rng.normal(size=(n, 3)))
    tasks[6].set_target(_random_states(robots, rng))
    if name == "hexapod":
        tasks.append(batch.EqualityTask(robots, gain=300.0, hard=False))
        tasks.append(batch.EqualityTask(robots, equalities=["loop4", "loop2"], gain=100.0))
    return tasks


class _Recorder:
    """Wraps a controller's QP solver and keeps the data of its last solve."""

    def __init__(self, qp):
        self.qp, self.last = qp, None

    def solve(self, H, c, A, b, lb, ub, active=None):
        self.last = {"H": np.array(H), "c": np.array(c), "A": np.array(A), "b": np.array(b), "lb": np.array(lb),
                     "ub": np.array(ub)}
        return self.qp.solve(H, c, A, b, lb, ub, active)


@pytest.mark.parametrize("name", ["arm", "hexapod", "pusher", "ball"])
def test_device_rows_equal_the_host_rows_and_the_serial_twins(name, pusher_model):
    rng = np.random.default_rng(11)
    robots = _robots(name, pusher_model)
    tasks = _every_device_task(robots, name, rng)
    limits = [batch.JointVelocityLimit(robots, np.full(robots.nv, 2.0))]
    if len(robots.joint_limits.names):
        limits.append(batch.JointPositionLimit(robots, influence=0.1, damper_rate=2.0))
    controller = batch.QPController(robots, tasks, limits, dt=DT)
    robots.set_q(_random_states(robots, rng))
    device = DeviceStep(robots.backend, controller)
    device.assemble()

    recorder = controller.qp = _Recorder(controller.qp)
    try:
        controller.compute_velocity()  # the host path on the same back-end: its rows, its QP
    except batch.WorldsFailed:
        pass
    world_robots = [robots.world(w) for w in range(N)]
    for task in tasks:
        error, jacobian, velocity = device.task_rows(task)
        scale = 1.0 + np.abs(task.target_velocity).max()
        np.testing.assert_allclose(error, task.error, rtol=0, atol=SAME_KINEMATICS)
        np.testing.assert_allclose(jacobian, task.jacobian, rtol=0, atol=SAME_KINEMATICS)
        np.testing.assert_allclose(velocity, task.target_velocity, rtol=0, atol=SAME_KINEMATICS * scale)
        gains = task.feedback_gains()
        gain = 1.0 if gains is None or not len(gains) else max(1.0, float(np.max(gains)))
        for w, robot in enumerate(world_robots):
            twin = task.serial_twin(robot, w)
            twin.attach(DT)
            twin.update()
            np.testing.assert_allclose(error[w], twin.error, rtol=0, atol=FLOAT32_KINEMATICS)
            twin_jacobian = twin.jacobian if not task.joint_space else twin.jacobian
            np.testing.assert_allclose(jacobian if task.joint_space else jacobian[w], twin_jacobian, rtol=0,
                                       atol=FLOAT32_KINEMATICS)
            np.testing.assert_allclose(velocity[w], twin.target_velocity, rtol=0, atol=FLOAT32_KINEMATICS * gain * 2)
    qp, host = device.qp_data(), recorder.last
    host_H = np.broadcast_to(host["H"], qp["H"].shape)
    scale = 1.0 + np.abs(host_H).max()
    np.testing.assert_allclose(qp["H"], host_H, rtol=0, atol=SAME_KINEMATICS * scale)
    np.testing.assert_allclose(qp["c"], host["c"], rtol=0, atol=SAME_KINEMATICS * (1.0 + np.abs(host["c"]).max()))
    np.testing.assert_allclose(qp["A"], host["A"], rtol=0, atol=SAME_KINEMATICS)
    np.testing.assert_allclose(qp["b"], host["b"], rtol=0, atol=SAME_KINEMATICS * (1.0 + np.abs(host["b"]).max(initial=0.0)))
    np.testing.assert_array_equal(qp["lb"], host["lb"])
    np.testing.assert_array_equal(qp["ub"], host["ub"])
    assert (qp["lb"] > -np.inf).any() and np.abs(host_H).max() > 1.0  # limits and soft tasks took part
    assert (device.lm_total.numpy() > 1e6).any()  # the controller's rescaling took part


def _pair(name, pusher_model, max_iterations=None):
    """Two identical warp controllers of warp_rollouts' problem: one steps on the
    device, the other on the host path."""
    out = []
    for _ in range(2):
        robots, controller = rollouts.controller(name, N, pusher_model, backend="warp", device="cpu")
        if max_iterations is not None:
            controller.qp = robots.backend.make_qp(robots.nv, controller.meq, max_iterations)
        out.append((robots, controller))
    return out


def _host_step(robots, controller):
    robots.integrate(controller.compute_velocity(), DT)


@pytest.mark.parametrize("name", ["arm", "hexapod", "pusher"])
def test_device_step_rollouts_equal_the_host_path_and_the_cpu_back_end(name, pusher_model):
    (robots, controller), (host_robots, host) = _pair(name, pusher_model)
    bound_steps = 0
    for _ in range(STEPS):
        controller.step()
        assert not len(controller.device_step.host_worlds)  # the device decided every world
        _host_step(host_robots, host)
        bound_steps += int(not host.result.closed_form.all())
    assert controller.step_path == "device" and not controller.device_step.captured  # no graphs on a CPU
    assert bound_steps > STEPS // 5  # the limits bound on many steps
    np.testing.assert_allclose(robots.q, host_robots.q, rtol=0, atol=1e-12)

    cpu_robots, cpu = rollouts.controller(name, N, pusher_model)
    reference = rollouts.rollout(cpu_robots, cpu, STEPS)
    np.testing.assert_allclose(robots.q, reference["q"][-1], rtol=0, atol=ROLLOUT_TOLERANCE[name])
    limits = robots.joint_limits
    q = robots.q[:, limits.qpos_index]
    assert (q >= limits.lower - 1e-9).all() and (q <= limits.upper + 1e-9).all()


def test_free_and_ball_joints_integrate_as_the_host():
    pair = []
    for _ in range(2):
        robots = _robots("ball", None)
        robots.set_q(_random_states(robots, np.random.default_rng(5)))
        tasks = [batch.FrameTask(robots, "tip", position_gain=50.0, orientation_gain=50.0),
                 batch.PostureTask(robots, target=robots.model.qpos0, gain=2.0, weight=0.1)]
        tasks[0].set_target(tasks[0].target_position + [0.2, -0.1, 0.3], tasks[0].target_rotation)
        limits = [batch.JointVelocityLimit(robots, np.full(robots.nv, 1.5)), batch.JointPositionLimit(robots)]
        pair.append((robots, batch.QPController(robots, tasks, limits, dt=DT)))
    (robots, controller), (host_robots, host) = pair
    integration = _Integration(robots.model)
    for _ in range(100):
        expected = robots.q.copy()
        controller.step()
        integration.apply(expected, controller.device_step.qdot(), DT)
        np.testing.assert_allclose(robots.q, expected, rtol=0, atol=1e-15)  # the device's mj_integratePos
        _host_step(host_robots, host)
    assert controller.step_path == "device"
    assert np.abs(robots.q - robots.model.qpos0).max() > 0.1
    # The two float64 states differ in their last bits (the quaternions' sin, cos and
    # norms), which now and then rounds a joint to the next float32 for the kinematics.
    np.testing.assert_allclose(robots.q, host_robots.q, rtol=0, atol=FLOAT32_KINEMATICS)
    for quat in (robots.q[:, 3:7], robots.q[:, 7:11]):
        np.testing.assert_allclose(np.linalg.norm(quat, axis=1), 1.0, atol=1e-15)


def test_worlds_the_device_does_not_settle_are_solved_by_daqp(pusher_model):
    # An active-set cap of one change: worlds where two bounds bind go to the host.
    (robots, controller), (host_robots, host) = _pair("pusher", pusher_model, max_iterations=1)
    handed = 0
    for _ in range(60):
        controller.step()
        handed += len(controller.device_step.host_worlds)
        _host_step(host_robots, host)
    assert handed > 0
    np.testing.assert_allclose(robots.q, host_robots.q, rtol=0, atol=1e-12)


def test_a_failing_world_keeps_its_configuration_and_is_named_as_by_the_host():
    (robots, controller), (host_robots, host) = _pair("arm", None)
    for k in range(3):
        targets = np.array([[1.0, 1.0], [1.2, 0.4], [0.5, 1.5], [0.8, 0.9]])
        if k == 2:
            targets[1, 0] = np.nan
        for ctrl in (controller, host):
            ctrl.tasks[0].set_target(targets)
        before = robots.q.copy()
        if k < 2:
            controller.step()
            host.step()
            continue
        with pytest.raises(batch.WorldsFailed) as device_failure:
            controller.step()
        with pytest.raises(batch.WorldsFailed) as host_failure:
            host.step()
    assert device_failure.value.worlds.tolist() == [1]
    assert device_failure.value.reasons == host_failure.value.reasons
    np.testing.assert_array_equal(robots.q[1], before[1])
    assert not device_failure.value.qdot[1].any()
    np.testing.assert_allclose(robots.q, host_robots.q, rtol=0, atol=1e-12)
    np.testing.assert_allclose(device_failure.value.qdot, host_failure.value.qdot, rtol=0, atol=1e-12)


def test_an_infeasible_world_is_reported_as_by_the_host():
    pair = []
    for _ in range(2):
        robots = batch.Robot.load("arm", 3, backend="warp", device="cpu")
        task = batch.PositionTask(robots, "end_effector", axes="xy", gain=400.0, hard=True)
        task.set_target(task.target + [[0.0, 1e-4], [0.5, 0.5], [1e-4, 0.0]])  # world 1: too far for the box
        limits = [batch.JointVelocityLimit(robots, np.full(4, 0.5)), batch.JointPositionLimit(robots)]
        pair.append((robots, batch.QPController(robots, [task, batch.DampingTask(robots)], limits, dt=DT)))
    (robots, controller), (host_robots, host) = pair
    with pytest.raises(batch.WorldsFailed) as device_failure:
        controller.step()
    with pytest.raises(batch.WorldsFailed) as host_failure:
        host.step()
    assert device_failure.value.worlds.tolist() == [1] == host_failure.value.worlds.tolist()
    assert "DAQP" in device_failure.value.reasons[1]
    assert device_failure.value.reasons == host_failure.value.reasons
    np.testing.assert_allclose(robots.q, host_robots.q, rtol=0, atol=1e-12)
    assert controller.device_step.host_worlds.tolist() == [1]


def test_tasks_without_a_device_kernel_step_on_the_host_and_say_so():
    pair = []
    for _ in range(2):
        robots = batch.Robot.load("arm", 3, backend="warp", device="cpu")
        task = batch.PositionTask(robots, "end_effector", axes="xy", gain=50.0)
        task.set_target(task.target + 0.1)
        sigma = batch.ManipulabilityTask(robots, batch.SigmaProxy(robots, ["theta2", "theta3"]), gain=5.0)
        pair.append((robots, batch.QPController(robots, [task, sigma], [batch.JointVelocityLimit(robots)], dt=DT)))
    (robots, controller), (host_robots, host) = pair
    with pytest.warns(batch.HostStepWarning, match="ManipulabilityTask has no device kernel"):
        controller.step()
    controller.step()  # said once
    for _ in range(2):
        _host_step(host_robots, host)
    assert controller.step_path == "host" and controller.device_step is None
    assert "ManipulabilityTask" in controller.host_step_reason
    np.testing.assert_array_equal(robots.q, host_robots.q)

    cpu_robots = batch.Robot.load("arm", 3)
    cpu = batch.QPController(cpu_robots, [batch.PostureTask(cpu_robots)], dt=DT)
    cpu.step()  # the CPU back-end: the host path, nothing to warn about
    assert cpu.step_path == "host" and "cpu back-end" in cpu.host_step_reason


def test_the_state_and_the_targets_cross_when_the_host_changes_them(pusher_model):
    (robots, controller), (host_robots, host) = _pair("pusher", pusher_model)
    task = controller.tasks[0]
    for k in range(6):
        if k == 2:  # the host moves the worlds: the device step starts from there
            for r in (robots, host_robots):
                r.set_q(rollouts.PUSHER_START + 0.05)
        if k == 4:  # a new target, given as the host path takes it
            for ctrl in (controller, host):
                ctrl.tasks[0].set_target(ctrl.tasks[0].target * 0.9)
        controller.step()
        _host_step(host_robots, host)
        np.testing.assert_allclose(robots.q, host_robots.q, rtol=0, atol=1e-12)
    with pytest.raises(ValueError, match="read-only"):
        task.target[0, 0] = 0.3  # the device step holds it: a write in place would be missed
    # The host path after device steps: its kinematics are refreshed.
    np.testing.assert_allclose(controller.compute_velocity(), host.compute_velocity(), rtol=0, atol=1e-12)


def test_a_device_step_of_an_unsupported_controller_is_refused_with_the_reason():
    robots = batch.Robot.load("arm", 2, backend="warp", device="cpu")
    controller = batch.QPController(robots, [batch.PostureTask(robots)], [batch.AccelerationLimit(robots, 10.0)],
                                    dt=DT)
    with pytest.raises(batch.NotBatched, match="AccelerationLimit has no device kernel"):
        DeviceStep(robots.backend, controller)


QP_BOUNDS_CHECK = """
import numpy as np
import warp

warp.config.mode = "debug"  # every array access checked: one outside aborts the process
from qpik.batch.backends.warp import WarpQP

rng = np.random.default_rng(0)
n_world, nv, meq = 64, 5, 2
M = rng.standard_normal((n_world, nv, nv))
H = M @ M.transpose(0, 2, 1) + 0.1 * np.eye(nv)
c = 3.0 * rng.standard_normal((n_world, nv))
A, b = rng.standard_normal((n_world, meq, nv)), rng.standard_normal((n_world, meq))
lb, ub = -rng.uniform(0.1, 1.0, (n_world, nv)), rng.uniform(0.1, 1.0, (n_world, nv))
result = WarpQP(n_world, nv, meq, device="cpu").solve(H, c, A, b, lb, ub)
print(int((result.status == 1).sum()), int(result.iterations))
"""


def test_the_device_qp_stays_inside_its_arrays():
    """With every bound and row active the method still forms the next row's column:
    its workspace holds n + 1 columns (it wrote past n before)."""
    done = subprocess.run([sys.executable, "-c", QP_BOUNDS_CHECK], capture_output=True, text=True, timeout=600)
    assert done.returncode == 0, done.stderr[-2000:]
    infeasible, iterations = map(int, done.stdout.split()[-2:])
    assert infeasible > 0 and iterations > 0  # worlds where the active set filled up
