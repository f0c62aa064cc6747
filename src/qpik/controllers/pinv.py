r"""Classical closed-loop inverse kinematics on the same task objects as the QP.

- :class:`PseudoinverseController` (the source's law):
  :math:`\dot q = J^\dagger v + (I - J^\dagger J)\,\dot q_0` with
  :math:`J^\dagger = J^T (J J^T + \lambda^2 I)^{-1}` (λ = 0: the right
  pseudoinverse; λ > 0: damped least squares), ``v`` and ``J`` stacked from the
  primary tasks and :math:`\dot q_0` the target velocity of a joint-space secondary
  task (e.g. :math:`k_0\nabla\sigma`).
- :class:`JacobianTransposeController`: :math:`\dot q = J^T (\dot x_d + K e)`, the
  gradient method of the lecture notes; it never inverts J and never diverges, but
  tracks with a lag.

Neither enforces limits: that is the point of the comparison.
"""

from __future__ import annotations

from typing import Sequence

import numpy as np

from ..errors import DivergenceError, InvalidInput
from ..problem import Problem, Stack
from ..robot import Robot
from ..tasks import Task

# A joint speed beyond this (rad/s or m/s) is divergence, not an answer: its square and
# a step's kinematics of it stay finite, so the error comes before any overflow.
DIVERGED_SPEED = 1e100


class _StackedTasks:
    """The primary tasks' rows stacked into J and v, each step (:class:`~qpik.problem.Stack`)."""

    def __init__(self, robot: Robot, primary: Sequence[Task], secondary: Sequence[Task] = ()):
        if not primary:
            raise InvalidInput("the controller needs at least one primary task")
        for task in primary:
            if task.needs_period:
                raise InvalidInput(f"{task.name}: its default gain is 1/dt of a QP controller's period; this "
                                   "law has none: give the task a gain (1/s)")
        # No control period here: attach(None) fixes the tasks' Jacobian kind, checks no gain.
        self.problem = Problem(robot, [*primary, *secondary], owner=type(self).__name__)
        self.robot = robot
        self.primary = list(primary)
        self.updated_tasks = tuple(self.problem.tasks)  # fresh after every step (rollouts read them)
        self._stack = Stack(robot.nv, self.primary)

    J = property(lambda self: self._stack.J, doc="The primary tasks' stacked Jacobian of the last step.")
    v = property(lambda self: self._stack.v, doc="Their stacked target velocities.")

    def stack(self) -> None:
        self.problem.fill()
        self._stack.stack()


class PseudoinverseController(_StackedTasks):
    """CLIK with the right pseudoinverse and optional null-space secondary task.

    Args:
        robot: the robot.
        primary: tasks stacked into the primary task (J, v).
        secondary: a joint-space task whose ``target_velocity`` is q̇0 (optional).
        damping: λ of damped least squares (0: the exact pseudoinverse).
    """

    kind = "pinv"
    solver = "none"

    def __init__(self, robot: Robot, primary: Sequence[Task], secondary: Task | None = None, damping: float = 0.0):
        super().__init__(robot, primary, [secondary] if secondary is not None else [])
        if secondary is not None and not secondary.joint_space:
            raise InvalidInput(f"the secondary task must be a joint-space task (J = I[dofs]), not a {secondary.name}")
        if not (np.isfinite(damping) and damping >= 0):
            raise InvalidInput(f"damping must be finite and >= 0, got {damping}")
        self.secondary = secondary
        self.damping = float(damping)
        self._gram = np.zeros((self._stack.dim, self._stack.dim))
        self.qdot = np.zeros(robot.nv)
        self._qdot0 = np.zeros(robot.nv)  # q̇0 = I[dofs]ᵀ v of the secondary task

    def compute_velocity(self) -> np.ndarray:
        self.stack()
        J, v = self.J, self.v
        # q̇ = q̇0 + J†(v − J q̇0) = J†v + (I − J†J) q̇0, one linear solve with J Jᵀ.
        rhs = v
        if self.secondary is not None:
            self._qdot0[self.secondary.dofs] = self.secondary.target_velocity
            rhs = v - J @ self._qdot0
        np.matmul(J, J.T, out=self._gram)
        if self.damping:
            self._gram.flat[:: len(v) + 1] += self.damping**2
        try:
            y = np.linalg.solve(self._gram, rhs)
        except np.linalg.LinAlgError:
            raise DivergenceError("pseudoinverse: J Jᵀ is singular (the arm is at a singularity)") from None
        np.matmul(J.T, y, out=self.qdot)
        if self.secondary is not None:
            self.qdot += self._qdot0
        # NaN fails the comparison too. Beyond the bound the undamped law at a singularity
        # has diverged: the next step's J Jᵀ would overflow (a RuntimeWarning, then inf).
        if not np.abs(self.qdot).max(initial=0.0) <= DIVERGED_SPEED:
            raise DivergenceError(f"pseudoinverse produced a joint velocity beyond {DIVERGED_SPEED:g} or not "
                                  "finite (singularity): give the law some damping")
        return self.qdot


class JacobianTransposeController(_StackedTasks):
    """q̇ = α Jᵀ v: the gradient (Jacobian transpose) law, a further baseline."""

    kind = "jt"
    solver = "none"

    def __init__(self, robot: Robot, primary: Sequence[Task], alpha: float = 1.0):
        super().__init__(robot, primary)
        if not (np.isfinite(alpha) and alpha > 0):
            raise InvalidInput(f"alpha must be positive, got {alpha}")
        self.alpha = float(alpha)
        self.qdot = np.zeros(robot.nv)

    def compute_velocity(self) -> np.ndarray:
        self.stack()
        np.matmul(self.J.T, self.v, out=self.qdot)
        self.qdot *= self.alpha
        return self.qdot
