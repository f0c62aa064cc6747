"""Kinetic-energy regularisation: ½ λ q̇ᵀ M(q) q̇, in every world."""

from __future__ import annotations

import numpy as np

from ..errors import InvalidInput
from .task import Task


class KineticEnergyRegularizationTask(Task):
    r"""Penalise the kinetic energy of the step, :math:`\tfrac12 \lambda\, \dot q^T M(q) \dot q`
    (mink's ``KineticEnergyRegularizationTask``): an inertia-weighted
    :class:`~qpik.tasks.damping.DampingTask`, under which heavy dofs move less.

    As rows :math:`J\dot q \approx 0` with weight λ: :math:`J = U`, the Cholesky factor
    :math:`M = U^T U` of the joint-space inertia matrix (the robot's :meth:`mass_matrix`:
    ``mj_crb`` and ``mj_fullM``, armature included; on N worlds MuJoCo's C world by world
    unless the back-end batches it), so :math:`\|J\dot q\|^2 = \dot q^T M \dot q`. A
    world whose M is only semidefinite (a massless dof) takes
    :math:`J = \Lambda^{1/2} V^T` of its eigendecomposition instead. qpik's variable is q̇
    itself, so no :math:`1/\Delta t^2` scaling is needed (mink's variable is Δq): λ = 1
    weighs the cost in joules. Light dofs are nearly free under it: pair it with a small
    damping task.

    Args:
        robot: the robot (one world or N).
        weight: λ, a number >= 0.
        priority: its level in a strict hierarchy (0 the highest).

    Raises:
        InvalidInput: a bad weight; ``hard=True`` (it would hold the robot still).
    """

    name = "kinetic-energy regularization task"

    def __init__(self, robot, weight: float = 1e-3, priority: int = 0, hard: bool = False):
        if hard:
            raise InvalidInput(f"{self.name} is a cost: a hard one would hold every dof still")
        if np.ndim(weight) != 0:
            raise InvalidInput(f"{self.name} weight must be one number, got {weight!r}")
        super().__init__(robot, robot.nv, weight, gain=0.0, priority=priority)
        self._inertia = np.zeros((robot.n, robot.nv, robot.nv))

    def measure_rows(self) -> None:
        """J = U of M = UᵀU in every world (e stays zero)."""
        inertia = self.robot.mass_matrix(self._inertia)
        try:
            factor = np.linalg.cholesky(inertia)  # L = Uᵀ
        except np.linalg.LinAlgError:  # a massless dof somewhere: M only semidefinite there
            self._factor_each(inertia)
            return
        np.copyto(self.jacobians, factor.transpose(0, 2, 1))

    def _factor_each(self, inertia: np.ndarray) -> None:
        for w, matrix in enumerate(inertia):
            try:
                self.jacobians[w] = np.linalg.cholesky(matrix).T
            except np.linalg.LinAlgError:
                values, vectors = np.linalg.eigh(matrix)
                self.jacobians[w] = np.sqrt(np.clip(values, 0.0, None))[:, None] * vectors.T

    def track(self) -> None:
        """v = 0: a cost on the step alone."""
