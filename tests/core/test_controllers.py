"""One control step of each controller, on real QP solvers, against closed forms."""

import numpy as np
import pytest

from qpik.robots.arm import model as arm
from qpik.errors import InfeasibleProblem, InvalidInput, UnknownName
from qpik.limits import JointPositionLimit, JointVelocityLimit
from qpik.controllers.pinv import JacobianTransposeController, PseudoinverseController
from qpik.controllers.qp import QPController
from qpik.robot import Robot
from qpik.solvers import available_solvers
from qpik.tasks import DampingTask, ManipulabilityTask, PositionTask, SigmaProxy, Yoshikawa

SOLVERS = available_solvers()


def _arm_at(q):
    robot = Robot.load("arm")
    robot.set_q(np.asarray(q, dtype=float))
    robot.update_kinematics()
    return robot


def _random_configurations(n, seed=0):
    rng = np.random.default_rng(seed)
    for _ in range(n):
        yield np.concatenate([rng.uniform(-2.0, 2.0, 3), rng.uniform(0.2, 0.8, 1)])


def _null_space_law(q, v, k0):
    """The source's law (docs/clik.md): q̇ = J†v + (I − J†J) k0 ∇σ with J† = Jᵀ(JJᵀ)⁻¹, from the DH formulas."""
    J = arm.position_jacobian(q)
    Jp = J.T @ np.linalg.inv(J @ J.T)
    return Jp @ v + (np.eye(4) - Jp @ J) @ (k0 * arm.sigma_gradient(q))


@pytest.mark.parametrize("solver", SOLVERS)
def test_qp_with_hard_task_equals_the_null_space_law(solver):
    for q in _random_configurations(5):
        robot = _arm_at(q)
        task = PositionTask(robot, "end_effector", axes="xy", gain=500.0, hard=True)
        p = arm.end_effector_position(q)
        task.set_target(p + [1e-4, -2e-4], [0.1, -0.05])
        manip = ManipulabilityTask(robot, SigmaProxy(robot, ["theta2", "theta3"]), gain=5.0)
        qp = QPController(robot, [task, manip], solver=solver, dt=0.002)
        expected = _null_space_law(q, np.array([0.1, -0.05]) + 500.0 * np.array([1e-4, -2e-4]), 5.0)
        np.testing.assert_allclose(qp.compute_velocity(), expected, atol=1e-6)
        pinv = PseudoinverseController(robot, [task], manip)
        np.testing.assert_allclose(pinv.compute_velocity(), expected, atol=1e-10)


@pytest.mark.parametrize("solver", SOLVERS)
def test_primary_only_qp_is_the_minimum_norm_solution(solver):
    for q in _random_configurations(3, seed=1):
        robot = _arm_at(q)
        task = PositionTask(robot, "end_effector", axes="xy", gain=500.0, hard=True)
        task.set_target(arm.end_effector_position(q), [0.2, 0.1])
        qp = QPController(robot, [task, DampingTask(robot, 1e-3)], solver=solver, dt=0.002)
        expected = np.linalg.pinv(arm.position_jacobian(q)) @ np.array([0.2, 0.1])
        np.testing.assert_allclose(qp.compute_velocity(), expected, atol=1e-6)


# qpsolvers' OSQP path converts to sparse and calls osqp.solve() without raise_error: the
# very overheads the native path avoids; their warnings are expected here.
@pytest.mark.filterwarnings("ignore:Converted matrix:UserWarning", "ignore:The default value of raise_error")
def test_native_and_qpsolvers_paths_agree():
    q = np.array([1.2, -0.4, 0.3, 0.5])
    for solver in ("daqp", "osqp", "proxqp"):
        results = []
        for native in (True, False):
            robot = _arm_at(q)
            task = PositionTask(robot, "end_effector", axes="xy", gain=500.0)
            task.set_target(arm.end_effector_position(q) + 1e-3, [0.3, 0.0])
            manip = ManipulabilityTask(robot, SigmaProxy(robot, ["theta2", "theta3"]), gain=5.0)
            limits = [JointPositionLimit(robot), JointVelocityLimit(robot, np.full(4, 0.3))]
            results.append(QPController(robot, [task, manip], limits, solver=solver, native=native, dt=0.002).compute_velocity())
        np.testing.assert_allclose(results[0], results[1], atol=1e-6)
        assert np.max(np.abs(results[0])) <= 0.3 + 1e-7  # a velocity bound is active here


def test_soft_task_with_velocity_limits_stays_in_bounds_and_reduces_error():
    q = np.array([np.pi / 2, 0.0, 0.0, 0.5])
    robot = _arm_at(q)
    task = PositionTask(robot, "end_effector", axes="xy", gain=500.0)
    task.set_target([2.0, 1.0])  # far: the unconstrained answer is huge
    qp = QPController(robot, [task, DampingTask(robot, 1e-3)], [JointVelocityLimit(robot)], solver="daqp", dt=0.002)
    qdot = qp.compute_velocity()
    assert np.all(np.abs(qdot) <= robot.velocity_limits + 1e-9)
    assert task.error @ (arm.position_jacobian(q) @ qdot) > 0  # moves toward the target


def test_position_limit_keeps_the_next_configuration_in_range():
    robot = _arm_at([np.pi / 2, 0.0, 0.0, 0.999])
    task = PositionTask(robot, "end_effector", axes="xy", gain=500.0)
    task.set_target([0.6, 2.0])  # pushes the ram outward, past d4 = 1
    qp = QPController(robot, [task, DampingTask(robot, 1e-3)], [JointPositionLimit(robot)], solver="daqp", dt=0.002)
    qdot = qp.compute_velocity()
    assert 0.999 + qdot[3] * 0.002 <= 1.0 + 1e-9



@pytest.mark.parametrize("influence", [0.01, 0.5])
def test_velocity_damper_never_steps_past_a_bound(influence):
    """rate/influence = 2000 1/s (influence 1 cm) exceeds the step limit gain/Δt = 500 1/s:
    the tighter of the two must hold, or the ram would step 1.5 cm past d4 = 1."""
    dt = 0.002
    robot = _arm_at([np.pi / 2, 0.0, 0.0, 0.995])
    limit = JointPositionLimit(robot, influence=influence, damper_rate=20.0)
    lb, ub = np.full(4, -8.0), np.full(4, 8.0)
    limit.apply(dt, lb[None], ub[None])  # one world's box
    assert 0.995 + ub[3] * dt <= 1.0
    assert ub[3] == pytest.approx(min(20.0 / influence, 1.0 / dt) * (1.0 - 1e-10 - 0.995), rel=1e-9)

def test_hard_task_against_limits_is_reported_infeasible():
    robot = _arm_at([np.pi / 2, 0.0, 0.0, 0.5])
    task = PositionTask(robot, "end_effector", axes="xy", gain=500.0, hard=True)
    task.set_target([0.6, 1.9])  # needs 50 m/s at K = 500; joints allow 8 rad/s
    for solver in ("daqp", "osqp", "proxqp"):
        qp = QPController(robot, [task, DampingTask(robot)], [JointVelocityLimit(robot)], solver=solver, dt=0.002)
        with pytest.raises(InfeasibleProblem):
            qp.compute_velocity()


def test_bad_inputs_raise_typed_errors():
    robot = _arm_at([np.pi / 2, 0.0, 0.0, 0.5])
    task = PositionTask(robot, "end_effector", axes="xy", gain=500.0, hard=True)
    with pytest.raises(InvalidInput):
        task.set_target([np.nan, 1.0])
    with pytest.raises(InvalidInput):
        task.set_target([1.0, 1.0, 1.0])
    with pytest.raises(InvalidInput):
        task.set_target([1.0, 1.0], [np.inf, 0.0])
    with pytest.raises(UnknownName):
        PositionTask(robot, "no_such_site")
    with pytest.raises(InvalidInput):
        PositionTask(robot, "end_effector", axes="xw")
    with pytest.raises(UnknownName):
        QPController(robot, [task], solver="no_such_solver", dt=0.002)
    with pytest.raises(InvalidInput):
        JointVelocityLimit(robot, np.array([1.0, -1.0, 1.0, 1.0]))
    with pytest.raises(InvalidInput):
        JointPositionLimit(robot, robot.joint_limits.tightened({"theta2": (1.0, 2.0)}), gain=0.0)
    with pytest.raises(InvalidInput):
        robot.joint_limits.tightened({"theta2": (1.0, -1.0)})


def test_yoshikawa_measure_and_gradient_match_dh_model():
    q = np.array([0.7, -0.9, 0.4, 0.6])
    robot = _arm_at(q)
    measure = Yoshikawa(robot, "end_effector", axes="xy")

    def w(qq):
        J = arm.position_jacobian(qq)
        return np.sqrt(np.linalg.det(J @ J.T))

    assert measure.value() == pytest.approx(w(q), rel=1e-12)
    grad = measure.gradient()[0]  # world 0 of (N, nv)
    fd = np.array([(w(q + e) - w(q - e)) / 2e-7 for e in np.eye(4) * 1e-7])
    np.testing.assert_allclose(grad, fd, atol=1e-6)
    # The full 3-row measure is zero on a planar arm: the reason for the axis mask.
    assert Yoshikawa(robot, "end_effector", axes="xyz").value() == pytest.approx(0.0, abs=1e-9)


def test_sigma_proxy_gradient_matches_formula():
    q = np.array([0.3, 1.1, -0.7, 0.4])
    robot = _arm_at(q)
    grad = SigmaProxy(robot, ["theta2", "theta3"]).gradient()[0]  # world 0 of (N, nv)
    np.testing.assert_allclose(grad, arm.sigma_gradient(q), atol=1e-15)
    assert SigmaProxy(robot, ["theta2", "theta3"]).value() == pytest.approx(arm.sigma(q))


def test_damped_least_squares_and_jacobian_transpose():
    q = np.array([0.9, 0.5, -0.3, 0.5])
    robot = _arm_at(q)
    task = PositionTask(robot, "end_effector", axes="xy", gain=500.0)
    task.set_target(arm.end_effector_position(q), [0.1, 0.2])
    J = arm.position_jacobian(q)
    lam = 0.3
    dls = PseudoinverseController(robot, [task], damping=lam).compute_velocity()
    np.testing.assert_allclose(dls, J.T @ np.linalg.solve(J @ J.T + lam**2 * np.eye(2), [0.1, 0.2]), atol=1e-12)
    jt = JacobianTransposeController(robot, [task], alpha=0.1).compute_velocity()
    np.testing.assert_allclose(jt, 0.1 * J.T @ [0.1, 0.2], atol=1e-12)
