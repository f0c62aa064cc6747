"""Orientation of a frame (site, body or geom) on selected world or local axes."""

from __future__ import annotations

import numpy as np

from .inputs import axis_rows, check_axes_frame, feedback_gain, mocap_pose, world_rotations, world_values
from .pose import PoseRows
from .task import Task


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

    def __init__(self, robot, frame: str, frame_type: str = "site", axes: str = "xyz", gain=None, weight=1.0,
                 hard: bool = False, lm_damping: float = 0.0, axes_frame: str = "world"):
        self.rows = axis_rows(axes)
        self.axes_frame = axes_frame
        local = check_axes_frame(axes_frame)
        self.frame = robot.frame(frame, frame_type)
        self._pose = PoseRows(robot, self.frame, None, self.rows, local)
        super().__init__(robot, len(self.rows), weight, hard, lm_damping=lm_damping)
        self.set_gain(feedback_gain(gain, self.dim, "orientation gain"))
        self.target_rotations = np.array(self.frame.rotations)
        self.target_angular_velocities = np.zeros((robot.n, 3))
        self.target_rotation = robot.present(self.target_rotations)
        self.target_angular_velocity = robot.present(self.target_angular_velocities)

    def set_target(self, rotation, angular_velocity=None) -> None:
        """Desired world rotation (a 3x3 matrix or a w-x-y-z unit quaternion; or one per
        world) and feed-forward angular velocity (world axes).

        Raises:
            InvalidInput: a matrix that is no rotation, a wrong shape, NaN or inf.
        """
        rotation = world_rotations(self.robot, rotation)
        angular = 0.0 if angular_velocity is None else world_values(self.robot, angular_velocity, (3,),
                                                                    "target angular velocity")
        self.target_rotations[...] = rotation
        self.target_angular_velocities[...] = angular

    def set_target_from_configuration(self) -> None:
        """Desired rotation: the frame's at the current configuration, in every world."""
        self.robot.ensure_kinematics()
        self.set_target(self.robot.present(self.frame.rotations))

    def set_target_from_mocap(self, body: str) -> None:
        """Desired rotation: a mocap body's (``data.mocap_quat``), read now (one world)."""
        self.set_target(mocap_pose(self.robot, body)[1])

    def measure_rows(self) -> None:
        self._pose.write(self, None, self.target_rotations, None, self.target_angular_velocities)
