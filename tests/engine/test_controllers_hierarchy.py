"""The engine's HierarchicalController: one robot equals the serial hierarchy (steps and
rollouts with bounds held and solved, general rows, dependent rows above), each of N = 4
worlds equals its own one-world run, typed errors name the level and the failing worlds;
and its least-squares closed form against the serial one."""

from __future__ import annotations

import mujoco
import numpy as np
import pytest

import qpik
import qpik.controllers as serial
import qpik.controllers as engine
import qpik.limits as engine_limits
import qpik.tasks as engine_tasks
import qpik.limits as serial_limits
import qpik.tasks as serial_tasks
from qpik.controllers import HierarchicalController
from qpik.problem.least_squares import DampedLeastSquares
from qpik.errors import InfeasibleProblem, InvalidInput, UnknownName, WorldsFailed
from qpik.problem.closed_form import damped_least_squares_step
from qpik.robots.arm.scenarios import ARM_START, SEED_PATH, TOO_FAST_SPEEDS, three_tasks_start
from qpik.trajectories import Segment

DT = 0.002  # s
# One robot's q̇ equals the serial hierarchy's to this relative to 1 + ‖q̇‖ (rad/s): the
# same minimisers by other closed forms (held bounds or damped least squares over a world
# axis, against the serial KKT steps) or the same solver (DAQP, exact); speeds are ~1.
TOLERANCE = 1e-10
# A world of N equals its own one-world run to this, relative.
WORLD_TOLERANCE = 1e-10
# θ2, θ3 within ±0.55 rad from the three-tasks start (θ2 = −0.5, θ3 = 0.5): σ pushes both
# into their bounds at once, held at both levels within the first steps.
NARROW = {"theta2": (-0.55, 0.55), "theta3": (-0.55, 0.55)}


class _SerialSlowSum(serial_limits.Limit):
    """One general row: the joint velocities sum to at least −``total`` (serial interface)."""

    inequality_rows = 1

    def __init__(self, total: float):
        self.total = total

    def apply(self, dt, lb, ub, G=None, h=None):
        G[0], h[0] = -1.0, self.total


class _SlowSum(engine_limits.Limit):
    """The same row in every world."""

    inequality_rows = 1

    def __init__(self, total: float):
        self.total = total

    def apply(self, dt, lower, upper, G=None, h=None):
        G[:, 0], h[:, 0] = -1.0, self.total


MODULES = {"engine": (engine, engine_tasks, engine_limits, _SlowSum),
           "serial": (serial, serial_tasks, serial_limits, _SerialSlowSum)}


def _arm(q=ARM_START) -> qpik.Robot:
    robot = qpik.Robot.load("arm")
    robot.set_q(np.asarray(q, dtype=float))
    robot.update_kinematics()
    return robot


def _configurations(count: int, seed: int = 0) -> np.ndarray:
    rng = np.random.default_rng(seed)
    return np.column_stack([rng.uniform(-2.0, 2.0, (count, 3)), rng.uniform(0.2, 0.8, count)])


def _path_and_sigma(which: str, robot, *, hard: bool = True, speeds=None, ranges=None, row: float | None = None,
                    target=None, rate=(0.1, -0.05)):
    """The arm's path level (x, y; hard, or soft with LM damping) over its σ level, with
    joint position limits (``ranges`` tightened) and speed limits (``speeds`` lowered),
    and a general row when ``row`` is given; built from the engine's or the serial classes."""
    controllers, tasks, limits, slow_sum = MODULES[which]
    position = tasks.PositionTask(robot, "end_effector", axes="xy", gain=500.0, hard=hard,
                                  lm_damping=0.0 if hard else 10.0)
    if target is None:
        robot.ensure_kinematics()
        target = np.array(position.measured()) + [1e-4, -2e-4]
    position.set_target(target, rate)
    sigma = tasks.ManipulabilityTask(robot, tasks.SigmaProxy(robot, ("theta2", "theta3")), gain=5.0)
    sigma.priority = 1
    vmax = robot.velocity_limits.copy()
    for joint, speed in (speeds or {}).items():
        vmax[robot.joint_dof_index(joint)] = speed
    bounds = [limits.JointPositionLimit(robot, robot.joint_limits.tightened(ranges or {}), influence=0.8,
                                        damper_rate=2.0), limits.JointVelocityLimit(robot, vmax)]
    if row is not None:
        bounds.append(slow_sum(row))
    return controllers.HierarchicalController(robot, [position, sigma], bounds, dt=DT), position


def _close(a: np.ndarray, b: np.ndarray, tolerance: float = TOLERANCE) -> bool:
    return float(np.linalg.norm(a - b)) <= tolerance * (1.0 + float(np.linalg.norm(b)))


SETUPS = {
    "hard path, sigma": {},
    "soft path, sigma": {"hard": False},
    "hard path, general row": {"row": 0.5},
    "soft path, slow joints": {"hard": False, "speeds": TOO_FAST_SPEEDS},
}


@pytest.mark.parametrize("setup", SETUPS)
def test_one_robot_equals_the_serial_hierarchy(setup):
    for q in _configurations(6):
        robot = _arm(q)
        ours, _ = _path_and_sigma("engine", robot, **SETUPS[setup])
        theirs, _ = _path_and_sigma("serial", robot, **SETUPS[setup])
        qdot = ours.compute_velocity()
        assert qdot.shape == (4,) and ours.level_velocities.shape == (2, 4)
        assert _close(qdot, theirs.compute_velocity())
        for k in range(2):
            assert _close(ours.level_velocities[k], theirs.level_velocities[k])
        np.testing.assert_allclose(ours.report()["level_residual"], theirs.report()["level_residual"],
                                   rtol=1e-8, atol=TOLERANCE)
        np.testing.assert_array_equal(ours.lb, theirs.lb)
        np.testing.assert_array_equal(ours.ub, theirs.ub)


# Where the general row binds, the soft path level (Hessian JᵀJ + ε, ε = 1e-10 along the
# dofs the path leaves free) is DAQP's answer, which no closed form polishes there: the
# serial hierarchy's own answer moves by up to 5e-10 (rad/s, of ~1.3) for a 1e-15 change
# of q at such a step (measured). Elsewhere answers are exact to rounding.
ROW_TOLERANCE = 1e-9
ROLLOUTS = {
    # σ drives θ2 and θ3 into ±0.55: bounds held in closed form at both levels.
    "bounds held": ({"ranges": NARROW}, three_tasks_start(), 5.0, TOLERANCE),
    # The path in 0.5 s with 1 rad/s joints: the soft path level and σ's both to the solver.
    "bounds solved": ({"hard": False, "speeds": TOO_FAST_SPEEDS}, ARM_START, 0.5, TOLERANCE),
    # The same, the joints' sum bounded by a general row.
    "general row": ({"hard": False, "speeds": TOO_FAST_SPEEDS, "row": 0.6}, ARM_START, 0.5, ROW_TOLERANCE),
}


@pytest.mark.parametrize("rollout", ROLLOUTS)
def test_a_rollout_equals_the_serial_rollout(rollout):
    """200 steps of the seed path from the scenario's start, limits binding."""
    options, start, duration, tolerance = ROLLOUTS[rollout]
    segment = Segment(SEED_PATH[0], SEED_PATH[1], duration, time_law="cubic")
    paths = []
    for which in ("engine", "serial"):
        robot = _arm(start)
        controller, position = _path_and_sigma(which, robot, target=SEED_PATH[0], rate=None, **options)
        path, steps = [], []
        for k in range(200):
            position.set_target(*segment.sample(k * DT))
            qdot = controller.compute_velocity()
            steps.append(qdot.copy())
            robot.integrate(qdot, DT)
            path.append(robot.q.copy())
        paths.append((np.array(path), np.array(steps), controller))
    (ours, our_steps, controller), (theirs, their_steps, _) = paths
    assert all(_close(a, b, tolerance) for a, b in zip(our_steps, their_steps))
    assert np.abs(ours - theirs).max() <= tolerance * (1.0 + np.abs(theirs).max())
    at_bound = np.isclose(our_steps, controller.lb, rtol=0, atol=1e-12) | \
        np.isclose(our_steps, controller.ub, rtol=0, atol=1e-12)
    assert at_bound[-1].any()  # a limit binds at the end


def test_dependent_rows_above_are_reduced_as_in_the_serial_hierarchy():
    """Path (2) + φ (1) + posture (4) above a damping level: 7 equality rows on 4 joints,
    consistent but dependent: the solver gets a basis of their row space."""
    answers = []
    for which in ("engine", "serial"):
        controllers, tasks, limits, _ = MODULES[which]
        robot = _arm([0.9, -0.5, 0.6, 0.4])
        position = tasks.PositionTask(robot, "end_effector", axes="xy", gain=500.0)
        position.set_target(np.array(position.measured()) + [1e-4, -2e-4], [0.1, -0.05])
        phi = tasks.OrientationTask(robot, "end_effector", axes="z", gain=50.0)
        phi.set_target(robot.data.site("end_effector").xmat.reshape(3, 3) @ _rotation_z(0.01))
        posture = tasks.PostureTask(robot, target=robot.q + 0.1, gain=2.0)
        levels = [[position], [phi], [posture], [tasks.DampingTask(robot, weight=1.0)]]
        bounds = [limits.JointPositionLimit(robot), limits.JointVelocityLimit(robot)]
        controller = controllers.HierarchicalController(robot, levels=levels, limits=bounds, dt=DT)
        answers.append((controller.compute_velocity().copy(), controller.kept_above))
    (ours, our_kept), (theirs, their_kept) = answers
    assert _close(ours, theirs) and our_kept == their_kept


def _rotation_z(angle: float) -> np.ndarray:
    c, s = np.cos(angle), np.sin(angle)
    return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])


def _worlds(count: int = 4, offset: float = 1e-3, seed: int = 1):
    """Different states (two near the narrow bounds) and targets ``offset`` m off their tips."""
    q = _configurations(count, seed)
    q[0], q[1] = three_tasks_start(), three_tasks_start(0.54)
    rng = np.random.default_rng(seed + 10)
    targets = [_path_and_sigma("engine", _arm(qi))[1].measured() + rng.uniform(-offset, offset, 2) for qi in q]
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
    batch, _ = _path_and_sigma("engine", robots, target=targets, **options)
    singles = [(robot, _path_and_sigma("engine", robot, target=target, **options)[0])
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
    targets[1] = _path_and_sigma("engine", _arm(q[1]))[1].measured() + [0.1, -0.1]
    robot = _arm(q[1])
    for which in ("engine", "serial"):
        with pytest.raises(InfeasibleProblem, match="level 0 .*position task"):
            _path_and_sigma(which, robot, target=targets[1])[0].compute_velocity()
    batch, _ = _path_and_sigma("engine", _batch(q), target=targets)
    with pytest.raises(WorldsFailed) as failed:
        batch.compute_velocity()
    assert failed.value.worlds.tolist() == [1]
    assert "InfeasibleProblem" in failed.value.reasons[1] and "level 0" in failed.value.reasons[1]
    np.testing.assert_array_equal(failed.value.qdot[1], 0.0)
    np.testing.assert_array_equal(batch.level_velocities[1], 0.0)
    for w in (0, 2, 3):
        single, _ = _path_and_sigma("engine", _arm(q[w]), target=targets[w])
        assert _close(failed.value.qdot[w], single.compute_velocity(), WORLD_TOLERANCE)


_JOINTLESS = '<mujoco><worldbody><body name="block" pos="0 0 1"><geom size="0.1"/><site name="tip"/></body>' \
             '</worldbody></mujoco>'


@pytest.mark.parametrize("controllers", [
    engine,
    # The serial class fails there with an untyped IndexError (an empty Hessian diagonal).
    pytest.param(serial, marks=pytest.mark.xfail(raises=IndexError, strict=True, reason="serial: IndexError")),
])
def test_a_model_without_dofs_is_a_typed_error(controllers):
    tasks = engine_tasks if controllers is engine else serial_tasks
    robot = qpik.Robot(mujoco.MjModel.from_xml_string(_JOINTLESS))
    assert robot.nv == 0
    tip = tasks.PositionTask(robot, "tip", gain=1.0, hard=True)
    with pytest.raises(InvalidInput, match="degree of freedom"):
        controllers.HierarchicalController(robot, [tip], dt=DT)


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


@pytest.mark.parametrize("form", ["epsilon", "joint-space tasks"])
def test_the_least_squares_closed_form_equals_the_serial_one_in_every_world(form):
    """Random rows [R₁; R₂] (2 soft, 2 equality rows on 4 dofs) with D = ε = 1e-10 and no
    c (a level of soft tasks alone), or D in [0.1, 2] and a random c (joint-space tasks on
    every dof): one world equals the serial damped_least_squares_step, each of 5 worlds
    its own one-world solve; a world with dependent equality rows that disagree is refused
    alone."""
    rng = np.random.default_rng(7)
    n, nv, soft, rows = 5, 4, 2, 2
    R = rng.normal(size=(n, soft + rows, nv))
    rhs = rng.normal(size=(n, soft + rows))
    R[3, soft + 1] = R[3, soft]  # world 3: dependent equality rows, which disagree
    if form == "epsilon":
        dinv, c = np.full((n, nv), 1e10), None
    else:
        dinv, c = 1.0 / rng.uniform(0.1, 2.0, (n, nv)), rng.normal(size=(n, nv))
    batch, ok = DampedLeastSquares(n, nv, soft, rows).solve(dinv, R, rhs, c)
    assert ok.tolist() == [True, True, True, False, True]
    one = DampedLeastSquares(1, nv, soft, rows)
    for w in (0, 1, 2, 4):
        cw = None if c is None else c[w:w + 1]
        x, solved = one.solve(dinv[w:w + 1], R[w:w + 1], rhs[w:w + 1], cw)
        assert solved[0] and _close(batch[w], x[0], WORLD_TOLERANCE)
        reference = damped_least_squares_step(dinv[w], R[w], soft, rhs[w], None if c is None else c[w])
        assert _close(x[0], reference)
        np.testing.assert_allclose(R[w, soft:] @ x[0], rhs[w, soft:], atol=1e-10)
    assert damped_least_squares_step(dinv[3], R[3], soft, rhs[3], None if c is None else c[3]) is None


def test_the_hexapod_hierarchy_equals_the_serial_one():
    """Loops (level 0), platform pose (1), damping (2) on the 6-PUS hexapod, 20 steps."""
    if not hasattr(engine_tasks, "EqualityTask"):
        pytest.skip("the engine has no EqualityTask yet (the hexapod's loop closures)")
    from qpik.robots.hexapod.control import HexapodModel

    paths = []
    for which in ("engine", "serial"):
        controllers, tasks, limits, _ = MODULES[which]
        robot = qpik.Robot.load("hexapod", keyframe="home")
        loops = tasks.EqualityTask(robot, HexapodModel(robot).loop_names, gain=500.0)
        platform = tasks.FrameTask(robot, "platform_center", position_gain=500.0, orientation_gain=500.0, hard=True)
        robot.ensure_kinematics()
        platform.set_target(robot.data.site("platform_center").xpos + [1e-4, 0.0, 0.0],
                            robot.data.site("platform_center").xmat.reshape(3, 3))
        damping = tasks.DampingTask(robot, weight=1e-6, joints=robot.joint_names)
        levels = [[loops], [platform], [damping]]
        controller = controllers.HierarchicalController(
            robot, levels=levels, limits=[limits.JointPositionLimit(robot), limits.JointVelocityLimit(robot)], dt=DT)
        path = []
        for _ in range(20):
            robot.integrate(controller.compute_velocity(), DT)
            path.append(robot.q.copy())
        paths.append(np.array(path))
    assert np.abs(paths[0] - paths[1]).max() <= TOLERANCE * (1.0 + np.abs(paths[1]).max())


def test_a_level_whose_rows_are_all_masked_is_solved():
    """Level 0 a position task of zero weights (every row masked), level 1 a posture: the
    serial hierarchy's hand-solved small system raised an untyped ValueError on its zero
    rows; the engine solves the empty level and leaves the posture to level 1."""
    from qpik import HierarchicalController as SerialHierarchy, JointVelocityLimit as SerialVelocity
    from qpik import PositionTask as SerialPosition, PostureTask as SerialPosture

    serial_robot = qpik.Robot.load("arm")
    serial = SerialHierarchy(serial_robot, levels=[[SerialPosition(serial_robot, "end_effector", axes="xy", gain=10.0,
                                                                   weight=[0.0, 0.0])],
                                                   [SerialPosture(serial_robot, gain=1.0)]],
                             limits=[SerialVelocity(serial_robot)], dt=DT)
    with pytest.raises(ValueError, match="not enough values"):
        serial.compute_velocity()
    robot = qpik.Robot.load("arm")
    posture = engine_tasks.PostureTask(robot, gain=1.0)
    posture.set_target(robot.q + 0.1)
    masked = engine_tasks.PositionTask(robot, "end_effector", axes="xy", gain=10.0, weight=[0.0, 0.0])
    qdot = HierarchicalController(robot, levels=[[masked], [posture]],
                                                     limits=[engine_limits.JointVelocityLimit(robot)],
                                                     dt=DT).compute_velocity()
    assert np.abs(qdot - 0.1).max() <= 1e-9  # the posture's K e, unhindered (ε-regularised level: 1e-9)
