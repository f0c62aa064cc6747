"""Orientation of a frame (site, body or geom) on selected world or local axes."""

from __future__ import annotations

import numpy as np

from ..robot import Robot
from .task import (
    PoseRows,
    Task,
    axis_rows,
    check_axes_frame,
    feedback_gain,
    target_vector,
    mocap_pose,
    rotation_matrix,
)


class OrientationTask(Task):
    r"""Track a frame's orientation on selected axes.

    .. math::
        J = S J_\omega,\qquad v = S\,\omega_d + K\,S\,e_o,\qquad \exp([e_o]_\times) R = R_d,

    with :math:`S` the rows of the mask ``axes`` and :math:`J_\omega` MuJoCo's rotational
    Jacobian of the frame. With ``axes_frame="local"`` the rows are the frame's own axes
    (:math:`S R^T`): e.g. ``axes="xy"`` there keeps the frame's z axis pointing where
    :math:`R_d`'s does while leaving the rotation about it free (to first order).

    Args:
        robot: the robot.
        frame: name of the site, body or geom.
        frame_type: ``"site"``, ``"body"`` (its origin) or ``"geom"``.
        axes: the rows kept, a subset of ``"xyz"``.
        gain: K (1/s), a scalar or one per row; default ``None``: dead-beat, 1/Δt of the
            controller the task is given to (K·Δt = 1, mink's default ``gain=1``).
        weight: cost weight of a soft task, a scalar or one per row.
        hard: enforce the rows as equalities in the QP.
        lm_damping: adaptive Levenberg–Marquardt weight μ (see :class:`~qpik.tasks.task.Task`).
        axes_frame: ``"world"`` or ``"local"`` (the frame's own axes).

    Raises:
        UnknownName: no frame of that type has this name (the closest are listed).
        InvalidInput: a bad gain, weight, mask or ``axes_frame``.
    """

    name = "orientation task"

    def __init__(self, robot: Robot, frame: str, frame_type: str = "site", axes: str = "xyz", gain=None, weight=1.0,
                 hard: bool = False, lm_damping: float = 0.0, axes_frame: str = "world"):
        self.rows = axis_rows(axes)
        self.axes_frame = axes_frame
        local = check_axes_frame(axes_frame)
        super().__init__(robot, len(self.rows), weight, hard, lm_damping=lm_damping)
        self.frame = robot.frame(frame, frame_type)
        self._use_gain(feedback_gain(gain, self.dim, "orientation gain"))
        self.target_rotation = self.frame.rotation.copy()
        self.target_angular_velocity = np.zeros(3)
        self._pose_rows = PoseRows(self.frame, robot.nv, None, self.rows, local)
        self._feedforward = np.zeros(self.dim)

    def set_target(self, rotation, angular_velocity=None) -> None:
        """Desired world rotation (a 3x3 matrix or a w-x-y-z unit quaternion) and
        feed-forward angular velocity (world axes).

        Raises:
            InvalidInput: a matrix that is no rotation, a wrong shape, NaN or inf.
        """
        self.target_rotation[:] = rotation_matrix(rotation)
        self.target_angular_velocity[:] = (0.0 if angular_velocity is None
                                           else target_vector(angular_velocity, 3, "target angular velocity"))

    def set_target_from_configuration(self) -> None:
        """Desired rotation: the frame's at the robot's current configuration."""
        self.robot.ensure_kinematics()
        self.set_target(self.frame.rotation)

    def set_target_from_mocap(self, body: str) -> None:
        """Desired rotation: a mocap body's (``data.mocap_quat``), read now.

        Raises:
            UnknownName: no body of that name.
            InvalidInput: the body is not a mocap body.
        """
        self.set_target(mocap_pose(self.robot, body)[1])

    def update(self) -> None:
        self._pose_rows.jacobian(self.jacobian)
        self.update_target_velocity()

    def update_target_velocity(self) -> None:
        """Error and v only (what a law without the Jacobian needs)."""
        self._pose_rows.errors(None, self.target_rotation, None, self.target_angular_velocity, self.error,
                               self._feedforward)
        self._track(self._feedforward)
