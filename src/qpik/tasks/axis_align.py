"""Align a frame's axis with a target direction; the roll about the axis is left free."""

from __future__ import annotations

import numpy as np

from ..errors import InvalidInput
from ..robot import Robot
from .look_at import local_jacobians, skew, unit_axis
from .task import Task


class AxisAlignTask(Task):
    r"""Align a frame's axis :math:`a` (its own coordinates) with a world direction
    :math:`t` (a surface normal, gravity), as mink's ``AxisAlignTask``: a
    :class:`~qpik.tasks.look_at.LookAtTask` at a point at infinity, the roll about the
    axis left free (rank 2).

    With the frame's rotation R the target direction in the frame's axes is
    :math:`x = R^T t`, driven to :math:`x_d = a`:

    .. math::
        e = a - R^T t,\qquad
        J = \frac{\partial (R^T t)}{\partial q} = [R^T t]_\times J_\omega,

    :math:`J_\omega` the frame's angular Jacobian in its own axes (mink's J with the
    opposite sign). Only turning the frame changes the error. Degenerate when the axis
    is opposite the target (:math:`R^T t = -a`): ``lm_damping`` keeps the step bounded
    there. Three rows of rank 2: keep the task soft.

    Args:
        robot: the robot.
        frame: name of the site, body or geom.
        frame_type: ``"site"``, ``"body"`` or ``"geom"``.
        axis: the axis in the frame's own coordinates (normalised), default +z.
        gain, weight, hard, priority, lm_damping: as for :class:`~qpik.tasks.task.Task`.

    The target is the axis's current world direction at construction (met);
    :meth:`set_target` changes it.

    Raises:
        UnknownName: no frame of that type has this name.
        InvalidInput: a zero or non-finite axis or direction, a bad gain or weight.
    """

    name = "axis-align task"
    dim = 3

    def __init__(self, robot: Robot, frame: str, frame_type: str = "site", axis=(0.0, 0.0, 1.0), **options):
        super().__init__(robot, **options)
        self.frame = robot.frame(frame, frame_type)
        self.axis = unit_axis(axis, f"{self.name} axis")
        robot.ensure_kinematics()
        self.direction = self.frame.rotation @ self.axis

    def set_target(self, direction, velocity=None) -> None:
        """The world direction (3,) to align the axis with (normalised).

        Raises:
            InvalidInput: a wrong shape, NaN, inf or zero, or a feed-forward velocity.
        """
        if velocity is not None:
            raise InvalidInput(f"{self.name}: the target is a direction; it takes no velocity")
        self.direction = unit_axis(direction, f"{self.name} target direction")

    def measured(self, robot: Robot | None = None) -> np.ndarray:
        """x = Rᵀt, the target direction in the frame's axes."""
        return (robot or self.robot).frame_rotation(self.frame).T @ self.direction

    def compute_error(self, robot: Robot) -> np.ndarray:
        return self.axis - self.measured(robot)

    def compute_jacobian(self, robot: Robot) -> np.ndarray:
        rotation, _, jac_w = local_jacobians(robot, self.frame)
        return skew(rotation.T @ self.direction) @ jac_w

