"""What the engine's task tests share (loaded by each test file from its own folder):
robots at given states, the three references (the task's rows written out from MuJoCo's
own functions in the test, each world's own one-world run, finite differences of the
error) and norm-wise comparisons.

Tolerances, said once:

- ``REFERENCE``: the engine's task on one :class:`qpik.Robot` against its formula written
  out in the test on MuJoCo's own poses and Jacobians (a fresh MjData at the same q) and
  SciPy's rotation vectors. The same MuJoCo calls give the same Jacobians and poses; the
  formulas on top are evaluated in another order (stacked ``matmul`` for ``dot``, a
  quaternion difference for SciPy's rotation vector of a matrix): a few roundings of O(1)
  values, so 1e-12 relative is a wide margin over the ~1e-16 seen.
- ``WORLDS`` = 1e-10 relative: each of N worlds against its own one-world run (the
  brief's figure; the CPU back-end's Jacobians are formed from ``cdof`` in NumPy and
  equal ``mj_jac`` to rounding, ~1e-16).
- ``AGREEMENT``: central differences at h = 1e-6 agree with an exact Jacobian to ~1e-9
  relative to its largest entry here (rounding ε|e|/h, curvature h²): 1e-7 allowed, as
  the core tests allow.
"""

from __future__ import annotations

from typing import Callable

import mujoco
import numpy as np

import qpik
from qpik import batch

REFERENCE = 1e-12
WORLDS = 1e-10
AGREEMENT = 1e-7
STEP = 1e-6
DT = 0.01  # the period given to dead-beat gains (attach) before v is compared


def relative(a, b) -> float:
    """‖a − b‖ / ‖b‖ (‖a − b‖ where b is zero): the norm-wise relative difference."""
    a, b = np.asarray(a, dtype=float), np.asarray(b, dtype=float)
    assert a.shape == b.shape, (a.shape, b.shape)
    scale = float(np.linalg.norm(b))
    gap = float(np.linalg.norm(a - b))
    return gap / scale if scale > 0.0 else gap


def displaced(model: mujoco.MjModel, q0: np.ndarray, seed: int, scale: float = 0.3) -> np.ndarray:
    """q0 moved by a random tangent step (MuJoCo's ``mj_integratePos``)."""
    q = np.array(q0, dtype=float)
    rng = np.random.default_rng(seed)
    mujoco.mj_integratePos(model, q, rng.normal(scale=scale, size=model.nv), 1.0)
    return q


def one_robot(scene, q: np.ndarray | None = None) -> qpik.Robot:
    """A one-world robot of ``scene`` (a bundled name, a path or an MjModel) at ``q``,
    its kinematics current; starts outside the joint ranges are allowed."""
    robot = qpik.Robot.load(scene, allow_outside_limits=True) if not isinstance(scene, mujoco.MjModel) else \
        qpik.Robot(scene, allow_outside_limits=True)
    if q is not None:
        robot.q[:] = q
    robot.update_kinematics()
    return robot


def worlds(scene, n: int = 4, seed: int = 0, scale: float = 0.3) -> batch.Robot:
    """N worlds of ``scene``, each at its own displaced state, kinematics current."""
    robots = batch.Robot.load(scene, n=n, allow_outside_limits=True) if not isinstance(scene, mujoco.MjModel) else \
        batch.Robot(scene, n=n, allow_outside_limits=True)
    start = robots.q[0].copy()
    robots.q[:] = [displaced(robots.model, start, seed + w, scale) for w in range(n)]
    robots.update_kinematics()
    return robots


def world_robot(robots: batch.Robot, w: int) -> qpik.Robot:
    """World ``w`` of a batch as a robot of its own (a new one: it outlives the next call)."""
    return one_robot(robots.model, robots.q[w])


def rows(task) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(e, J, v) as a user reads them, copies."""
    return np.array(task.error), np.array(task.jacobian), np.array(task.target_velocity)


def measured(task, dt: float | None = DT) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Attach the period (dead-beat gains become 1/dt), update, and return :func:`rows`."""
    task.attach(dt)
    task.robot.ensure_kinematics()
    task.update()
    return rows(task)


def assert_rows(task, expected, tolerance: float = REFERENCE, dt: float | None = DT) -> None:
    """The task's e, J, v on one robot (after attaching ``dt``) against ``expected``, the
    three written out in the test (see ``REFERENCE``); ``expected`` may be a function of
    no argument, called after the task is measured (dead-beat gains are then set)."""
    engine = measured(task, dt)
    expected = expected() if callable(expected) else expected
    for what, a, b in zip("eJv", engine, expected):
        assert relative(a, b) <= tolerance, f"{what}: {relative(a, b):.2e}"


def assert_each_world(robots: batch.Robot, build: Callable, tolerance: float = WORLDS, dt: float | None = DT):
    """``build(robot, w)`` makes the task on a robot (``w`` None: the batch; else world w's
    own one-world robot, with world w's targets): each world's e, J, v equal its own
    one-world run. Returns the batch's task."""
    task = build(robots, None)
    engine = measured(task, dt)
    for w in range(robots.n):
        alone = measured(build(world_robot(robots, w), w), dt)
        for what, a, b in zip("eJv", engine, alone):
            assert relative(a[w], b) <= tolerance, f"world {w}, {what}: {relative(a[w], b):.2e}"
    return task


def finite_differences(robot: qpik.Robot, measure: Callable, step: float = STEP) -> np.ndarray:
    """Central differences of ``measure()`` (an array) along each dof of a one-world robot
    (q ⊕ ±h e_k, MuJoCo's own tangent steps), the robot left at its start."""
    q0 = robot.q.copy()
    columns = []
    for k in range(robot.nv):
        values = []
        for h in (step, -step):
            robot.q[:] = q0
            mujoco.mj_integratePos(robot.model, robot.q, np.eye(robot.nv)[k] * h, 1.0)
            robot.update_kinematics()
            values.append(np.array(measure(), dtype=float).reshape(-1))
        columns.append((values[0] - values[1]) / (2 * step))
    robot.q[:] = q0
    robot.update_kinematics()
    return np.array(columns).T


def assert_jacobian_is_the_derivative(task, sign: float = -1.0) -> None:
    """The task's J equals ``sign`` times the finite differences of its error (``AGREEMENT``)."""
    robot = task.robot

    def error():
        task.update()
        return task.error.copy()

    task.attach(DT)
    robot.ensure_kinematics()
    task.update()
    jacobian = np.array(task.jacobian)
    fd = sign * finite_differences(robot, error)
    gap = float(np.max(np.abs(fd - jacobian)))
    assert gap <= AGREEMENT * max(1.0, float(np.max(np.abs(jacobian)))), f"{task.name}: |FD − J| = {gap:.2e}"
