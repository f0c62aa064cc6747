"""qpik.batch against the serial library: every batched task's rows equal its serial
twin's (same parameters, same target) on random states of several models, and every
world of a batched rollout equals a serial controller's rollout of that world, with
limits active — on the arm, the hexapod (loop closures hard) and a third-party 7-DoF arm."""

from __future__ import annotations

import numpy as np
import pytest

import qpik
from qpik import batch
from qpik.errors import ModelError
from qpik.models import pusher_arm

DT = 0.002
PUSHER_SPEED = 2.0  # rad/s, every joint of the pusher arm (its MJCF declares none)


def random_states(robots, rng, spread: float) -> np.ndarray:
    """Configurations around each world's start, inside the joint ranges."""
    model = robots.model
    q = np.tile(robots.q[0], (robots.n, 1))
    for i in range(robots.n):
        qpos = q[i].copy()
        import mujoco

        mujoco.mj_integratePos(model, qpos, rng.uniform(-spread, spread, robots.nv), 1.0)
        q[i] = qpos
    limits = robots.joint_limits
    inner = 1e-3 * (limits.upper - limits.lower)
    q[:, limits.qpos_index] = np.clip(q[:, limits.qpos_index], limits.lower + inner, limits.upper - inner)
    return q


def pusher_robots(n: int):
    try:
        model = pusher_arm()
    except ModelError as exc:
        pytest.skip(str(exc))
    robots = batch.Robot(model, n, name="pusher_arm")
    robots.set_q(np.array([0.2, 0.3, -0.2, -1.0, 0.3, -0.5, 0.2]))
    return robots


def check_rows(task, robots, world_robots, twins, tolerance=1e-12):
    task.update()
    for w, (robot, twin) in enumerate(zip(world_robots, twins)):
        twin.update()
        jac = twin.jacobian
        np.testing.assert_allclose(task.error[w], twin.error, rtol=0, atol=tolerance)
        np.testing.assert_allclose(task.target_velocity[w], twin.target_velocity, rtol=0, atol=tolerance * 1e3)
        batched_jac = task.jacobian if task.joint_space else task.jacobian[w]
        np.testing.assert_allclose(batched_jac, jac, rtol=0, atol=tolerance)


def twins_of(task, robots, dt=DT):
    world_robots = [robots.world(w) for w in range(robots.n)]
    twins = [task.serial_twin(r, w) for w, r in enumerate(world_robots)]
    for twin in twins:
        twin.attach(dt)
    return world_robots, twins


def _frame_tasks(robots, frame, frame_type, rng):
    tasks = [
        batch.FrameTask(robots, frame, frame_type, position_gain=300.0, orientation_gain=200.0),
        batch.FrameTask(robots, frame, frame_type, position_gain=300.0, orientation_gain=200.0,
                        position_axes="xz", orientation_axes="y", axes_frame="local"),
        batch.PositionTask(robots, frame, frame_type, axes="xy", gain=100.0),
        batch.PositionTask(robots, frame, frame_type, axes="yz", gain=100.0, axes_frame="local"),
        batch.OrientationTask(robots, frame, frame_type, axes="xz", gain=50.0),
        batch.OrientationTask(robots, frame, frame_type, gain=50.0, axes_frame="local"),
        batch.ComTask(robots, gain=20.0),
        batch.PostureTask(robots, gain=3.0),
        batch.DampingTask(robots),
    ]
    n = robots.n
    rotation = np.linalg.qr(rng.normal(size=(n, 3, 3)))[0]
    rotation *= np.sign(np.linalg.det(rotation))[:, None, None]
    tasks[0].set_target(rng.normal(size=(n, 3)), rotation, rng.normal(size=(n, 3)), rng.normal(size=(n, 3)))
    tasks[1].set_target(rng.normal(size=(n, 3)), rotation[::-1].copy())
    tasks[2].set_target(rng.normal(size=(n, 2)), rng.normal(size=(n, 2)))
    tasks[3].set_target(rng.normal(size=(n, 3)))
    tasks[4].set_target(rotation, rng.normal(size=(n, 3)))
    tasks[5].set_target(rotation[::-1].copy())
    tasks[6].set_target(rng.normal(size=(n, 3)))
    return tasks


@pytest.mark.parametrize("model", ["arm", "hexapod", "pusher"])
def test_every_batched_task_has_the_rows_of_its_serial_twin(model):
    rng = np.random.default_rng(7)
    n = 6
    if model == "pusher":
        robots, frame, frame_type = pusher_robots(n), "tips_arm", "body"
    else:
        robots = batch.Robot.load(model, n)
        frame, frame_type = ("end_effector", "site") if model == "arm" else ("platform_center", "site")
    tasks = _frame_tasks(robots, frame, frame_type, rng)
    if model == "arm":
        sigma = batch.SigmaProxy(robots, ["theta2", "theta3"])
        tasks.append(batch.ManipulabilityTask(robots, sigma, gain=5.0))
        tasks.append(batch.ManipulabilityTask(robots, sigma, gain=5.0, joints=["theta2", "theta3"]))
    if model == "hexapod":
        tasks.append(batch.EqualityTask(robots, gain=300.0))
        tasks.append(batch.RelativeFrameTask(robots, "platform_center", "leg1_tip", position_gain=10.0,
                                             orientation_gain=10.0))
    robots.set_q(random_states(robots, rng, 0.3))
    robots.ensure_kinematics()
    for task in tasks:
        task.attach(DT)
        check_rows(task, robots, *twins_of(task, robots))


def _closed_loop(controller, robots, twins_controllers, steps, move=None):
    for k in range(steps):
        if move is not None:
            move(k)
        qdot = controller.compute_velocity()
        robots.integrate(qdot, DT)
        for robot, serial in twins_controllers:
            robot.integrate(serial.compute_velocity(), DT)
    return max(float(np.abs(robots.q[w] - robot.q).max()) for w, (robot, _) in enumerate(twins_controllers))


def serial_controllers(robots, tasks, limits, **kwargs):
    robots.ensure_kinematics()
    out = []
    for w in range(robots.n):
        robot = robots.world(w)
        out.append((robot, qpik.QPController(robot, [t.serial_twin(robot, w) for t in tasks],
                                             [lim.serial_twin(robot, w) for lim in limits], dt=DT, **kwargs)))
    return out


def test_arm_worlds_equal_serial_controllers_after_one_second_with_limits_active():
    rng = np.random.default_rng(1)
    robots = batch.Robot.load("arm", 8)
    robots.set_q(random_states(robots, rng, 0.4))
    robots.ensure_kinematics()
    task = batch.PositionTask(robots, "end_effector", axes="xy", gain=500.0, lm_damping=10.0)
    task.set_target(rng.uniform(-2.2, 2.2, (robots.n, 2)))  # far: the limits bind
    sigma = batch.ManipulabilityTask(robots, batch.SigmaProxy(robots, ["theta2", "theta3"]), gain=5.0)
    limits = [batch.JointPositionLimit(robots, influence=0.1, damper_rate=2.0), batch.JointVelocityLimit(robots),
              batch.AccelerationLimit(robots, 400.0)]
    controller = batch.QPController(robots, [task, sigma], limits, dt=DT)
    serials = serial_controllers(robots, [task, sigma], limits)
    assert _closed_loop(controller, robots, serials, 500) <= 1e-9
    assert controller.qp.stats["active_set"] > 0  # limits were active on some steps


def test_hexapod_worlds_equal_serial_controllers_with_loops_closed():
    rng = np.random.default_rng(2)
    robots = batch.Robot.load("hexapod", 4)
    robots.ensure_kinematics()
    pose = batch.FrameTask(robots, "platform_center", position_gain=500.0, orientation_gain=500.0,
                           lm_damping=10.0)
    start = pose.target_position.copy()
    loops = batch.EqualityTask(robots, gain=500.0)
    damping = batch.DampingTask(robots, weight=1e-4, joints=robots.template.joint_names)
    limits = [batch.JointPositionLimit(robots), batch.JointVelocityLimit(robots)]
    offset = rng.uniform(-1, 1, (robots.n, 3)) * [0.25, 0.05, 0.03]  # x: past the strokes
    pose.set_target(start + offset, pose.target_rotation)
    controller = batch.QPController(robots, [pose, loops, damping], limits, dt=DT)
    serials = serial_controllers(robots, [pose, loops, damping], limits)
    assert _closed_loop(controller, robots, serials, 500) <= 1e-9
    residual = max(t.max_residual(r) for r, c in serials for t in c.tasks if isinstance(t, qpik.EqualityTask))
    assert residual < 1e-6  # the loops stayed closed
    assert controller.qp.stats["active_set"] + controller.qp.stats["daqp"] > 0


def test_pusher_arm_worlds_equal_serial_controllers_pose_and_posture():
    rng = np.random.default_rng(3)
    robots = pusher_robots(8)
    robots.set_q(random_states(robots, rng, 0.3))
    robots.ensure_kinematics()
    hand = batch.FrameTask(robots, "tips_arm", "body", position_gain=50.0, orientation_gain=50.0)
    start = hand.target_position.copy()
    hand.set_target(start + rng.uniform(-0.3, 0.3, (robots.n, 3)), hand.target_rotation)
    posture = batch.PostureTask(robots, gain=1.0, weight=1e-2)
    limits = [batch.JointPositionLimit(robots), batch.JointVelocityLimit(robots, np.full(7, PUSHER_SPEED))]
    controller = batch.QPController(robots, [hand, posture], limits, dt=DT)
    serials = serial_controllers(robots, [hand, posture], limits)
    assert _closed_loop(controller, robots, serials, 500) <= 1e-9
    assert controller.qp.stats["active_set"] > 0


def test_pseudoinverse_worlds_equal_the_serial_law():
    rng = np.random.default_rng(4)
    robots = batch.Robot.load("arm", 5)
    robots.set_q(random_states(robots, rng, 0.3))
    robots.ensure_kinematics()
    task = batch.PositionTask(robots, "end_effector", axes="xy", gain=500.0)
    task.set_target(task.target + rng.uniform(-0.05, 0.05, (robots.n, 2)))
    sigma = batch.ManipulabilityTask(robots, batch.SigmaProxy(robots, ["theta2", "theta3"]), gain=5.0)
    controller = batch.PseudoinverseController(robots, [task], sigma)
    serials = []
    for w in range(robots.n):
        robot = robots.world(w)
        serials.append((robot, qpik.PseudoinverseController(robot, [task.serial_twin(robot, w)],
                                                            sigma.serial_twin(robot, w))))
    assert _closed_loop(controller, robots, serials, 200) <= 1e-9


COUPLED = """
<mujoco>
  <compiler angle="radian"/>
  <worldbody>
    <body name="a">
      <joint name="j1" axis="0 0 1" range="-2 2"/>
      <geom type="capsule" size="0.05" fromto="0 0 0 1 0 0"/>
      <body name="b" pos="1 0 0">
        <joint name="j2" axis="0 1 0" range="-2 2"/>
        <geom type="capsule" size="0.05" fromto="0 0 0 1 0 0"/>
      </body>
    </body>
    <body name="c" pos="0 1 0">
      <joint name="j3" axis="1 0 0" range="-2 2"/>
      <geom type="capsule" size="0.05" fromto="0 0 0 0 0 1"/>
      <body name="d" pos="0 0 1">
        <joint name="j4" type="slide" axis="0 0 1" range="-1 1"/>
        <geom type="box" size="0.05 0.05 0.05"/>
      </body>
    </body>
  </worldbody>
  <equality>
    <joint joint1="j3" joint2="j1" polycoef="0.1 0.5 0.2 -0.3 0.05"/>
    <connect body1="b" body2="d" anchor="0.5 0 0"/>
    <joint joint1="j4" polycoef="0.2 0 0 0 0"/>
  </equality>
</mujoco>
"""


def test_joint_couplings_and_body_anchored_connects_have_the_rows_of_their_serial_twin():
    import mujoco

    robots = batch.Robot(mujoco.MjModel.from_xml_string(COUPLED), 5)
    rng = np.random.default_rng(11)
    robots.set_q(rng.uniform(-0.8, 0.8, (robots.n, robots.nq)))
    robots.ensure_kinematics()
    task = batch.EqualityTask(robots, gain=200.0)
    assert task.dim == 5  # 1 + 3 + 1 rows, in the equalities' order
    task.attach(DT)
    check_rows(task, robots, *twins_of(task, robots))
