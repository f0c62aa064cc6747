"""Promises every controller keeps on any robot: a returned step meets its hard rows, is
finite, and a typed error is raised only on a problem that is infeasible (checked by an
independent LP), with a message that names what to change.

The robots are small chains generated here (hinges about alternating axes), so each case
is a few lines and runs in milliseconds."""

from __future__ import annotations

import warnings

import mujoco
import numpy as np
import pytest
from scipy.optimize import linprog

from qpik import (ComTask, DampingTask, FrameTask, HierarchicalController, InfeasibleProblem, InvalidInput, JointPositionLimit,
                  JointVelocityLimit, PositionTask, PostureTask, QpikError, QPController, RelativeFrameTask, Robot)
from qpik.controllers.worlds import WorldSolver
from qpik.solvers import available_solvers

SOLVERS = [name for name in ("daqp", "osqp", "proxqp", "quadprog") if name in available_solvers()]
# The bar for a hard row: |J q̇ − v| <= 1e-9 (1 + |v|). The closed form and the
# active-set solvers meet it (their residual is a few ulps times cond(S) <= 1e12 · 1e-16
# only in the worst case the closed form still accepts, which is then rejected).
HARD_ROW_TOLERANCE = 1e-9


def chain(n: int, limited: bool = False) -> Robot:
    """An n-hinge serial chain, links 0.2 m, axes z, y, x in turn; a site at the tip and
    one ("mid") on the second body."""
    bodies, closing = "", ""
    for i in range(n):
        axis = ("0 0 1", "0 1 0", "1 0 0")[i % 3]
        limits = ' limited="true" range="-2 2"' if limited else ""
        site = '<site name="mid" pos="0 0 0.1"/>' if i == 1 else ""
        bodies += (f'<body name="b{i}" pos="0 0 0.2"><joint name="j{i}" axis="{axis}"{limits}/>'
                   f'<geom type="capsule" size="0.02" fromto="0 0 0 0 0 0.2" mass="1"/>{site}')
        closing += "</body>"
    xml = (f'<mujoco><compiler angle="radian"/><worldbody>{bodies}<site name="tip" pos="0 0 0.2"/>'
           f'{closing}</worldbody></mujoco>')
    return Robot(mujoco.MjModel.from_xml_string(xml))


def relative_miss(task, qdot: np.ndarray) -> float:
    v = task.target_velocity
    return float(np.abs(task.jacobian @ qdot - v).max()) / (1.0 + float(np.abs(v).max()))


def solver_answer(ctrl: QPController) -> np.ndarray:
    """The chosen solver's own answer to the controller's last problem (one robot), through
    the engine's per-world solve (taming, fallbacks, checks): the step wherever no closed
    form settles it (what ``fast_path=False`` returned before the closed form was always
    tried)."""
    qp = ctrl.world_qp(0)
    return WorldSolver(ctrl.solver, ctrl.robot.nv, len(qp.b), len(qp.h)).solve(0, qp)


class SolverOnly:
    """A QPController's steps through its solver alone (the closed form not taken)."""

    def __init__(self, robot, tasks, limits, **options):
        self.controller = QPController(robot, tasks, limits, **options)

    def compute_velocity(self) -> np.ndarray:
        self.controller.compute_velocity()
        return solver_answer(self.controller)


@pytest.mark.parametrize("seed", range(12))
def test_the_step_meets_the_hard_rows_beside_a_soft_task_with_its_own_jacobian(seed):
    """A 7-DoF chain, no limits: a hard tip position and a soft frame task on a middle body
    (its Jacobian makes H = JᵀWJ + εI, nearly singular). The closed form through H⁻¹ lost
    up to 3e-4 relative of the hard row here; the returned step must meet it to 1e-9, as
    the solver's own answer does."""
    rng = np.random.default_rng(seed)
    q = rng.uniform(-1.0, 1.0, 7)
    tip_target = rng.normal(0.0, 0.1, 3)
    body_target = rng.normal(0.0, 1.0, 3)
    robot = chain(7)
    robot.set_q(q)
    hard = PositionTask(robot, "tip", gain=10.0, hard=True)
    hard.set_target(hard.target + tip_target)
    soft = FrameTask(robot, "b3", frame_type="body", position_gain=10.0, orientation_gain=10.0)
    soft.set_target(body_target, np.eye(3))
    ctrl = QPController(robot, [hard, soft], dt=0.01)
    for qdot in (ctrl.compute_velocity().copy(), solver_answer(ctrl)):
        assert relative_miss(hard, qdot) <= HARD_ROW_TOLERANCE
        assert np.all(np.isfinite(qdot))


def contradictory_hard_tasks(robot: Robot):
    """Two hard position tasks on the same tip, with targets 10 cm apart: no q̇ meets both."""
    first = PositionTask(robot, "tip", gain=10.0, hard=True)
    second = PositionTask(robot, "tip", gain=10.0, hard=True)
    first.set_target(first.target + [0.1, 0.0, 0.0])
    second.set_target(second.target - [0.1, 0.0, 0.0])
    return [first, second, DampingTask(robot, weight=1e-3)]


@pytest.mark.parametrize("solver", SOLVERS)
def test_every_solver_reports_contradictory_hard_tasks_as_infeasible(solver):
    """quadprog returned a q̇ that missed both rows (its answers were never checked):
    every solver's answer goes through the same check, and the step is infeasible for
    all of them (an LP confirms it), from the controller (closed form tried first) and
    from the solver alone."""
    robot = chain(4)
    robot.set_q([0.3, 0.5, -0.4, 0.2])
    tasks = contradictory_hard_tasks(robot)
    ctrl = QPController(robot, tasks, dt=0.01, solver=solver)
    with pytest.raises(InfeasibleProblem):
        ctrl.compute_velocity()
    with pytest.raises(InfeasibleProblem):
        solver_answer(ctrl)
    A = np.vstack([tasks[0].jacobian, tasks[1].jacobian])
    b = np.concatenate([tasks[0].target_velocity, tasks[1].target_velocity])
    lp = linprog(np.zeros(robot.nv), A_eq=A, b_eq=b, bounds=[(None, None)] * robot.nv, method="highs")
    assert lp.status == 2  # infeasible


def test_an_infeasibility_message_names_the_frames_and_the_binding_limits():
    """Two hard position tasks of one kind were both "hard position task", and the limits
    that bind were named only by kind: the message names each task's frame and each
    binding bound with its value."""
    robot = chain(4)
    robot.set_q([0.3, 0.5, -0.4, 0.2])
    tip, mid = PositionTask(robot, "tip", gain=10.0, hard=True), PositionTask(robot, "mid", gain=10.0, hard=True)
    tip.set_target(tip.target + [0.1, 0.0, 0.0])
    mid.set_target(mid.target + [0.0, 0.1, 0.0])
    speed = JointVelocityLimit(robot, np.full(robot.nv, 0.01))
    with pytest.raises(InfeasibleProblem) as error:
        QPController(robot, [tip, mid, DampingTask(robot)], [speed], dt=0.01).compute_velocity()
    message = str(error.value)
    assert "'tip'" in message and "'mid'" in message
    assert "joint j0 at its" in message and "relax those limits" in message


def test_a_singular_infeasibility_does_not_ask_to_relax_unnamed_limits():
    """A straight chain cannot move its tip along itself: a hard task asking for it is
    infeasible with no limit in the way, and the message says so instead of "relax those
    limits" with none named."""
    robot = chain(3)
    robot.set_q([0.0, 0.0, 0.0])
    tip = PositionTask(robot, "tip", gain=10.0, hard=True)
    tip.set_target(tip.target + [0.0, 0.0, 0.1])
    limits = [JointVelocityLimit(robot, np.full(robot.nv, 5.0))]
    with pytest.raises(InfeasibleProblem) as error:
        QPController(robot, [tip, DampingTask(robot)], limits, dt=0.01).compute_velocity()
    message = str(error.value)
    assert "relax those limits" not in message and "singularity" in message and "'tip'" in message


CONTROLLERS = {
    "qp": lambda robot, tasks, limits: QPController(robot, tasks, limits, dt=0.01),
    "qp-solver": lambda robot, tasks, limits: SolverOnly(robot, tasks, limits, dt=0.01),
    "hqp": lambda robot, tasks, limits: HierarchicalController(robot, levels=[[t] for t in tasks], limits=limits,
                                                               dt=0.01),
}


def _target_setters(robot):
    """A target of ``value`` on each axis, for every task kind with a point target."""
    frame = FrameTask(robot, "tip", position_gain=10.0, orientation_gain=10.0)
    position = PositionTask(robot, "tip", gain=10.0)
    relative = RelativeFrameTask(robot, "tip", "mid", position_gain=10.0, orientation_gain=10.0)
    posture = PostureTask(robot, gain=10.0)
    return {
        "frame": (frame, lambda v: frame.set_target(np.full(3, v), np.eye(3))),
        "frame velocity": (frame, lambda v: frame.set_target(np.zeros(3), np.eye(3), linear_velocity=[v, 0, 0])),
        "position": (position, lambda v: position.set_target(np.full(3, v))),
        "relative": (relative, lambda v: relative.set_target(np.full(3, v), np.eye(3))),
        "posture": (posture, lambda v: posture.set_target(np.full(robot.nq, v))),
        "com": (None, lambda v: ComTask(robot, gain=10.0).set_target(np.full(3, v))),
    }


@pytest.mark.parametrize("kind", ["frame", "frame velocity", "position", "relative", "posture", "com"])
@pytest.mark.parametrize("controller", sorted(CONTROLLERS))
def test_a_target_whose_feedback_would_overflow_is_refused_when_set_without_a_warning(kind, controller):
    """A finite target of 1e308 (or 1e200) overflowed K·e to inf in the task's update: a
    RuntimeWarning every step (the any-robot fuzz counted them in every task kind), then
    an InvalidInput from the controller. Refused when set, with no warning; a far target
    of 1e100 is kept and every controller returns a finite step from it."""
    robot = chain(3)
    task, set_target = _target_setters(robot)[kind]
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        for huge in (1e308, 1e200):
            with pytest.raises(InvalidInput, match="magnitude|overflows"):
                set_target(huge)
        if task is None:
            return
        set_target(1e100)
        soft = [task, DampingTask(robot, weight=1e-6)]
        qdot = CONTROLLERS[controller](robot, soft, [JointVelocityLimit(robot, np.full(3, 1.0))]).compute_velocity()
    assert np.all(np.isfinite(qdot)) and np.max(np.abs(qdot)) <= 1.0 + 1e-9


@pytest.mark.parametrize("solver", SOLVERS)
@pytest.mark.parametrize("distance", [1e8, 1e15, 1e28])
def test_hierarchy_tames_a_far_soft_target_as_the_qp_does(solver, distance):
    """A soft tip target far out of reach: QPController returned a step with every solver,
    the hierarchy raised InfeasibleProblem (daqp), SolverError (proxqp, quadprog). Both
    now share the taming and the fallbacks: the step is finite, inside the box, and
    moves the tip toward the target (a vertex of the limits in the cost's direction)."""
    robot = chain(4, limited=True)
    robot.set_q([0.3, 0.5, -0.4, 0.2])
    tip = PositionTask(robot, "tip", gain=10.0)
    direction = np.ones(3) / np.sqrt(3.0)
    tip.set_target(tip.target + distance * direction)
    posture = PostureTask(robot, gain=1.0, weight=1e-3)
    limits = [JointPositionLimit(robot), JointVelocityLimit(robot, np.full(robot.nv, 2.0))]
    ctrl = HierarchicalController(robot, levels=[[tip], [posture]], limits=limits, dt=0.01, solver=solver)
    qdot = ctrl.compute_velocity()
    assert np.all(np.isfinite(qdot))
    assert np.all(qdot >= ctrl.lb - 1e-9) and np.all(qdot <= ctrl.ub + 1e-9)
    assert float(direction @ (tip.jacobian @ qdot)) > 0.1  # m/s toward the target


def test_hierarchy_polish_leaves_unbounded_dofs_free():
    """With two dofs' speeds bounded (one binding) and the others not, the polish counted every unbounded
    dof as "at its bound" (|x − (−inf)| <= inf): it multiplied inf by the Jacobian (a
    RuntimeWarning) and never polished. The polished level matches the QP with the same
    level alone (the same strictly convex problem; DAQP alone leaves ~1e-7)."""
    robot = chain(4)
    robot.set_q([0.3, 0.5, -0.4, 0.2])
    tip = PositionTask(robot, "tip", gain=10.0)
    tip.set_target(tip.target + [0.5, 0.3, 0.0])
    speed = JointVelocityLimit(robot, np.array([0.05, 10.0, np.inf, np.inf]))
    hierarchy = HierarchicalController(robot, [tip], [speed], dt=0.01)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        qdot = hierarchy.compute_velocity()
    assert abs(qdot[0]) == pytest.approx(0.05)  # the bound binds: the solver's step, polished
    alone = SolverOnly(robot, [tip], [speed], dt=0.01, regularization=1e-10)
    reference = alone.compute_velocity()
    assert np.allclose(tip.jacobian @ qdot, tip.jacobian @ reference, atol=1e-9)


@pytest.mark.parametrize("solver", SOLVERS)
def test_a_lower_level_is_never_infeasible_when_the_level_above_is_in_the_box(solver):
    """A tip target 1e13 m away with two joints unbounded: level 0 sits at a vertex of
    the box with 1e13 rad/s on the free joints, and the levels below (whose set holds
    level 0's velocity) were declared infeasible. Each step now returns a velocity in
    the box that keeps level 0's task velocity (to its scale, 1e-9 relative)."""
    robot = chain(5)
    robot.set_q([0.4, -0.6, 0.9, 0.3, -0.2])
    tip = PositionTask(robot, "tip", gain=20.0)
    tip.set_target(tip.target + 5.6e12 * np.array([0.6, -0.48, 0.64]))
    body = FrameTask(robot, "b0", frame_type="body", position_gain=5.0, orientation_gain=5.0)
    body.set_target([0.3, -0.2, 0.5], np.eye(3))
    posture = PostureTask(robot, gain=1.0, weight=1e-3)
    speed = JointVelocityLimit(robot, np.array([2.0, 2.8, 2.7, np.inf, np.inf]))
    # A short step: q stays within 1e10 (where MuJoCo resets a configuration, and qpik refuses it).
    ctrl = HierarchicalController(robot, levels=[[tip], [body], [posture]], limits=[speed], dt=1e-6, solver=solver)
    for _ in range(3):
        qdot = ctrl.compute_velocity()
        assert np.all(np.isfinite(qdot))
        assert np.all(qdot >= ctrl.lb) and np.all(qdot <= ctrl.ub)
        level0 = tip.jacobian @ ctrl.level_velocities[0]
        assert np.allclose(tip.jacobian @ qdot, level0, rtol=0.0, atol=1e-9 * (1.0 + np.abs(level0).max()))
        robot.integrate(qdot, 1e-6)


def test_a_com_target_whose_feedback_overflows_is_refused_without_a_warning():
    """A CoM target of 1e308 on one axis is finite, but K·(target − CoM) overflowed every
    step (RuntimeWarnings, then an inf velocity): refused when set, with no warning."""
    robot = chain(3)
    com = ComTask(robot, gain=10.0, axes="z")
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        with pytest.raises(InvalidInput, match="overflow"):
            com.set_target([1e308])
        com.set_target([1e140])  # far, but K·e stays finite
        com.update()
    assert np.all(np.isfinite(com.target_velocity))


@pytest.mark.parametrize("distance", [1e3, 1e12, 1e25])
def test_a_far_hard_target_is_not_blamed_on_the_limits_alone(distance):
    """A hard tip target far away within speed limits of 2 rad/s: the box alone is
    feasible (an LP agrees), yet the message said "the limits alone cannot be met
    together" (its elastic solve failed on the 1e19 cost). It names the task and the
    bounds the closest point sits on."""
    robot = chain(4, limited=True)
    robot.set_q([0.3, 0.5, -0.4, 0.2])
    tip = PositionTask(robot, "tip", gain=10.0, hard=True)
    tip.set_target(tip.target + distance)
    limits = [JointPositionLimit(robot), JointVelocityLimit(robot, np.full(robot.nv, 2.0))]
    ctrl = QPController(robot, [tip, DampingTask(robot)], limits, dt=0.01)
    with pytest.raises(InfeasibleProblem) as error:
        ctrl.compute_velocity()
    message = str(error.value)
    lp = linprog(np.zeros(robot.nv), bounds=np.column_stack([ctrl.lb, ctrl.ub]), method="highs")
    assert lp.status == 0  # the limits alone are feasible
    assert "limits alone" not in message
    assert "'tip'" in message and "speed limit" in message


def test_the_pseudoinverse_law_calls_a_diverged_step_an_error_before_anything_overflows():
    """The undamped law near a singularity (the any-robot fuzz: 1.8e16 rad/s at the first
    step, 8.7e214 five steps on) returned such speeds as answers until J Jᵀ overflowed in a
    RuntimeWarning. A speed beyond 1e100 is now a DivergenceError, before any warning; a
    target 1e140 m away asks for one."""
    from qpik import DivergenceError, PseudoinverseController

    robot = chain(3)
    robot.set_q([0.3, 0.5, -0.4])
    robot.update_kinematics()
    tip = PositionTask(robot, "tip", gain=1.0)
    tip.set_target(np.array([1e140, 0.0, 0.0]))
    ctrl = PseudoinverseController(robot, [tip])
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        with pytest.raises(DivergenceError, match="beyond"):
            ctrl.compute_velocity()
        tip.set_target(tip.frame.position + np.array([0.01, 0.0, 0.0]))
        assert np.all(np.isfinite(ctrl.compute_velocity()))


@pytest.mark.parametrize("solver", [s for s in ("daqp", "quadprog") if s in SOLVERS])
@pytest.mark.parametrize("seed", range(3))
def test_a_soft_target_far_beyond_the_hard_rows_scale_is_tamed_not_a_solver_error(solver, seed):
    """An 8-hinge chain without limits: a hard tip task near its target and a soft
    task on a middle body 1e8 m away, damping 1e-12. The soft cost (1e9 times H's scale
    after the first cap) drove |q̇| to ~1e8, where A q̇ cannot be computed to the hard
    rows' 1e-9: every solver's answer failed the check, a SolverError on a feasible step
    (any-robot fuzz cases 1047, 1258, 3486, 3586). The failed step is now solved with the
    cost capped harder: the hard rows met, the soft task still pulled toward its target."""
    rng = np.random.default_rng(seed)
    robot = chain(8)
    robot.set_q(rng.uniform(-1.0, 1.0, 8))
    robot.update_kinematics()
    tip = PositionTask(robot, "tip", gain=100.0, hard=True)
    tip.set_target(tip.frame.position + rng.normal(0.0, 0.01, 3))
    far = PositionTask(robot, "mid", gain=400.0, weight=10.0)
    far.set_target(rng.normal(0.0, 1e8, 3))
    ctrl = QPController(robot, [tip, far, DampingTask(robot, weight=1e-12)], solver=solver, dt=0.002)
    for qdot in (ctrl.compute_velocity().copy(), solver_answer(ctrl)):
        assert np.all(np.isfinite(qdot)) and relative_miss(tip, qdot) <= HARD_ROW_TOLERANCE
        assert float(np.dot(far.jacobian @ qdot, far.error)) > 0.0
