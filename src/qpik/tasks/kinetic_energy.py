"""Kinetic-energy regularisation: ½ λ q̇ᵀ M(q) q̇."""

from __future__ import annotations

import mujoco
import numpy as np

from ..errors import InvalidInput
from ..robot import Robot
from .task import Task


class KineticEnergyRegularizationTask(Task):
    r"""Penalise the kinetic energy of the step, :math:`\tfrac12 \lambda\, \dot q^T M(q) \dot q`
    (mink's ``KineticEnergyRegularizationTask``): an inertia-weighted
    :class:`~qpik.tasks.damping.DampingTask`, under which heavy dofs move less.

    As rows :math:`J\dot q \approx 0` with weight λ: :math:`J = U`, the Cholesky factor
    :math:`M = U^T U` of the joint-space inertia matrix (``mj_fullM``, armature
    included), so :math:`\|J\dot q\|^2 = \dot q^T M \dot q`. qpik's variable is q̇ itself,
    so no :math:`1/\Delta t^2` scaling is needed (mink's variable is Δq): λ = 1 weighs
    the cost in joules. With a hard task and nothing else in the cost the step is the
    inertia-weighted minimum-norm solution :math:`M^{-1}J^T (J M^{-1} J^T)^{-1} v`.
    Light dofs are nearly free under it: pair it with a small damping task.

    Args:
        robot: the robot.
        weight: λ, a number >= 0.
        priority: its level in a strict hierarchy (0 the highest).

    Raises:
        InvalidInput: a bad weight; ``hard=True`` (it would hold the robot still).
    """

    name = "kinetic-energy regularization task"

    def __init__(self, robot: Robot, weight: float = 1e-3, priority: int = 0, hard: bool = False):
        if hard:
            raise InvalidInput(f"{self.name} is a cost: a hard one would hold every dof still")
        if np.ndim(weight) != 0:
            raise InvalidInput(f"{self.name} weight must be one number, got {weight!r}")
        super().__init__(robot, robot.nv, weight, gain=0.0, priority=priority)
        self._inertia = np.zeros((robot.nv, robot.nv))
        self._zero = np.zeros(robot.nv)

    def compute_error(self, robot: Robot) -> np.ndarray:
        return self._zero

    def compute_jacobian(self, robot: Robot) -> np.ndarray:
        mujoco.mj_crb(robot.model, robot.data)  # M at q (the kinematics are current)
        mujoco.mj_fullM(robot.model, robot.data, self._inertia)
        try:
            return np.linalg.cholesky(self._inertia).T
        except np.linalg.LinAlgError:  # a massless dof: M only semidefinite
            values, vectors = np.linalg.eigh(self._inertia)
            return np.sqrt(np.clip(values, 0.0, None))[:, None] * vectors.T
