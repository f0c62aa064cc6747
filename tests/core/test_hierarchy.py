"""HierarchicalController: one step against closed forms and independent QPs, rollouts
against the hard QP, and its typed errors."""

import numpy as np
import pytest
import qpsolvers

from qpik.app.runs import run
from qpik.controllers.hierarchy import HierarchicalController
from qpik.controllers.qp import QPController
from qpik.controllers.sns import SNSController
from qpik.errors import InfeasibleProblem, InvalidInput
from qpik.limits import JointPositionLimit, JointVelocityLimit
from qpik.robot import Robot
from qpik.robots.arm import model as arm
from qpik.robots.arm.planar import PlanarOrientationTask
from qpik.solvers import available_solvers
from qpik.tasks import DampingTask, ManipulabilityTask, PositionTask, PostureTask, SigmaProxy

SOLVERS = available_solvers()
EXACT = {"daqp", "quadprog"}

DT = 0.002  # s, the control period


def _arm_at(q):
    robot = Robot.load("arm")
    robot.set_q(np.asarray(q, dtype=float))
    robot.update_kinematics()
    return robot


def _configurations(n, seed=0):
    rng = np.random.default_rng(seed)
    for _ in range(n):
        yield np.concatenate([rng.uniform(-2.0, 2.0, 3), rng.uniform(0.2, 0.8, 1)])


def _position(robot, hard=True, offset=(1e-4, -2e-4), rate=(0.1, -0.05)):
    task = PositionTask(robot, "end_effector", axes="xy", gain=500.0, hard=hard)
    task.set_target(arm.end_effector_position(robot.q) + np.array(offset), rate)
    return task


@pytest.mark.parametrize("solver", SOLVERS)
def test_two_levels_equal_the_hard_qp_and_the_null_space_law(solver):
    """Position (hard) then σ: the hard QP, hence J†v + (I − J†J) k0∇σ with no limit active."""
    for q in _configurations(4):
        robot = _arm_at(q)
        position = _position(robot)
        sigma = ManipulabilityTask(robot, SigmaProxy(robot, ["theta2", "theta3"]), gain=5.0)
        sigma.priority = 1
        limits = [JointPositionLimit(robot), JointVelocityLimit(robot)]
        hqp = HierarchicalController(robot, [position, sigma], limits, solver=solver, dt=DT).compute_velocity()
        qp = QPController(robot, [position, sigma], limits, solver=solver, dt=DT).compute_velocity()
        J = arm.position_jacobian(q)
        J_pinv = J.T @ np.linalg.inv(J @ J.T)
        law = J_pinv @ position.target_velocity + (np.eye(4) - J_pinv @ J) @ (5.0 * arm.sigma_gradient(q))
        tolerance = 1e-9 if solver in EXACT else 1e-6
        np.testing.assert_allclose(hqp, qp, atol=tolerance)
        np.testing.assert_allclose(hqp, law, atol=tolerance)


@pytest.mark.parametrize("scenario", ["seed-primary", "seed-redundant"])
def test_hqp_rollout_equals_the_hard_qp_and_the_classical_law(scenario):
    hqp, qp, pinv = (run("arm", scenario, kind)[1] for kind in ("hqp", "qp", "pinv"))
    assert np.max(np.abs(hqp.q - qp.q)) <= 1e-9
    assert np.max(np.abs(hqp.q - pinv.q)) <= 1e-9
    summary = hqp.summary()
    assert summary.info.controller == "hqp" and summary.limit_violation_max == 0.0
    assert summary.levels.error_max[0] == pytest.approx(qp.summary().max_error, rel=1e-6)


def _recursive_law(jacobians, velocities):
    """q̇_k = q̇_{k−1} + (J_k P_{k−1})†(v_k − J_k q̇_{k−1}),
    P_k = P_{k−1} − (J_k P_{k−1})† J_k P_{k−1}: the prioritised pseudoinverse law (numpy's
    SVD pseudoinverse)."""
    qdot, P = np.zeros(jacobians[0].shape[1]), np.eye(jacobians[0].shape[1])
    for J, v in zip(jacobians, velocities):
        JP_pinv = np.linalg.pinv(J @ P, rcond=1e-10)
        qdot = qdot + JP_pinv @ (v - J @ qdot)
        P = P - JP_pinv @ J @ P
    return qdot


def test_four_levels_without_active_limits_are_the_prioritised_pseudoinverse_law():
    """x, then y, then φ, then a posture: four levels, each a task the levels above leave room
    for; with no limit active hqp and SNS both give the recursive law."""
    for q in _configurations(4, seed=3):
        robot = _arm_at(q)
        x = PositionTask(robot, "end_effector", axes="x", gain=500.0)
        y = PositionTask(robot, "end_effector", axes="y", gain=500.0)
        p = arm.end_effector_position(q)
        x.set_target(p[:1] + 1e-4, [0.1])
        y.set_target(p[1:] - 2e-4, [-0.05])
        phi = PlanarOrientationTask(robot, "end_effector", gain=10.0)
        phi.set_target(phi.angle() + 0.01)
        posture = PostureTask(robot, target=robot.q + 0.05, gain=1.0)
        for level, task in enumerate((x, y, phi, posture)):
            task.priority = level
        tasks = [posture, phi, y, x]  # order does not matter: priorities do
        hqp = HierarchicalController(robot, tasks, [JointPositionLimit(robot)], dt=DT).compute_velocity()
        sns = SNSController(robot, tasks, [JointPositionLimit(robot)], dt=DT).compute_velocity()
        for task in tasks:
            task.update()
        law = _recursive_law([t.jacobian for t in (x, y, phi, posture)],
                             [t.target_velocity for t in (x, y, phi, posture)])
        np.testing.assert_allclose(hqp, law, atol=1e-9)
        np.testing.assert_allclose(sns, law, atol=1e-12)


def test_explicit_levels_equal_priorities_and_keep_each_level_exact():
    robot = _arm_at([0.7, -0.6, 0.4, 0.5])
    position = _position(robot, hard=False)
    phi = PlanarOrientationTask(robot, "end_effector", gain=500.0)
    phi.set_target(phi.angle() + 0.3)  # wants 150 rad/s: far beyond the box
    sigma = ManipulabilityTask(robot, SigmaProxy(robot, ["theta2", "theta3"]), gain=5.0)
    limits = [JointPositionLimit(robot), JointVelocityLimit(robot)]
    by_levels = HierarchicalController(robot, levels=[[position], [phi], [sigma]], limits=limits, dt=DT)
    qdot = by_levels.compute_velocity().copy()
    position.priority, phi.priority, sigma.priority = 0, 1, 2
    np.testing.assert_allclose(HierarchicalController(robot, [sigma, phi, position], limits, dt=DT).compute_velocity(),
                               qdot, atol=1e-12)
    # Level 0 is met exactly; φ takes what the bounds leave; it is never traded for σ.
    np.testing.assert_allclose(position.jacobian @ qdot, position.target_velocity, atol=1e-10)
    assert np.all(qdot <= by_levels.ub + 1e-12) and np.all(qdot >= by_levels.lb - 1e-12)
    best_phi = _best_second_level(position.jacobian, position.target_velocity, phi.jacobian,
                                  phi.target_velocity, by_levels.lb, by_levels.ub)
    assert abs(phi.jacobian @ qdot - phi.target_velocity)[0] <= best_phi + 1e-7
    residuals = by_levels.report()["level_residual"]
    assert residuals[0] <= 1e-10 and residuals[1] == pytest.approx(best_phi, abs=1e-7)


def _best_second_level(J0, v0, J1, v1, lb, ub):
    """min ‖J1 q̇ − v1‖ s.t. J0 q̇ = v0, lb ≤ q̇ ≤ ub, with quadprog (another solver and
    another formulation than the hierarchy's)."""
    n = J0.shape[1]
    P = J1.T @ J1 + 1e-10 * np.eye(n)
    x = qpsolvers.solve_qp(P, -J1.T @ v1, A=J0, b=v0, lb=lb, ub=ub, solver="quadprog")
    return float(np.linalg.norm(J1 @ x - v1))


@pytest.mark.parametrize("solver", SOLVERS)
def test_dependent_rows_above_a_level_are_reduced(solver):
    """Path (2) + φ (1) + posture (4) above a damping level: 7 equality rows on 4 joints.
    Consistent but dependent: solvers that refuse them get a basis of their row space."""
    robot = _arm_at([0.9, -0.5, 0.6, 0.4])
    position = _position(robot, hard=False)
    phi = PlanarOrientationTask(robot, "end_effector", gain=50.0)
    phi.set_target(phi.angle() + 0.01)
    posture = PostureTask(robot, target=robot.q + 0.1, gain=2.0)
    damping = DampingTask(robot, weight=1.0)
    levels = [[position], [phi], [posture], [damping]]
    limits = [JointPositionLimit(robot), JointVelocityLimit(robot)]
    reference = HierarchicalController(robot, levels=levels, limits=limits, solver="daqp", dt=DT)
    reference = reference.compute_velocity().copy()
    qdot = HierarchicalController(robot, levels=levels, limits=limits, solver=solver, dt=DT).compute_velocity()
    np.testing.assert_allclose(qdot, reference, atol=1e-9 if solver in EXACT else 1e-5)
    np.testing.assert_allclose(position.jacobian @ qdot, position.target_velocity,
                               atol=1e-9 if solver in EXACT else 1e-5)


def test_an_infeasible_top_level_names_the_level():
    robot = _arm_at([np.pi / 2, 0.0, 0.0, 0.5])
    task = PositionTask(robot, "end_effector", axes="xy", gain=500.0, hard=True)
    task.set_target([0.6, 1.9])  # needs 50 m/s at K = 500; joints allow 8 rad/s
    posture = PostureTask(robot)
    posture.priority = 1
    for solver in ("daqp", "osqp", "quadprog"):
        hqp = HierarchicalController(robot, [task, posture], [JointVelocityLimit(robot)], solver=solver, dt=DT)
        with pytest.raises(InfeasibleProblem, match="level 0 .*position task"):
            hqp.compute_velocity()


def test_a_soft_top_level_is_never_infeasible():
    """The same impossible target as a least-squares level: the best velocity in the box."""
    robot = _arm_at([np.pi / 2, 0.0, 0.0, 0.5])
    task = PositionTask(robot, "end_effector", axes="xy", gain=500.0)
    task.set_target([0.6, 1.9])
    hqp = HierarchicalController(robot, [task], [JointVelocityLimit(robot)], dt=DT)
    qdot = hqp.compute_velocity()
    assert np.all(np.abs(qdot) <= robot.velocity_limits + 1e-12)
    assert task.error @ (task.jacobian @ qdot) > 0


def test_bad_hierarchies_are_typed_errors():
    robot = _arm_at([0.7, -0.6, 0.4, 0.5])
    position, posture = _position(robot), PostureTask(robot)
    with pytest.raises(InvalidInput, match="priority"):
        position.priority = -1
    for bad in (1.5, True, "0", None):
        with pytest.raises(InvalidInput, match="priority"):
            posture.priority = bad
    assert position.priority == 0 and posture.priority == 0  # unchanged by the refused values
    with pytest.raises(InvalidInput, match=r"listed twice \(level 0\)"):
        HierarchicalController(robot, [position, position], dt=DT)
    with pytest.raises(InvalidInput, match=r"listed twice \(levels 0 and 1\)"):
        HierarchicalController(robot, levels=[[position], [posture, position]], dt=DT)
    with pytest.raises(InvalidInput, match="level 1 is empty"):
        HierarchicalController(robot, levels=[[position], [], [posture]], dt=DT)
    with pytest.raises(InvalidInput, match="either tasks"):
        HierarchicalController(robot, [position], levels=[[position]], dt=DT)
    with pytest.raises(InvalidInput, match="at least one task"):
        HierarchicalController(robot, [], dt=DT)
    with pytest.raises(InvalidInput, match="another robot"):
        HierarchicalController(robot, [PostureTask(_arm_at([0.0, 0.0, 0.0, 0.5]))], dt=DT)
    with pytest.raises(InvalidInput, match="not a Task"):
        HierarchicalController(robot, levels=[[position], ["posture"]], dt=DT)
    with pytest.raises(InvalidInput, match="dt"):
        HierarchicalController(robot, [position], dt=0.0)
    with pytest.raises(InvalidInput, match="level 1 is empty"):  # the same grouping for SNS
        SNSController(robot, levels=[[position], []], dt=DT)
    for controller in (HierarchicalController, SNSController):  # no default period: the limits need it
        with pytest.raises(InvalidInput, match="dt is required"):
            controller(robot, [position])


def test_equal_priorities_share_a_level_and_are_weighed():
    """Two tasks of one priority form one least-squares level, weighed as in the QP."""
    robot = _arm_at([0.7, -0.6, 0.4, 0.5])
    position = _position(robot, hard=False)
    posture = PostureTask(robot, target=robot.q + 0.2, gain=1.0, weight=1e-2)
    hqp = HierarchicalController(robot, [position, posture], dt=DT).compute_velocity()
    qp = QPController(robot, [position, posture], regularization=1e-12, dt=DT).compute_velocity()
    np.testing.assert_allclose(hqp, qp, atol=1e-9)


def test_hexapod_hierarchy_closes_the_loops_first_and_equals_the_hard_qp():
    """Loops (level 0), platform pose (1), damping (2): every level hard or a minimum norm,
    as in the hexapod's QP, so the two give the same rollout."""
    hqp, qp = run("hexapod", "hexapod-circle", "hqp")[1], run("hexapod", "hexapod-circle", "qp")[1]
    assert hqp.levels.names == ("loops", "platform")
    assert np.max(np.abs(hqp.q - qp.q)) <= 1e-9
    assert hqp.summary().levels.error_max[0] <= 1e-6 and hqp.summary().limit_violation_max == 0.0
