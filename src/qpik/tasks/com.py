"""Centre of mass of the whole model or of a body's subtree, in every world."""

from __future__ import annotations

import numpy as np

from ..errors import ModelError
from .inputs import as_index, axis_rows, feedback_gain
from .task import Task


class ComTask(Task):
    r"""Track the centre of mass c of the whole model, or of the subtree of one body.

    .. math::
        J = S\,\frac{\partial c}{\partial q},\qquad v = S\,\dot c_d + K\,S (c_d - c),

    with :math:`S` the world rows of the mask ``axes`` (e.g. ``"xy"`` to keep the CoM
    above a support polygon), c MuJoCo's ``subtree_com`` and its Jacobian
    ``mj_jacSubtreeCom`` (the robot's :meth:`subtree_com` and :meth:`com_jacobian`, every
    world's).

    Args:
        robot: the robot (one world or N).
        subtree: a body name: the CoM of that body and its descendants (default: the
            whole model, the world body's subtree).
        axes: the world rows kept, a subset of ``"xyz"``.
        gain, weight, hard, lm_damping: K, dead-beat by default, and the rest as for
            :class:`~qpik.tasks.task.Task`.

    Raises:
        UnknownName: ``subtree`` names no body (the closest are listed).
        ModelError: the subtree has no mass.
        InvalidInput: a bad gain, weight or mask.

    The target is the CoM when the task is built; :meth:`set_target` moves it (one for
    every world, or one per world).
    """

    name = "CoM task"

    def __init__(self, robot, gain=None, weight=1.0, subtree: str | None = None, axes: str = "xyz",
                 hard: bool = False, lm_damping: float = 0.0):
        self.rows = axis_rows(axes)
        self.body = 0 if subtree is None else robot.body_id(subtree)
        if not robot.model.body_subtreemass[self.body] > 0:
            what = "the model" if subtree is None else f"the subtree of body {subtree!r}"
            raise ModelError(f"{self.name}: {what} has no mass, so no centre of mass")
        self._rows = as_index(self.rows)
        self._jacp = np.zeros((robot.n, 3, robot.nv))  # ∂c/∂q, every row
        self.com = robot.subtree_com(self.body)  # (N, 3) view, refreshed by every kinematics update
        super().__init__(robot, len(self.rows), weight, hard, lm_damping=lm_damping)
        self.set_gain(feedback_gain(gain, self.dim, "CoM gain"))
        self.targets = np.array(self.com[:, self._rows])  # (N, dim)
        self.target = robot.present(self.targets)

    def _allocate_jacobians(self) -> None:
        # Consecutive rows: a view of the whole Jacobian, no copy per step.
        rows = self._rows
        self.jacobians = self._jacp[:, rows] if isinstance(rows, slice) else \
            np.zeros((self.robot.n, len(rows), self.robot.nv))

    def set_target(self, position, velocity=None) -> None:
        """Desired CoM and its feed-forward velocity, on the masked world axes (``len(axes)``
        each, or (N, len(axes)) one per world).

        Raises:
            InvalidInput: a wrong shape, NaN or inf, or a target so far away that the
                feedback K·e would overflow (InvalidWorlds: in some worlds).
        """
        super().set_target(position, velocity)  # into ``target``, a view of ``targets``

    def set_target_from_configuration(self) -> None:
        """Desired CoM: the CoM at the current configuration, in every world."""
        self.robot.ensure_kinematics()
        self.set_target(self.robot.present(self.com[:, self._rows]))

    def measured(self, robot=None) -> np.ndarray:
        """The CoM on the masked axes (a copy) as a user reads it, on the bound robot or
        another robot of the same model (after its kinematics update)."""
        robot = robot or self.robot
        return robot.present(robot.subtree_com(self.body)[:, self.rows])

    def measure_rows(self) -> None:
        self.robot.com_jacobian(self.body, self._jacp)
        rows = self._rows
        if not isinstance(rows, slice):
            np.take(self._jacp, rows, 1, self.jacobians)
        np.subtract(self.targets, self.com[:, rows], self.errors)
