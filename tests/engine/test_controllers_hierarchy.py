"""The engine's HierarchicalController: one robot's answers (steps, and every state of
rollouts with bounds held and solved, general rows, dependent rows above, the hexapod's
loops) equal the sequence of its levels' QPs solved independently, level by level
(tests/engine/references.py: each level's QP written out from the tasks' rows, the rows
above kept through an SVD basis of their row space, DAQP called directly and the active
set solved exactly); each of N = 4 worlds equals its own one-world run; typed errors name
the level and the failing worlds; its least-squares closed form against the KKT system
solved by NumPy."""

from __future__ import annotations

import importlib.util
from pathlib import Path

import mujoco
import numpy as np
import pytest

import qpik
import qpik.limits as engine_limits
import qpik.tasks as engine_tasks
from qpik.controllers import HierarchicalController
from qpik.errors import InfeasibleProblem, InvalidInput, UnknownName, WorldsFailed
from qpik.problem import DampedLeastSquares
from qpik.robots.arm.scenarios import ARM_START, SEED_PATH, TOO_FAST_SPEEDS, three_tasks_start
from qpik.trajectories import Segment

_spec = importlib.util.spec_from_file_location("references", Path(__file__).with_name("references.py"))
references = importlib.util.module_from_spec(_spec)
_spec.loader.exec_module(references)

DT = 0.002  # s
# One robot's q̇ equals the independent level-by-level solve to this relative to 1 + ‖q̇‖
# (rad/s): the same minimisers by other closed forms (held bounds or damped least squares
# over a world axis, against a null-space least-squares solve on DAQP's active set);
# speeds are ~1.
TOLERANCE = 1e-10
# A world of N equals its own one-world run to this, relative.
WORLD_TOLERANCE = 1e-10
# θ2, θ3 within ±0.55 rad from the three-tasks start (θ2 = −0.5, θ3 = 0.5): σ pushes both
# into their bounds at once, held at both levels within the first steps.
NARROW = {"theta2": (-0.55, 0.55), "theta3": (-0.55, 0.55)}


class _SlowSum(engine_limits.Limit):
    """One general row in every world: the joint velocities sum to at least −``total``."""

    inequality_rows = 1

    def __init__(self, total: float):
        self.total = total

    def apply(self, dt, lower, upper, G=None, h=None):
        G[:, 0], h[:, 0] = -1.0, self.total


def _arm(q=ARM_START) -> qpik.Robot:
    robot = qpik.Robot.load("arm")
    robot.set_q(np.asarray(q, dtype=float))
    robot.update_kinematics()
    return robot


def _configurations(count: int, seed: int = 0) -> np.ndarray:
    rng = np.random.default_rng(seed)
    return np.column_stack([rng.uniform(-2.0, 2.0, (count, 3)), rng.uniform(0.2, 0.8, count)])


def _path_and_sigma(robot, *, hard: bool = True, speeds=None, ranges=None, row: float | None = None, target=None,
                    rate=(0.1, -0.05)):
    """The arm's path level (x, y; hard, or soft with LM damping) over its σ level, with
    joint position limits (``ranges`` tightened) and speed limits (``speeds`` lowered),
    and a general row when ``row`` is given: (controller, position task, levels)."""
    position = engine_tasks.PositionTask(robot, "end_effector", axes="xy", gain=500.0, hard=hard,
                                         lm_damping=0.0 if hard else 10.0)
    if target is None:
        robot.ensure_kinematics()
        target = np.array(position.measured()) + [1e-4, -2e-4]
    position.set_target(target, rate)
    sigma = engine_tasks.ManipulabilityTask(robot, engine_tasks.SigmaProxy(robot, ("theta2", "theta3")), gain=5.0)
    sigma.priority = 1
    vmax = robot.velocity_limits.copy()
    for joint, speed in (speeds or {}).items():
        vmax[robot.joint_dof_index(joint)] = speed
    bounds = [engine_limits.JointPositionLimit(robot, robot.joint_limits.tightened(ranges or {}), influence=0.8,
                                               damper_rate=2.0), engine_limits.JointVelocityLimit(robot, vmax)]
    if row is not None:
        bounds.append(_SlowSum(row))
    return HierarchicalController(robot, [position, sigma], bounds, dt=DT), position, [[position], [sigma]]


def _close(a: np.ndarray, b: np.ndarray, tolerance: float = TOLERANCE) -> bool:
    return float(np.linalg.norm(a - b)) <= tolerance * (1.0 + float(np.linalg.norm(b)))


def _reference(controller, levels, world: int = 0):
    """Each level's velocity solved independently on the step's rows, box and general rows
    (the limits applied into fresh arrays)."""
    robot = controller.robot
    lower, upper, G, h = references.limits_box(controller.limits, DT, robot.n, robot.nv)
    return references.hierarchy_answers(levels, world, robot.nv, (lower[world], upper[world]), (G[world], h[world]))


def _assert_as_the_reference(controller, levels, tolerance: float = TOLERANCE) -> np.ndarray:
    """The step's answer and every level's velocity against the independent solve; the
    box against the limits'; each level's residual ‖J q̇ − v‖ (its rows) written out."""
    expected = _reference(controller, levels)
    qdot = np.array(controller.qdot)
    assert _close(qdot, expected[-1], tolerance), (qdot, expected[-1])
    for k, answer in enumerate(expected):
        assert _close(controller.level_velocities[k], answer, tolerance), (k, controller.level_velocities[k], answer)
    lower, upper, _, _ = references.limits_box(controller.limits, DT, 1, controller.robot.nv)
    np.testing.assert_array_equal(controller.lb, lower[0])
    np.testing.assert_array_equal(controller.ub, upper[0])
    residuals = []
    for level in levels:
        J, v = references.level_rows(level, 0)
        residuals.append(np.linalg.norm(J @ qdot - v))
    np.testing.assert_allclose(controller.report()["level_residual"], residuals, rtol=1e-8, atol=TOLERANCE)
    return qdot


SETUPS = {
    "hard path, sigma": {},
    "soft path, sigma": {"hard": False},
    "hard path, general row": {"row": 0.5},
    "soft path, slow joints": {"hard": False, "speeds": TOO_FAST_SPEEDS},
}


@pytest.mark.parametrize("setup", SETUPS)
def test_one_robot_equals_its_levels_solved_in_turn(setup):
    for q in _configurations(6):
        robot = _arm(q)
        controller, _, levels = _path_and_sigma(robot, **SETUPS[setup])
        qdot = controller.compute_velocity()
        assert qdot.shape == (4,) and controller.level_velocities.shape == (2, 4)
        _assert_as_the_reference(controller, levels)


# Where the general row binds, the soft path level (Hessian JᵀJ + ε, ε = 1e-10 along the
# dofs the path leaves free: a condition up to 6e10) is DAQP's answer at its default
# settings, which no closed form polishes there (a point held on a row would cross it by
# rounding): over this rollout it lies within 2.5e-9 (relative to 1 + ‖q̇‖) of the exact
# minimiser (the reference's, itself checked in rational arithmetic at the worst step), so
# 5e-9. (The old 1e-9 was judged against the serial hierarchy's DAQP answer, which shared
# that error.) Elsewhere answers are exact to rounding.
ROW_TOLERANCE = 5e-9
ROLLOUTS = {
    # σ drives θ2 and θ3 into ±0.55: bounds held in closed form at both levels.
    "bounds held": ({"ranges": NARROW}, three_tasks_start(), 5.0, TOLERANCE),
    # The path in 0.5 s with 1 rad/s joints: the soft path level and σ's both to the solver.
    "bounds solved": ({"hard": False, "speeds": TOO_FAST_SPEEDS}, ARM_START, 0.5, TOLERANCE),
    # The same, the joints' sum bounded by a general row.
    "general row": ({"hard": False, "speeds": TOO_FAST_SPEEDS, "row": 0.6}, ARM_START, 0.5, ROW_TOLERANCE),
}


@pytest.mark.parametrize("rollout", ROLLOUTS)
def test_every_state_of_a_rollout_is_answered_as_its_levels_solved_in_turn(rollout):
    """200 steps of the seed path from the scenario's start, limits binding: at every state
    of the rollout each level's velocity is its QP's minimiser."""
    options, start, duration, tolerance = ROLLOUTS[rollout]
    segment = Segment(SEED_PATH[0], SEED_PATH[1], duration, time_law="cubic")
    robot = _arm(start)
    controller, position, levels = _path_and_sigma(robot, target=SEED_PATH[0], rate=None, **options)
    at_bound = False
    for k in range(200):
        position.set_target(*segment.sample(k * DT))
        controller.compute_velocity()
        qdot = _assert_as_the_reference(controller, levels, tolerance)
        at_bound = bool(np.any(np.isclose(qdot, controller.lb, rtol=0, atol=1e-12) |
                               np.isclose(qdot, controller.ub, rtol=0, atol=1e-12)))
        robot.integrate(qdot, DT)
    assert at_bound  # a limit binds at the end


def test_dependent_rows_above_are_reduced_to_their_row_space():
    """Path (2) + φ (1) + posture (4) above a damping level: 7 equality rows on 4 joints,
    consistent but dependent: each level equals its QP with the rows above kept through a
    basis of their row space."""
    robot = _arm([0.9, -0.5, 0.6, 0.4])
    position = engine_tasks.PositionTask(robot, "end_effector", axes="xy", gain=500.0)
    position.set_target(np.array(position.measured()) + [1e-4, -2e-4], [0.1, -0.05])
    phi = engine_tasks.OrientationTask(robot, "end_effector", axes="z", gain=50.0)
    phi.set_target(robot.data.site("end_effector").xmat.reshape(3, 3) @ _rotation_z(0.01))
    posture = engine_tasks.PostureTask(robot, target=robot.q + 0.1, gain=2.0)
    levels = [[position], [phi], [posture], [engine_tasks.DampingTask(robot, weight=1.0)]]
    bounds = [engine_limits.JointPositionLimit(robot), engine_limits.JointVelocityLimit(robot)]
    controller = HierarchicalController(robot, levels=levels, limits=bounds, dt=DT)
    controller.compute_velocity()
    _assert_as_the_reference(controller, levels)
    assert controller.kept_above == 0  # every level solved (none kept the velocity above)
    above = np.vstack([references.level_rows(level, 0)[0] for level in levels[:3]])
    assert np.linalg.matrix_rank(above) == 4 < len(above)  # dependent indeed


def _rotation_z(angle: float) -> np.ndarray:
    c, s = np.cos(angle), np.sin(angle)
    return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])


def _worlds(count: int = 4, offset: float = 1e-3, seed: int = 1):
    """Different states (two near the narrow bounds) and targets ``offset`` m off their tips."""
    q = _configurations(count, seed)
    q[0], q[1] = three_tasks_start(), three_tasks_start(0.54)
    rng = np.random.default_rng(seed + 10)
    targets = [_path_and_sigma(_arm(qi))[1].measured() + rng.uniform(-offset, offset, 2) for qi in q]
    return q, np.array(targets)


def _batch(q: np.ndarray) -> qpik.batch.Robot:
    robots = qpik.batch.Robot.load("arm", n=len(q))
    robots.set_q(q)
    return robots


WORLD_SETUPS = {
    "hard path, narrow ranges": ({"ranges": NARROW}, 1e-3),
    "soft path, slow joints, general row": ({"hard": False, "speeds": TOO_FAST_SPEEDS, "row": 0.6}, 0.05),
}


@pytest.mark.parametrize("setup", WORLD_SETUPS)
def test_each_of_four_worlds_equals_its_own_one_world_run(setup):
    """N = 4 worlds of different states and targets, 20 steps with limits binding in some."""
    options, offset = WORLD_SETUPS[setup]
    q, targets = _worlds(offset=offset)
    robots = _batch(q)
    batch = _path_and_sigma(robots, target=targets, **options)[0]
    singles = [(robot, _path_and_sigma(robot, target=target, **options)[0])
               for robot, target in ((_arm(qi), ti) for qi, ti in zip(q, targets))]
    for _ in range(20):
        qdots = batch.compute_velocity()
        assert qdots.shape == (4, 4) and batch.level_velocities.shape == (4, 2, 4)
        for w, (robot, single) in enumerate(singles):
            qdot = single.compute_velocity()
            assert _close(qdots[w], qdot, WORLD_TOLERANCE)
            assert _close(batch.level_velocities[w], single.level_velocities, WORLD_TOLERANCE)
            robot.integrate(qdot, DT)
        robots.integrate(qdots, DT)
    assert batch.report()["level_residual"].shape == (4, 2)
    assert batch.kept_above == sum(single.kept_above for _, single in singles)


def test_an_infeasible_level_is_named_and_in_n_worlds_the_others_are_solved():
    """World 1's hard target needs 50 m/s at K = 500; the joints allow 8 rad/s."""
    q, targets = _worlds()
    targets[1] = _path_and_sigma(_arm(q[1]))[1].measured() + [0.1, -0.1]
    with pytest.raises(InfeasibleProblem, match="level 0 .*position task"):
        _path_and_sigma(_arm(q[1]), target=targets[1])[0].compute_velocity()
    batch = _path_and_sigma(_batch(q), target=targets)[0]
    with pytest.raises(WorldsFailed) as failed:
        batch.compute_velocity()
    assert failed.value.worlds.tolist() == [1]
    assert "InfeasibleProblem" in failed.value.reasons[1] and "level 0" in failed.value.reasons[1]
    np.testing.assert_array_equal(failed.value.qdot[1], 0.0)
    np.testing.assert_array_equal(batch.level_velocities[1], 0.0)
    for w in (0, 2, 3):
        single = _path_and_sigma(_arm(q[w]), target=targets[w])[0]
        assert _close(failed.value.qdot[w], single.compute_velocity(), WORLD_TOLERANCE)


_JOINTLESS = '<mujoco><worldbody><body name="block" pos="0 0 1"><geom size="0.1"/><site name="tip"/></body>' \
             '</worldbody></mujoco>'


def test_a_model_without_dofs_is_a_typed_error():
    robot = qpik.Robot(mujoco.MjModel.from_xml_string(_JOINTLESS))
    assert robot.nv == 0
    tip = engine_tasks.PositionTask(robot, "tip", gain=1.0, hard=True)
    with pytest.raises(InvalidInput, match="degree of freedom"):
        HierarchicalController(robot, [tip], dt=DT)


def test_bad_hierarchies_are_typed_errors():
    robot = _arm([0.7, -0.6, 0.4, 0.5])
    position = engine_tasks.PositionTask(robot, "end_effector", axes="xy", gain=500.0, hard=True)
    posture = engine_tasks.PostureTask(robot)
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
    with pytest.raises(InvalidInput, match="not a Task"):
        HierarchicalController(robot, levels=[[position], ["posture"]], dt=DT)
    with pytest.raises(InvalidInput, match="another robot"):
        HierarchicalController(robot, [engine_tasks.PostureTask(_arm())], dt=DT)
    for dt in (None, 0.0, np.nan, "fast"):
        with pytest.raises(InvalidInput, match="dt"):
            HierarchicalController(robot, [position], dt=dt)
    for regularization in (0.0, -1.0, np.nan, np.inf, 1e13):
        with pytest.raises(InvalidInput, match="regularization"):
            HierarchicalController(robot, [position], dt=DT, regularization=regularization)
    with pytest.raises(UnknownName, match="solver"):
        HierarchicalController(robot, [position], solver="no-such-solver", dt=DT)


def _kkt_solution(dinv, R, rhs, soft: int, c):
    """min ½‖R₁x − r₁‖² + ½xᵀDx + cᵀx s.t. R₂x = r₂ from its KKT system
    [[R₁ᵀR₁ + D, R₂ᵀ], [R₂, 0]] [x; λ] = [R₁ᵀr₁ − c; r₂], solved by NumPy's LU."""
    nv, rows = R.shape[1], R.shape[0] - soft
    R1, R2 = R[:soft], R[soft:]
    kkt = np.block([[R1.T @ R1 + np.diag(1.0 / dinv), R2.T], [R2, np.zeros((rows, rows))]])
    linear = np.zeros(nv) if c is None else c
    return np.linalg.solve(kkt, np.concatenate([R1.T @ rhs[:soft] - linear, rhs[soft:]]))[:nv], np.linalg.cond(kkt)


@pytest.mark.parametrize("form", ["epsilon", "joint-space tasks"])
def test_the_least_squares_closed_form_is_the_kkt_solution_in_every_world(form):
    """Random rows [R₁; R₂] (2 soft, 2 equality rows on 4 dofs) with D = ε = 1e-10 and no
    c (a level of soft tasks alone), or D in [0.1, 2] and a random c (joint-space tasks on
    every dof): each of 5 worlds equals its own one-world solve and the KKT system's
    solution (NumPy's LU: the error of a backward-stable solve, ε κ(KKT), below 1e-12
    here); a world with dependent equality rows that disagree is refused alone."""
    rng = np.random.default_rng(7)
    n, nv, soft, rows = 5, 4, 2, 2
    R = rng.normal(size=(n, soft + rows, nv))
    rhs = rng.normal(size=(n, soft + rows))
    R[3, soft + 1] = R[3, soft]  # world 3: dependent equality rows, which disagree
    if form == "epsilon":
        dinv, c = np.full((n, nv), 1e10), None
    else:
        dinv, c = 1.0 / rng.uniform(0.1, 2.0, (n, nv)), rng.normal(size=(n, nv))
    batch, _, ok = DampedLeastSquares(n, nv, soft, rows).solve(dinv, R, rhs, c)
    assert ok.tolist() == [True, True, True, False, True]
    one = DampedLeastSquares(1, nv, soft, rows)
    for w in (0, 1, 2, 4):
        cw = None if c is None else c[w:w + 1]
        x, _, solved = one.solve(dinv[w:w + 1], R[w:w + 1], rhs[w:w + 1], cw)
        assert solved[0] and _close(batch[w], x[0], WORLD_TOLERANCE)
        expected, condition = _kkt_solution(dinv[w], R[w], rhs[w], soft, None if c is None else c[w])
        assert condition * np.finfo(float).eps < 1e-12
        assert _close(x[0], expected)
        np.testing.assert_allclose(R[w, soft:] @ x[0], rhs[w, soft:], atol=1e-10)
    assert np.linalg.matrix_rank(R[3, soft:]) == 1  # world 3's rows: no point meets both


def test_the_hexapods_hierarchy_is_its_levels_solved_in_turn():
    """Loops (level 0), platform pose (1), damping (2) on the 6-PUS hexapod, 20 steps: at
    every state each level's velocity is its QP's minimiser, and the loops stay closed."""
    from qpik.robots.hexapod.control import HexapodModel

    robot = qpik.Robot.load("hexapod", keyframe="home")
    loops = engine_tasks.EqualityTask(robot, HexapodModel(robot).loop_names, gain=500.0)
    platform = engine_tasks.FrameTask(robot, "platform_center", position_gain=500.0, orientation_gain=500.0, hard=True)
    robot.ensure_kinematics()
    platform.set_target(robot.data.site("platform_center").xpos + [1e-4, 0.0, 0.0],
                        robot.data.site("platform_center").xmat.reshape(3, 3))
    damping = engine_tasks.DampingTask(robot, weight=1e-6, joints=robot.joint_names)
    levels = [[loops], [platform], [damping]]
    controller = HierarchicalController(
        robot, levels=levels, limits=[engine_limits.JointPositionLimit(robot), engine_limits.JointVelocityLimit(robot)],
        dt=DT)
    for _ in range(20):
        controller.compute_velocity()
        qdot = _assert_as_the_reference(controller, levels)
        robot.integrate(qdot, DT)
    assert loops.max_residual() < 1e-6  # (m): the loops closed to the linearisation's second order


def test_a_level_whose_rows_are_all_masked_is_solved():
    """Level 0 a position task of zero weights (every row masked), level 1 a posture: the
    empty level is solved (a hand-solved small system once raised an untyped ValueError on
    its zero rows) and leaves the posture to level 1."""
    robot = qpik.Robot.load("arm")
    posture = engine_tasks.PostureTask(robot, gain=1.0)
    posture.set_target(robot.q + 0.1)
    masked = engine_tasks.PositionTask(robot, "end_effector", axes="xy", gain=10.0, weight=[0.0, 0.0])
    qdot = HierarchicalController(robot, levels=[[masked], [posture]], limits=[engine_limits.JointVelocityLimit(robot)],
                                  dt=DT).compute_velocity()
    assert np.abs(qdot - 0.1).max() <= 1e-9  # the posture's K e, unhindered (ε-regularised level: 1e-9)
