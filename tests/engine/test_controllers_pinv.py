"""The engine's PseudoinverseController and JacobianTransposeController: one robot equals
the laws written out on MuJoCo's own Jacobian (J†v + (I − J†J) q̇0 with NumPy's SVD
pseudoinverse, damped or not; αJᵀv), on one step and along a rollout; each of N = 4
worlds equals its own one-world run; bad input and failing worlds are typed errors."""

from __future__ import annotations

import importlib.util
from pathlib import Path

import mujoco
import numpy as np
import pytest

import qpik
import qpik.tasks as engine_tasks
from qpik import numerics
from qpik.controllers import JacobianTransposeController, PseudoinverseController
from qpik.controllers.pinv import scaled_condition
from qpik.problem.closed_form import SINGULAR_RATIO
from qpik.errors import DivergenceError, InvalidInput, WorldsFailed
from qpik.robots.arm.scenarios import ARM_START, JT_ALPHA, SEED_DURATION, SEED_PATH
from qpik.trajectories import Segment

_spec = importlib.util.spec_from_file_location("references", Path(__file__).with_name("references.py"))
references = importlib.util.module_from_spec(_spec)
_spec.loader.exec_module(references)

DT = 0.002  # s
# An answer agrees with the law written out to this relative to 1 + ‖q̇‖ (rad/s): the same
# formula in another order of operations (a Cholesky solve of J Jᵀ here, NumPy's SVD
# there), on Jacobians of norm ~3 and conditions below 1e3.
TOLERANCE = 1e-10
# A world of N equals its own one-world run to this, relative.
WORLD_TOLERANCE = 1e-10
_ARM_MODEL = qpik.Robot.load("arm").model  # the laws' reference kinematics (read only)


def _configurations(count: int, seed: int = 0) -> np.ndarray:
    rng = np.random.default_rng(seed)
    return np.column_stack([rng.uniform(-2.0, 2.0, (count, 3)), rng.uniform(0.2, 0.8, count)])


def _arm(q=ARM_START) -> qpik.Robot:
    robot = qpik.Robot.load("arm")
    robot.set_q(np.asarray(q, dtype=float))
    robot.update_kinematics()
    return robot


def _tasks(robot, target=None, rate=(0.1, -0.05)):
    """The arm's position task (x, y) and its σ task; the target 1e-4 m off the tip by default."""
    position = engine_tasks.PositionTask(robot, "end_effector", axes="xy", gain=500.0)
    if target is None:
        robot.ensure_kinematics()
        target = np.array(position.measured()) + [1e-4, -2e-4]
    position.set_target(target, rate)
    sigma = engine_tasks.ManipulabilityTask(robot, engine_tasks.SigmaProxy(robot, ("theta2", "theta3")), gain=5.0)
    return position, sigma


def _pinv(robot, kind: str, damping: float = 0.0, target=None):
    position, sigma = _tasks(robot, target)
    if kind == "jt":
        return JacobianTransposeController(robot, [position], alpha=JT_ALPHA), position
    secondary = sigma if kind == "pinv+sigma" else None
    return PseudoinverseController(robot, [position], secondary, damping=damping), position


def _close(a: np.ndarray, b: np.ndarray, tolerance: float = TOLERANCE) -> bool:
    return float(np.linalg.norm(a - b)) <= tolerance * (1.0 + float(np.linalg.norm(b)))


def _law(q, target, rate, kind: str, damping: float):
    """(q̇, J, v) of the law written out at q: J = the rows x, y of MuJoCo's site Jacobian,
    v = K (x_d − x) + ẋ_d; pinv: J†v + (I − J†J) q̇0 with J† = V diag(s/(s² + λ²)) Uᵀ
    (NumPy's SVD; λ = 0: np.linalg.pinv) and q̇0 = k0 ∂σ/∂q = 5 sin θ cos θ on θ2, θ3
    (zero without σ); jt: α Jᵀ v."""
    p, _, Jp, _ = references.frame_state(_ARM_MODEL, q, "end_effector")
    J = Jp[:2]
    v = 500.0 * (np.asarray(target) - p[:2]) + np.asarray(rate)
    if kind == "jt":
        return JT_ALPHA * J.T @ v, J, v
    if damping:
        u, s, vt = np.linalg.svd(J, full_matrices=False)
        inverse = vt.T @ np.diag(s / (s**2 + damping**2)) @ u.T
    else:
        inverse = np.linalg.pinv(J)
    qdot0 = np.zeros(4)
    if kind == "pinv+sigma":
        qdot0[1:3] = 5.0 * np.sin(q[1:3]) * np.cos(q[1:3])
    return inverse @ v + (np.eye(4) - inverse @ J) @ qdot0, J, v


KINDS = [("pinv", 0.0), ("pinv", 0.1), ("pinv+sigma", 0.0), ("pinv+sigma", 0.05), ("jt", 0.0)]


@pytest.mark.parametrize(("kind", "damping"), KINDS)
def test_one_robot_equals_the_law_written_out(kind, damping):
    for q in _configurations(6):
        robot = _arm(q)
        ours, position = _pinv(robot, kind, damping)
        qdot = ours.compute_velocity()
        expected, J, v = _law(q, position.target, (0.1, -0.05), kind, damping)
        assert qdot.shape == (4,)
        assert _close(qdot, expected)
        # MuJoCo's Jacobian through another MjData: the same calls, 1e-12 of its norm.
        assert np.linalg.norm(ours.J - J) <= 1e-12 * np.linalg.norm(J)
        assert np.linalg.norm(ours.v - v) <= 1e-12 * np.linalg.norm(v)


@pytest.mark.parametrize("kind", ["pinv+sigma", "jt"])
def test_a_rollout_along_the_seed_path_follows_the_law(kind):
    """200 steps of the seed path (the source's segment, cubic law) from the arm's start:
    on every state of the rollout the answer is the law written out."""
    segment = Segment(SEED_PATH[0], SEED_PATH[1], SEED_DURATION, time_law="cubic")
    robot = _arm()
    controller, position = _pinv(robot, kind, target=SEED_PATH[0])
    start = robot.q.copy()
    for k in range(200):
        target, rate = segment.sample(k * DT)
        position.set_target(target, rate)
        q = robot.q.copy()
        qdot = controller.compute_velocity()
        assert _close(qdot, _law(q, target, rate, kind, 0.0)[0]), k
        robot.integrate(qdot, DT)
    assert np.abs(robot.q - start).max() > 1e-3  # the arm moved


def _worlds(count: int = 4, seed: int = 1):
    """``count`` different configurations and targets (each 1e-3 m or so off its tip)."""
    q = _configurations(count, seed)
    rng = np.random.default_rng(seed + 10)
    targets = []
    for qi in q:
        position, _ = _tasks(_arm(qi))
        targets.append(position.measured() + rng.uniform(-1e-3, 1e-3, 2))
    return q, np.array(targets)


def _batch(q: np.ndarray) -> qpik.batch.Robot:
    robots = qpik.batch.Robot.load("arm", n=len(q))
    robots.set_q(q)
    return robots


@pytest.mark.parametrize(("kind", "damping"), KINDS)
def test_each_of_four_worlds_equals_its_own_one_world_run(kind, damping):
    """N = 4 worlds of different states and targets, 20 steps: every world's q̇ equals the
    one-world controller's at that world's state, and the worlds' paths their own runs."""
    q, targets = _worlds()
    robots = _batch(q)
    batch, _ = _pinv(robots, kind, damping, targets)
    singles = []
    for qi, target in zip(q, targets):
        robot = _arm(qi)
        singles.append((robot, _pinv(robot, kind, damping, target)[0]))
    for _ in range(20):
        qdots = batch.compute_velocity()
        assert qdots.shape == (4, 4)
        for w, (robot, single) in enumerate(singles):
            qdot = single.compute_velocity()
            assert _close(qdots[w], qdot, WORLD_TOLERANCE)
            robot.integrate(qdot, DT)
        robots.integrate(qdots, DT)
    for w, (robot, _) in enumerate(singles):
        assert _close(robots.q[w], robot.q, WORLD_TOLERANCE)


def test_bad_input_is_typed():
    robot = _arm()
    position, sigma = _tasks(robot)
    with pytest.raises(InvalidInput, match="at least one primary task"):
        PseudoinverseController(robot, [])
    with pytest.raises(InvalidInput, match="at least one primary task"):
        JacobianTransposeController(robot, [])
    dead_beat = engine_tasks.PositionTask(robot, "end_effector", axes="xy")  # gain 1/dt: this law has no dt
    with pytest.raises(InvalidInput, match="give the task a gain"):
        PseudoinverseController(robot, [dead_beat])
    with pytest.raises(InvalidInput, match="joint-space task"):
        PseudoinverseController(robot, [position], position)
    for damping in (-1.0, np.nan, np.inf, 1e13, "0.1", [0.1]):
        with pytest.raises(InvalidInput, match="damping"):
            PseudoinverseController(robot, [position], sigma, damping=damping)
    for alpha in (0.0, -1.0, np.nan, np.inf, 1e13):
        with pytest.raises(InvalidInput, match="alpha"):
            JacobianTransposeController(robot, [position], alpha=alpha)
    with pytest.raises(InvalidInput, match="another"):
        PseudoinverseController(robot, [_tasks(_arm())[0]])


def test_a_singular_gram_matrix_is_a_divergence():
    """x, y and z of the planar arm's tip: the z row is zero, J Jᵀ singular, undamped (a
    DivergenceError); damped, the law written out."""
    robot = _arm()
    tip = engine_tasks.PositionTask(robot, "end_effector", axes="xyz", gain=10.0)
    tip.set_target([0.6, 1.9, 0.0])
    with pytest.raises(DivergenceError, match="singular"):
        PseudoinverseController(robot, [tip]).compute_velocity()
    damped = PseudoinverseController(robot, [tip], damping=0.1).compute_velocity()
    p, _, Jp, _ = references.frame_state(robot.model, robot.q, "end_effector")
    u, s, vt = np.linalg.svd(Jp, full_matrices=False)
    expected = vt.T @ np.diag(s / (s**2 + 0.01)) @ u.T @ (10.0 * (np.array([0.6, 1.9, 0.0]) - p))
    assert np.abs(Jp[2]).max() == 0.0 and _close(damped, expected)


def test_a_diverging_world_is_named_and_the_others_are_solved():
    """World 2's target is 1e120 m away: its law asks for more than 1e100 m/s (one robot: a
    DivergenceError); the other worlds are each their own run."""
    q, targets = _worlds()
    targets[2] = [1e120, 0.0]
    with pytest.raises(DivergenceError, match="beyond"):
        _pinv(_arm(q[2]), "pinv+sigma", target=targets[2])[0].compute_velocity()
    batch, _ = _pinv(_batch(q), "pinv+sigma", target=targets)
    with pytest.raises(WorldsFailed) as failed:
        batch.compute_velocity()
    assert failed.value.worlds.tolist() == [2] and "DivergenceError" in failed.value.reasons[2]
    np.testing.assert_array_equal(failed.value.qdot[2], 0.0)
    for w in (0, 1, 3):
        single, _ = _pinv(_arm(q[w]), "pinv+sigma", target=targets[w])
        assert _close(failed.value.qdot[w], single.compute_velocity(), WORLD_TOLERANCE)


def _kahan(m: int, angle: float) -> np.ndarray:
    """Kahan's upper triangular matrix: RᵀR's Cholesky pivots (R's diagonal, sin^i) stay
    far from revealing how nearly singular it is."""
    c, s = np.cos(angle), np.sin(angle)
    return np.diag(s ** np.arange(m)) @ (np.eye(m) + np.triu(np.full((m, m), -c), 1))


class _FixedRows(engine_tasks.Task):
    """A user task whose Jacobian is a given matrix (its error: ones)."""

    def __init__(self, robot, jacobian):
        self.jacobian_rows = np.asarray(jacobian, dtype=float)
        super().__init__(robot, dim=len(self.jacobian_rows), gain=1.0)

    def compute_error(self, robot):
        return np.ones(self.dim)

    def compute_jacobian(self, robot):
        return self.jacobian_rows


def test_a_gram_matrix_singular_to_rounding_is_refused_whatever_its_pivots():
    """J = Rᵀ, R Kahan's 8x8 matrix (angle 0.2): every Cholesky pivot of J Jᵀ passes the
    ratio test (√M_jj / L_jj below 1e6), yet J Jᵀ scaled to a unit diagonal has a condition
    number past 1e14 (NumPy's SVD), so a solve's rounding is most of y: the law refuses it
    as singular (any-robot case 6230: pivots within 1e6, κ 1.8e15, two runs' q̇ 4 % apart)."""
    chain = "".join(f'<body pos="0 0 0.1"><joint type="hinge" axis="0 1 0"/><geom size="0.02" mass="1"/>'
                    for _ in range(8)) + "</body>" * 8
    robot = qpik.Robot(mujoco.MjModel.from_xml_string(
        f'<mujoco><compiler angle="radian"/><worldbody>{chain}</worldbody></mujoco>'))
    J = _kahan(8, 0.2).T
    M = J @ J.T
    pivots = np.diag(np.linalg.cholesky(M))
    scale = 1.0 / np.sqrt(np.diag(M))
    assert np.max(np.sqrt(np.diag(M)) / pivots) < SINGULAR_RATIO
    assert np.linalg.cond(M * scale[:, None] * scale[None, :]) > 1e14
    with pytest.raises(DivergenceError, match="singular"):
        PseudoinverseController(robot, [_FixedRows(robot, J)]).compute_velocity()
    well = PseudoinverseController(robot, [_FixedRows(robot, _kahan(8, 1.2).T)]).compute_velocity()
    assert np.all(np.isfinite(well))


def test_scaled_condition_is_the_trace_of_the_scaled_inverse():
    """Every world's Σ_i M_ii (M⁻¹)_ii against NumPy's inverse of SMS (S = diag(M)^(-1/2))
    formed explicitly: its trace to 1e-9 relative (κ below 1e6 here, the inverse carrying a
    rounding of the data by κ), within a factor m of SMS's 2-norm condition number, for one
    world and for three."""
    rng = np.random.default_rng(3)
    A = rng.normal(size=(3, 5, 7)) * rng.uniform(0.1, 10.0, (3, 5, 1))
    M = A @ A.transpose(0, 2, 1)
    for worlds in (M[:1], M):
        factor, ok = numerics.cholesky_factor(worlds)
        got = scaled_condition(worlds, factor, ok, np.tile(np.eye(5), (len(worlds), 1, 1)))
        for value, m in zip(got, worlds):
            s = 1.0 / np.sqrt(np.diag(m))
            scaled = m * s[:, None] * s[None, :]
            assert abs(value - np.trace(np.linalg.inv(scaled))) <= 1e-9 * value
            assert np.linalg.cond(scaled) / 5 <= value <= 5 * np.linalg.cond(scaled)
