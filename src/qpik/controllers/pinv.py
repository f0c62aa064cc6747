r"""Classical closed-loop inverse kinematics on the same task objects as the QP, in every world.

- :class:`PseudoinverseController` (the source's law):
  :math:`\dot q = J^\dagger v + (I - J^\dagger J)\,\dot q_0` with
  :math:`J^\dagger = J^T (J J^T + \lambda^2 I)^{-1}` (λ = 0: the right
  pseudoinverse; λ > 0: damped least squares), ``v`` and ``J`` stacked from the
  primary tasks and :math:`\dot q_0` the target velocity of a joint-space secondary
  task (e.g. :math:`k_0\nabla\sigma`).
- :class:`JacobianTransposeController`: :math:`\dot q = \alpha J^T (\dot x_d + K e)`, the
  gradient method of the lecture notes; it never inverts J and never diverges, but
  tracks with a lag.

Neither enforces limits: that is the point of the comparison. Both run over the worlds'
leading axis: one Cholesky solve of :math:`J J^T + \lambda^2 I` per world
(:func:`~qpik.numerics.cholesky_factor`), no loop over worlds. A world whose
:math:`J J^T + \lambda^2 I` is singular to rounding (:func:`scaled_condition` past
``SINGULAR_CONDITION``) is refused: its q̇ would not be determined by J and v.
"""

from __future__ import annotations

from typing import Sequence

import numpy as np

from ..errors import DivergenceError, InvalidInput
from ..numerics import both, cholesky_factor, cholesky_substitute, everywhere
from ..problem import Problem, Stack
from ..problem.closed_form import SINGULAR_RATIO
from ..tasks import Task
from ..tasks.inputs import as_index, positive_scalar
from .worlds import solve_each

# A joint speed beyond this (rad/s or m/s) is divergence, not an answer: its square and
# a step's kinematics of it stay finite, so the error comes before any overflow.
DIVERGED_SPEED = 1e100
# J Jᵀ + λ²I is singular past this condition number (scaled to a unit diagonal): the solve's
# rounding, ε·κ of y, is then 1e-4 of it and more.
SINGULAR_CONDITION = SINGULAR_RATIO**2


def scaled_condition(gram: np.ndarray, factor: np.ndarray, ok: np.ndarray, identity: np.ndarray) -> np.ndarray:
    """(N,) Σ_i M_ii (M⁻¹)_ii = trace((SMS)⁻¹), S = diag(M)^(-1/2), of every world's M
    (N, m, m), M⁻¹ from its Cholesky ``factor`` (``ok`` where accepted; ``identity``
    (N, m, m)): the condition number of M scaled to a unit diagonal within a factor m
    (SMS's largest eigenvalue lies in [1, m], the trace of its inverse in [1, m] times the
    inverse's largest), and at least every pivot's (√M_jj / L_jj)². The scaled κ is what
    a Cholesky solve's rounding grows with (van der Sluis); the pivots only bound it from
    below (any-robot case 6230: pivots within 1e6, κ 1.8e15)."""
    return np.einsum("nii,nii->n", gram, cholesky_substitute(factor, identity, ok))


class _StackedTasks:
    """The primary tasks' rows stacked into J (N, m, nv) and v (N, m), each step
    (:class:`~qpik.problem.Stack`); the answers go to ``qdots`` (N, nv)."""

    def __init__(self, robot, primary: Sequence[Task], secondary: Sequence[Task] = ()):
        if not primary:
            raise InvalidInput("the controller needs at least one primary task")
        for task in primary:
            if task.needs_period:
                raise InvalidInput(f"{task.name}: its default gain is 1/dt of a QP controller's period; this "
                                   "law has none: give the task a gain (1/s)")
        # No control period here: attach(None) checks no gain.
        self.problem = Problem(robot, [*primary, *secondary], owner=type(self).__name__)
        self.robot = robot
        self.primary = list(primary)
        self.updated_tasks = tuple(self.problem.tasks)  # fresh after every step (rollouts read them)
        self._stack = Stack(robot, self.primary)
        self.qdots = np.zeros((robot.n, robot.nv))
        self.qdot = robot.present(self.qdots)
        self._qdot_rows = self.qdots[:, None, :]  # (N, 1, nv): q̇ᵀ, written by (N, 1, m) @ (N, m, nv)

    J = property(lambda self: self.robot.present(self._stack.J),
                 doc="The primary tasks' stacked Jacobian of the last step.")
    v = property(lambda self: self.robot.present(self._stack.v), doc="Their stacked target velocities.")

    def stack(self) -> None:
        self.problem.fill()
        self._stack.stack()


class PseudoinverseController(_StackedTasks):
    r"""CLIK with the right pseudoinverse and optional null-space secondary task, in every world.

    .. math::
        \dot q = \dot q_0 + J^T y,\qquad (J J^T + \lambda^2 I)\, y = v - J \dot q_0

    (the same as :math:`J^\dagger v + (I - J^\dagger J)\dot q_0`: one linear solve per world).

    Args:
        robot: the robot (:class:`qpik.Robot` or :class:`qpik.batch.Robot`).
        primary: tasks stacked into the primary task (J, v).
        secondary: a joint-space task whose ``target_velocity`` is q̇0 (optional).
        damping: λ of damped least squares (0: the exact pseudoinverse).

    Raises:
        InvalidInput: no primary task, a primary task with the dead-beat default gain, a
            secondary task that is not joint-space, a damping that is not a finite number
            >= 0 (at most 1e12).
    """

    kind = "pinv"
    solver = "none"

    def __init__(self, robot, primary: Sequence[Task], secondary: Task | None = None, damping: float = 0.0):
        super().__init__(robot, primary, [secondary] if secondary is not None else [])
        if secondary is not None and not secondary.joint_space:
            raise InvalidInput(f"the secondary task must be a joint-space task (J = I[dofs]), not a {secondary.name}")
        self.secondary = secondary
        self.damping = positive_scalar(damping, "pseudoinverse damping", allow_zero=True)
        n, nv, m = robot.n, robot.nv, self._stack.dim
        self._gram = np.zeros((n, m, m))
        self._gram_diagonal = np.einsum("nii->ni", self._gram)  # a writable view
        self._squared_damping = self.damping**2
        self._identity = np.tile(np.eye(m), (n, 1, 1))
        self._qdot0 = np.zeros((n, nv))  # q̇0 = I[dofs]ᵀ v of the secondary task
        self._dofs = None if secondary is None else as_index(secondary.dofs)
        self._Jq0, self._rhs = np.zeros((n, m, 1)), np.zeros((n, m))
        self._solved = everywhere(n)

    def compute_velocity(self) -> np.ndarray:
        """Every world's q̇: (nv,) for one robot, (N, nv) for N worlds.

        Raises:
            DivergenceError: one robot's J Jᵀ + λ²I is singular or its q̇ is beyond
                ``DIVERGED_SPEED`` or not finite (a singularity without damping).
            WorldsFailed: some of N worlds diverge; the others are solved.
        """
        self.stack()
        J, v = self._stack.J, self._stack.v
        rhs = v
        if self.secondary is not None:
            self._qdot0[:, self._dofs] = self.secondary.target_velocities
            np.matmul(J, self._qdot0[:, :, None], self._Jq0)
            rhs = np.subtract(v, self._Jq0[:, :, 0], self._rhs)
        np.matmul(J, J.transpose(0, 2, 1), self._gram)
        if self._squared_damping:
            self._gram_diagonal += self._squared_damping
        # Singular within SINGULAR_CONDITION, not at an exactly zero pivot: whether a Schur
        # complement of a singular J Jᵀ rounds to +ε or −ε is no decision to act on.
        factor, solved = cholesky_factor(self._gram, SINGULAR_RATIO)
        conditioned = scaled_condition(self._gram, factor, solved, self._identity) <= SINGULAR_CONDITION
        self._solved = both(solved, everywhere(len(conditioned)) if conditioned.all() else conditioned)
        y = cholesky_substitute(factor, rhs, self._solved)
        np.matmul(y[:, None, :], J, self._qdot_rows)
        if self.secondary is not None:
            self.qdots += self._qdot0
        qdots = self.qdots
        # NaN fails the comparisons too. Beyond the bound the undamped law at a singularity
        # has diverged: the next step's J Jᵀ would overflow (a RuntimeWarning, then inf).
        if self._solved is everywhere(len(qdots)) and qdots.max() <= DIVERGED_SPEED and \
                qdots.min() >= -DIVERGED_SPEED:
            return self.qdot
        with np.errstate(invalid="ignore"):
            diverged = ~(np.abs(qdots).max(axis=1) <= DIVERGED_SPEED) | ~np.asarray(self._solved)
        solve_each(np.flatnonzero(diverged), self._diverged, qdots, self.robot.batched,
                   "PseudoinverseController step")
        return self.qdot

    def _diverged(self, world: int) -> np.ndarray:
        """The error of a world whose law diverged (``solve_each`` names it)."""
        if not self._solved[world]:
            raise DivergenceError(f"pseudoinverse: J Jᵀ is singular (a singularity: condition past "
                                  f"{SINGULAR_CONDITION:g})")
        raise DivergenceError(f"pseudoinverse produced a joint velocity beyond {DIVERGED_SPEED:g} or not "
                              "finite (singularity): give the law some damping")


class JacobianTransposeController(_StackedTasks):
    r""":math:`\dot q = \alpha J^T v`: the gradient (Jacobian transpose) law, a further
    baseline, in every world.

    Args:
        robot: the robot (:class:`qpik.Robot` or :class:`qpik.batch.Robot`).
        primary: tasks stacked into (J, v).
        alpha: the step α > 0 (at most 1e12).

    Raises:
        InvalidInput: no primary task, a task with the dead-beat default gain, a bad ``alpha``.
    """

    kind = "jt"
    solver = "none"

    def __init__(self, robot, primary: Sequence[Task], alpha: float = 1.0):
        super().__init__(robot, primary)
        self.alpha = positive_scalar(alpha, "alpha")
        self._v_rows = self._stack.v[:, None, :]  # (N, 1, m): the stack's arrays are fixed

    def compute_velocity(self) -> np.ndarray:
        """Every world's q̇: (nv,) for one robot, (N, nv) for N worlds."""
        self.stack()
        np.matmul(self._v_rows, self._stack.J, self._qdot_rows)
        self.qdots *= self.alpha
        return self.qdot
