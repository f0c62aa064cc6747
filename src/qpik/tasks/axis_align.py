"""Align a frame's axis with a target direction, in every world; the roll about the axis is left free."""

from __future__ import annotations

import numpy as np

from ..numerics import skew
from .look_at import FrameAxisTask, world_unit_vectors


class AxisAlignTask(FrameAxisTask):
    r"""Align a frame's axis :math:`a` (its own coordinates) with a world direction
    :math:`t` (a surface normal, gravity), as mink's ``AxisAlignTask``: a
    :class:`~qpik.tasks.look_at.LookAtTask` at a point at infinity, the roll about
    the axis left free (rank 2).

    With the frame's rotation R the target direction in the frame's axes is
    :math:`x = R^T t`, driven to :math:`x_d = a`, in every world:

    .. math::
        e = a - R^T t,\qquad
        J = \frac{\partial (R^T t)}{\partial q} = [R^T t]_\times J_\omega,

    :math:`J_\omega` the frame's angular Jacobian in its own axes (mink's J with the
    opposite sign). Only turning the frame changes the error. Degenerate when the axis
    is opposite the target (:math:`R^T t = -a`): ``lm_damping`` keeps the step bounded
    there. Three rows of rank 2: keep the task soft.

    Args:
        robot, frame, frame_type, axis: as for :class:`~qpik.tasks.look_at.LookAtTask`.
        gain, weight, hard, priority, lm_damping: as for :class:`~qpik.tasks.task.Task`.

    The target is the axis's current world direction at construction (met);
    :meth:`set_target` changes it.

    Raises:
        UnknownName, InvalidInput: as :class:`~qpik.tasks.look_at.LookAtTask` (the target
            here a direction: a zero or non-finite one is refused).
    """

    name = "axis-align task"

    def _start(self, robot) -> None:
        self.directions = np.matmul(self.frame.rotations, self.axis)  # (N, 3)
        self.direction = robot.present(self.directions)
        self._seen = np.zeros((robot.n, 3))  # x = Rᵀt

    def set_target(self, direction, velocity=None) -> None:
        """The world direction (3,) to align the axis with (normalised), or (N, 3) one per world.

        Raises:
            InvalidInput: a wrong shape, NaN, inf or zero (InvalidWorlds: in some worlds),
                or a feed-forward velocity.
        """
        self._no_velocity(velocity, "a direction")
        self.directions[...] = world_unit_vectors(self.robot, direction, f"{self.name} target direction")

    def _seen_directions(self, rotations: np.ndarray, out: np.ndarray) -> np.ndarray:
        """x = Rᵀt of every world (as the rows tᵀR), into ``out`` (N, 3)."""
        np.matmul(self.directions[:, None, :], rotations, out[:, None, :])
        return out

    def measured(self, robot=None) -> np.ndarray:
        """x = Rᵀt, the target direction in the frame's axes (a copy), on the bound robot
        or another robot of the same model and number of worlds."""
        robot, frame = self._frame_on(robot)
        return robot.present(self._seen_directions(frame.rotations, np.zeros((robot.n, 3))))

    def measure_rows(self) -> None:
        seen, axes = self._seen_directions(self.frame.rotations, self._seen), self._axes
        axes.update(linear=False)
        np.subtract(self.axis, seen, self.errors)
        np.matmul(skew(seen, self._skew), axes.angular, self.jacobians)
