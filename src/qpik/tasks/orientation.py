"""Orientation of a frame (site, body or geom) on selected world or local axes."""

from __future__ import annotations

import numpy as np

from .inputs import mocap_pose, world_rotations, world_values
from .pose import MaskedFrameTask


class OrientationTask(MaskedFrameTask):
    r"""Track a frame's orientation on selected axes.

    .. math::
        J = S J_\omega,\qquad v = S\,\omega_d + K\,S\,e_o,\qquad \exp([e_o]_\times) R = R_d,

    with :math:`S` the rows of the mask ``axes`` and :math:`J_\omega` MuJoCo's rotational
    Jacobian of the frame. With ``axes_frame="local"`` the rows are the frame's own axes
    (:math:`S R^T`): e.g. ``axes="xy"`` there keeps the frame's z axis pointing where
    :math:`R_d`'s does while leaving the rotation about it free (to first order).

    Args:
        robot, frame, frame_type, axes, axes_frame: as for :class:`~qpik.PositionTask`.
        gain, weight, hard, lm_damping: K, dead-beat by default, and the rest as for
            :class:`~qpik.tasks.task.Task`.

    Raises:
        UnknownName: no frame of that type has this name (the closest are listed).
        InvalidInput: a bad gain, weight, mask or ``axes_frame``.
    """

    name = "orientation task"
    block = "orientation"

    def _start(self, robot) -> None:
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
