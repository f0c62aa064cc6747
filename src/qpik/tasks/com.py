"""Centre of mass of the whole model or of a body's subtree."""

from __future__ import annotations

import mujoco
import numpy as np

from ..errors import ModelError
from ..robot import Robot
from .task import PointTarget, Task, axis_rows, feedback_gain


class ComTask(Task):
    r"""Track the centre of mass c of the whole model, or of the subtree of one body.

    .. math::
        J = S\,\frac{\partial c}{\partial q},\qquad v = S\,\dot c_d + K\,S (c_d - c),

    with :math:`S` the world rows of the mask ``axes`` (e.g. ``"xy"`` to keep the CoM
    above a support polygon), c MuJoCo's ``subtree_com`` and its Jacobian
    ``mj_jacSubtreeCom``.

    Args:
        robot: the robot.
        gain: K (1/s), a scalar or one per row; default ``None``: dead-beat, 1/Δt of the
            controller the task is given to (K·Δt = 1, mink's default ``gain=1``).
        weight: cost weight of a soft task, a scalar or one per row.
        subtree: a body name: the CoM of that body and its descendants (default: the
            whole model, the world body's subtree).
        axes: the world rows kept, a subset of ``"xyz"``.
        hard: enforce the rows as equalities in the QP.
        lm_damping: adaptive Levenberg–Marquardt weight μ (see :class:`~qpik.tasks.task.Task`).

    Raises:
        UnknownName: ``subtree`` names no body (the closest are listed).
        ModelError: the subtree has no mass.
        InvalidInput: a bad gain, weight or mask.

    The target is the CoM when the task is built; :meth:`set_target` moves it.
    """

    name = "CoM task"

    def __init__(self, robot: Robot, gain=None, weight=1.0, subtree: str | None = None, axes: str = "xyz",
                 hard: bool = False, lm_damping: float = 0.0):
        self.rows = axis_rows(axes)
        super().__init__(robot, len(self.rows), weight, hard, lm_damping=lm_damping)
        self.body = 0 if subtree is None else robot.body_id(subtree)
        if not robot.model.body_subtreemass[self.body] > 0:
            what = "the model" if subtree is None else f"the subtree of body {subtree!r}"
            raise ModelError(f"{self.name}: {what} has no mass, so no centre of mass")
        self._use_gain(feedback_gain(gain, self.dim, "CoM gain"))
        self.com = robot.data.subtree_com[self.body]  # a view, refreshed by every kinematics update
        self._jacp = np.zeros((3, robot.nv))
        self._goal = PointTarget(self.com[self.rows], "target CoM", "target CoM velocity")
        self.target, self.target_rate = self._goal.target, self._goal.rate
        self._masked = np.zeros(self.dim)

    @property
    def target_dim(self) -> int:
        """Length of a target: ``len(axes)``."""
        return self.dim

    def set_target(self, position, velocity=None) -> None:
        """Desired CoM and its feed-forward velocity, on the masked world axes.

        Raises:
            InvalidInput: a wrong length, NaN or inf, or a target so far away that the
                feedback K·e would overflow.
        """
        self._goal.set(position, velocity)  # checked: K·e stays finite

    def set_target_from_configuration(self) -> None:
        """Desired CoM: the CoM at the robot's current configuration."""
        self.robot.ensure_kinematics()
        self.set_target(self.measured())

    def measured(self, robot: Robot | None = None) -> np.ndarray:
        """The CoM on the masked axes (a copy), on the bound robot or another of the same model
        (valid after its kinematics update)."""
        return (robot or self.robot).data.subtree_com[self.body][self.rows]

    def update(self) -> None:
        mujoco.mj_jacSubtreeCom(self.robot.model, self.robot.data, self._jacp, self.body)
        self._jacp.take(self.rows, 0, self.jacobian)
        self.update_target_velocity()

    def update_target_velocity(self) -> None:
        """Error and v only (what a law without the Jacobian needs)."""
        np.subtract(self.target, self.com.take(self.rows, None, self._masked), self.error)
        self._track(self.target_rate)
