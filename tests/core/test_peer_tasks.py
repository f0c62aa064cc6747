"""The tasks and limits mink and pink added, each through the Task/Limit contract: their
Jacobians against finite differences, and one real rollout each."""

from __future__ import annotations

import mujoco
import numpy as np
import pytest

from qpik import (
    AccelerationLimit,
    AxisAlignTask,
    DampingTask,
    DofFreezingTask,
    FloatingBaseVelocityLimit,
    FrameTask,
    HierarchicalController,
    InvalidInput,
    JointVelocityLimit,
    KineticEnergyRegularizationTask,
    LookAtTask,
    ModelError,
    PositionTask,
    QPController,
    Robot,
    SNSController,
)

DT = 0.002


def generated_chain(n: int = 6, free_base: bool = False) -> Robot:
    """An n-hinge spatial chain (axes z, y, x in turn, links 0.2 m, masses decreasing
    along it), optionally on a free-floating base body; a site ``tip`` at its end."""
    bodies, closing = "", ""
    for i in range(n):
        axis = ("0 0 1", "0 1 0", "1 0 0")[i % 3]
        bodies += (f'<body name="b{i}" pos="0 0 0.2"><joint name="j{i}" axis="{axis}" range="-3 3"/>'
                   f'<geom type="capsule" size="0.02" fromto="0 0 0 0 0 0.2" mass="{2.0 / (i + 1):g}"/>')
        closing += "</body>"
    chain = f'{bodies}<site name="tip" pos="0 0 0.2"/>{closing}'
    if free_base:
        chain = (f'<body name="base"><freejoint name="root"/><geom type="box" size="0.1 0.1 0.05" mass="5"/>'
                 f'{chain}</body>')
    xml = f'<mujoco><compiler angle="radian"/><worldbody>{chain}</worldbody></mujoco>'
    robot = Robot(mujoco.MjModel.from_xml_string(xml))
    q = robot.q.copy()
    q[-n:] = np.linspace(0.3, -0.4, n)
    robot.set_q(q)
    robot.update_kinematics()
    return robot


def rollout(robot, controller, steps, dt=DT):
    """Integrate the controller's answers; the answers, one row per step."""
    answers = []
    for _ in range(steps):
        qdot = controller.compute_velocity().copy()
        answers.append(qdot)
        robot.integrate(qdot, dt)
    robot.update_kinematics()
    return np.array(answers)


# Central differences, eps 1e-6, of unit vectors on a 1 m chain: truncation ~eps² times
# the curvature (~10), rounding ~1e-16/eps: both far below 1e-7.
FD_TOLERANCE = 1e-7


@pytest.mark.parametrize("free_base", [False, True])
def test_look_at_jacobian_is_the_derivative_of_the_direction(free_base, finite_difference_jacobian):
    robot = generated_chain(free_base=free_base)
    task = LookAtTask(robot, "tip", axis=(1.0, 0.5, 0.2), gain=10.0)
    task.set_target([0.4, -0.3, 0.5])
    fd = finite_difference_jacobian(robot, task.measured)
    np.testing.assert_allclose(task.compute_jacobian(robot), fd, atol=FD_TOLERANCE)
    np.testing.assert_allclose(task.compute_error(robot), task.axis - task.measured(), atol=0)


@pytest.mark.parametrize("free_base", [False, True])
def test_axis_align_jacobian_is_the_derivative_of_the_direction(free_base, finite_difference_jacobian):
    robot = generated_chain(free_base=free_base)
    task = AxisAlignTask(robot, "tip", axis=(0.0, 1.0, 1.0), gain=10.0)
    task.set_target([0.2, -1.0, 0.3])
    fd = finite_difference_jacobian(robot, task.measured)
    np.testing.assert_allclose(task.compute_jacobian(robot), fd, atol=FD_TOLERANCE)


def world_axis_and_line_of_sight(robot, task):
    rotation = robot.frame_rotation(task.frame)
    sight = task.point - robot.frame_position(task.frame)
    return rotation @ task.axis, sight / np.linalg.norm(sight)


@pytest.mark.parametrize("kind", ["qp", "hqp"])
def test_look_at_points_the_axis_at_the_target(kind):
    robot = generated_chain()
    task = LookAtTask(robot, "tip", axis=(0.0, 0.0, 1.0), gain=50.0)
    task.set_target([0.5, 0.4, 0.3])
    axis, sight = world_axis_and_line_of_sight(robot, task)
    assert axis @ sight < 0.5  # starts more than 60° off
    damping = DampingTask(robot, weight=1e-4)
    controller = (QPController(robot, [task, damping], dt=DT) if kind == "qp"
                  else HierarchicalController(robot, [task, damping.__class__(robot, weight=1e-4)], dt=DT))
    rollout(robot, controller, 1500)
    axis, sight = world_axis_and_line_of_sight(robot, task)
    # An independent check (the world axis against the line of sight), not the task's own error.
    assert np.degrees(np.arccos(min(1.0, axis @ sight))) < 1e-4
    assert np.linalg.norm(task.compute_error(robot)) < 1e-6


def test_axis_align_aligns_the_axis_and_leaves_the_roll_free():
    robot = generated_chain()
    align = AxisAlignTask(robot, "tip", axis=(0.0, 0.0, 1.0), gain=50.0)
    goal = np.array([1.0, -1.0, 0.5]) / np.linalg.norm([1.0, -1.0, 0.5])
    align.set_target(goal)
    controller = QPController(robot, [align, DampingTask(robot, weight=1e-4)], dt=DT)
    rollout(robot, controller, 1500)
    np.testing.assert_allclose(robot.frame_rotation(align.frame) @ align.axis, goal, atol=1e-6)
    # Rank 2: the rows have no component along the axis (the roll is free).
    assert np.linalg.matrix_rank(align.compute_jacobian(robot), tol=1e-9) == 2


@pytest.mark.parametrize("kind", ["qp", "hqp", "sns"])
def test_dof_freezing_keeps_the_listed_joints_still_while_a_task_moves_the_others(kind):
    robot = generated_chain()
    frozen = DofFreezingTask(robot, ["j1", "j3"])
    assert frozen.joint_space and frozen.hard
    np.testing.assert_array_equal(frozen.dofs, [1, 3])
    np.testing.assert_array_equal(frozen.jacobian, np.eye(robot.nv)[[1, 3]])
    reach = PositionTask(robot, "tip", gain=20.0)
    reach.priority = 1
    reach.set_target(reach.target + [0.05, -0.08, -0.05])
    q0 = robot.q.copy()
    damping = DampingTask(robot, weight=1e-4)
    damping.priority = 2
    controllers = {"qp": lambda: QPController(robot, [frozen, reach, damping], dt=DT),
                   "hqp": lambda: HierarchicalController(robot, [frozen, reach, damping], dt=DT),
                   "sns": lambda: SNSController(robot, [frozen, reach], dt=DT)}
    start = np.linalg.norm(reach.compute_error(robot))
    answers = rollout(robot, controllers[kind](), 1000)
    # Equality rows met by an exact solve: q̇_i of order the rounding of the others
    # (~1e-16 · |q̇|), so the frozen joints drift by far less than 1e-12 rad in 2 s.
    assert np.abs(answers[:, [1, 3]]).max() < 1e-12
    np.testing.assert_allclose(robot.q[[1, 3]], q0[[1, 3]], atol=1e-12, rtol=0)
    assert np.abs(robot.q - q0).max() > 0.05  # the others moved
    assert np.linalg.norm(reach.compute_error(robot)) < 1e-3 * start


def test_dof_freezing_needs_joints():
    robot = generated_chain()
    with pytest.raises(InvalidInput, match="name the joints"):
        DofFreezingTask(robot, [])


def test_kinetic_energy_rows_give_mujocos_kinetic_energy():
    robot = generated_chain(free_base=True)
    task = KineticEnergyRegularizationTask(robot, weight=1.0)
    jacobian = task.compute_jacobian(robot)
    qdot = np.random.default_rng(3).normal(size=robot.nv)
    # Independent reference: MuJoCo's own kinetic energy of the state (mj_energyVel).
    data = mujoco.MjData(robot.model)
    data.qpos[:] = robot.q
    data.qvel[:] = qdot
    robot.model.opt.enableflags |= mujoco.mjtEnableBit.mjENBL_ENERGY
    mujoco.mj_forward(robot.model, data)
    np.testing.assert_allclose(0.5 * np.sum((jacobian @ qdot) ** 2), data.energy[1], rtol=1e-10)
    np.testing.assert_array_equal(task.target_velocity, 0.0)


def kinetic_energy(robot, qdot) -> float:
    inertia = np.zeros((robot.nv, robot.nv))
    mujoco.mj_crb(robot.model, robot.data)
    mujoco.mj_fullM(robot.model, robot.data, inertia)
    return 0.5 * float(qdot @ inertia @ qdot)


def test_kinetic_energy_regularization_gives_the_inertia_weighted_minimum_norm_step():
    robot = generated_chain()
    reach = PositionTask(robot, "tip", gain=20.0, hard=True)
    reach.set_target(reach.target + [0.05, -0.05, 0.02])
    plain = QPController(robot, [reach], dt=DT).compute_velocity().copy()
    weighted = QPController(robot, [reach, KineticEnergyRegularizationTask(robot, weight=1.0)],
                            dt=DT).compute_velocity().copy()
    # Reference: M⁻¹Jᵀ(J M⁻¹ Jᵀ)⁻¹ v from MuJoCo's inertia matrix.
    inertia = np.zeros((robot.nv, robot.nv))
    mujoco.mj_crb(robot.model, robot.data)
    mujoco.mj_fullM(robot.model, robot.data, inertia)
    J, v = reach.jacobian, reach.target_velocity
    MinvJt = np.linalg.solve(inertia, J.T)
    reference = MinvJt @ np.linalg.solve(J @ MinvJt, v)
    np.testing.assert_allclose(weighted, reference, rtol=1e-7, atol=1e-10)
    np.testing.assert_allclose(J @ weighted, v, atol=1e-10)
    assert kinetic_energy(robot, weighted) < 0.9 * kinetic_energy(robot, plain)


def test_kinetic_energy_regularization_lowers_the_energy_of_a_rollout():
    energies, errors = {}, {}
    for regularized in (False, True):
        robot = generated_chain()
        reach = PositionTask(robot, "tip", gain=20.0)
        reach.set_target(reach.target + [-0.08, 0.06, -0.1])  # within reach of the near-upright chain
        tasks = [reach, DampingTask(robot, weight=1e-6)]
        if regularized:
            tasks.append(KineticEnergyRegularizationTask(robot, weight=1e-3))
        controller = QPController(robot, tasks, dt=DT)
        total = 0.0
        for _ in range(500):
            qdot = controller.compute_velocity()
            total += kinetic_energy(robot, qdot) * DT
            robot.integrate(qdot, DT)
        robot.update_kinematics()
        energies[regularized], errors[regularized] = total, np.linalg.norm(reach.compute_error(robot))
    assert energies[True] < 0.8 * energies[False]  # 0.019 against 0.043 J·s when written
    assert errors[True] < 1e-6 and errors[False] < 1e-6  # the task still met


def test_kinetic_energy_regularization_is_a_cost():
    with pytest.raises(InvalidInput, match="hard"):
        KineticEnergyRegularizationTask(generated_chain(), hard=True)


def base_speeds(answers: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    return np.abs(answers[:, 0:3]).max(axis=0), np.abs(answers[:, 3:6]).max(axis=0)


def test_floating_base_limit_bounds_the_base_where_a_joint_limit_did_not():
    peaks = {}
    for bounded in (False, True):
        robot = generated_chain(3, free_base=True)
        hand = FrameTask(robot, "tip")  # dead-beat: a far pose asked for in one step
        hand.set_target([0.8, -0.5, 0.9], np.eye(3)[[1, 2, 0]])
        limits = [JointVelocityLimit(robot, {"j0": 5.0, "j1": 5.0, "j2": 5.0})]
        if bounded:
            limits.append(FloatingBaseVelocityLimit(robot, linear=[1.0, 1.0, 0.5], angular=2.0))
        controller = QPController(robot, [hand, DampingTask(robot, weight=1e-3, joints=["root", "j0", "j1", "j2"])],
                                  limits, dt=DT)
        answers = rollout(robot, controller, 400)
        assert np.abs(answers[:, 6:]).max() <= 5.0 + 1e-9
        peaks[bounded] = base_speeds(answers)
    linear, angular = peaks[False]
    assert linear.max() > 50.0 and angular.max() > 50.0  # the joint-wise limit left the base free
    linear, angular = peaks[True]
    assert np.all(linear <= np.array([1.0, 1.0, 0.5]) + 1e-9) and np.all(angular <= 2.0 + 1e-9)
    assert linear.max() > 0.99  # it did move, at the bound


def test_floating_base_limit_needs_a_free_joint():
    with pytest.raises(ModelError, match="no free joint"):
        FloatingBaseVelocityLimit(generated_chain(), linear=1.0)
    robot = generated_chain(free_base=True)
    with pytest.raises(InvalidInput, match="not a free joint"):
        FloatingBaseVelocityLimit(robot, linear=1.0, joint="j0")
    with pytest.raises(InvalidInput, match="positive"):
        FloatingBaseVelocityLimit(robot, linear=-1.0)


def jumping_rollout(robot, controller, reach, steps):
    """Answers while the target jumps 10 cm every 0.1 s (a step the dead-beat gain asks
    to cover in one period)."""
    base = reach.target.copy()
    answers = []
    for k in range(steps):
        if k % 50 == 0:
            reach.set_target(base + (0.1 if (k // 50) % 2 else -0.1) * np.array([1.0, -0.5, 0.3]))
        qdot = controller.compute_velocity().copy()
        answers.append(qdot)
        robot.integrate(qdot, DT)
    return np.array(answers)


@pytest.mark.parametrize("kind", ["qp", "hqp", "sns"])
def test_acceleration_limit_bounds_every_change_of_velocity(kind):
    amax = 20.0  # rad/s²: aΔt = 0.04 rad/s per step
    changes = {}
    for limited in (False, True):
        robot = generated_chain()
        reach = PositionTask(robot, "tip")
        limits = [AccelerationLimit(robot, amax)] if limited else []
        tasks = [reach, DampingTask(robot, weight=1e-4)]
        build = {"qp": lambda: QPController(robot, tasks, limits, dt=DT),
                 "hqp": lambda: HierarchicalController(robot, tasks, limits, dt=DT),
                 "sns": lambda: SNSController(robot, [reach], limits, dt=DT)}[kind]
        answers = jumping_rollout(robot, build(), reach, 300)
        steps = np.vstack([answers[:1], np.diff(answers, axis=0)])  # starts at rest
        changes[limited] = np.abs(steps).max()
    # The box is around (q_k ⊖ q_{k−1})/Δt, the last command to rounding (~|q|·1e-16/Δt).
    assert changes[True] <= amax * DT + 1e-9
    assert changes[False] > 10 * amax * DT  # without it the jumps are far larger


def test_acceleration_limit_reset_and_bad_input():
    robot = generated_chain()
    limit = AccelerationLimit(robot, 10.0)
    lb, ub = np.full(robot.nv, -np.inf), np.full(robot.nv, np.inf)
    limit.reset(np.full(robot.nv, 1.0))
    limit.apply(DT, lb[None], ub[None])  # the box of the robot's one world, (1, nv) views
    np.testing.assert_allclose(ub, 1.0 + 10.0 * DT)
    np.testing.assert_allclose(lb, 1.0 - 10.0 * DT)
    with pytest.raises(InvalidInput, match="positive"):
        AccelerationLimit(robot, 0.0)
    with pytest.raises(InvalidInput, match="one per dof"):
        AccelerationLimit(robot, [1.0, 2.0])
