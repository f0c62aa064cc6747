"""Pose of a frame in another frame's coordinates."""

from __future__ import annotations

import numpy as np

from ..errors import InvalidInput
from ..robot import Robot
from .task import RotationError, Task, feedback_gain, homogeneous_transform, rotation_matrix, target_vector


class RelativeFrameTask(Task):
    r"""Track the pose of ``frame`` in the coordinates of ``root`` (both move).

    With :math:`d = p_f - p_r`, the relative pose is :math:`p = R_r^T d`,
    :math:`R = R_r^T R_f`, and its time derivative, in root coordinates,

    .. math::
        \dot p = R_r^T\,(J_{p,f} - J_{p,r} + [d]_\times J_{\omega,r})\,\dot q,\qquad
        \omega = R_r^T\,(J_{\omega,f} - J_{\omega,r})\,\dot q,

    the task's two 3-row blocks. As for :class:`~qpik.tasks.FrameTask`,
    :math:`v = [\dot p_d + K_p (p_d - p);\ \omega_d + K_o e_o]` with
    :math:`\exp([e_o]_\times) R = R_d`, all in root coordinates. With ``root`` the world
    body this is the FrameTask. mink's RelativeFrameTask regulates the same pose.

    Args:
        robot: the robot.
        frame: name of the tracked site, body or geom.
        root: name of the site, body or geom whose coordinates the pose is taken in.
        frame_type: type of ``frame``: ``"site"``, ``"body"`` or ``"geom"``.
        root_type: type of ``root``.
        position_gain: :math:`K_p` (1/s), a scalar or one per axis; default ``None``:
            dead-beat, 1/Δt of the controller the task is given to (K·Δt = 1).
        orientation_gain: :math:`K_o` (1/s), a scalar or one per axis; default dead-beat.
        weight: cost weight of a soft task, a scalar or one per row (6).
        hard: enforce the rows as equalities in the QP.
        lm_damping: adaptive Levenberg–Marquardt weight μ (see :class:`~qpik.tasks.task.Task`).

    Raises:
        UnknownName: a frame name unknown for its type (the closest are listed).
        InvalidInput: a bad gain or weight, or ``frame`` and ``root`` the same frame.

    The target is the relative pose when the task is built; :meth:`set_target` moves it.
    """

    name = "relative frame task"

    def __init__(self, robot: Robot, frame: str, root: str, frame_type: str = "site", root_type: str = "site",
                 position_gain=None, orientation_gain=None, weight=1.0, hard: bool = False, lm_damping: float = 0.0):
        super().__init__(robot, 6, weight, hard, lm_damping=lm_damping)
        self.frame = robot.frame(frame, frame_type)
        self.root = robot.frame(root, root_type)
        if (self.frame.type, self.frame.id) == (self.root.type, self.root.id):
            raise InvalidInput(f"{self.name}: frame and root are the same {frame_type} {frame!r}")
        self._use_gain(np.concatenate([feedback_gain(position_gain, 3, "position gain"),
                                       feedback_gain(orientation_gain, 3, "orientation gain")]))
        self.position_gain, self.orientation_gain = self.gain[:3], self.gain[3:]
        nv = robot.nv
        self._jac_frame, self._jac_root = np.zeros((6, nv)), np.zeros((6, nv))
        self._moved = np.zeros((3, nv))
        self._row = np.zeros(nv)
        self._offset = np.zeros(3)
        self.position = np.zeros(3)  # the relative pose, refreshed by every update
        self.rotation = np.zeros((3, 3))
        self._relative_pose()
        self.target_position = self.position.copy()
        self.target_rotation = self.rotation.copy()
        self._twist = np.zeros(6)
        self.target_linear_velocity, self.target_angular_velocity = self._twist[:3], self._twist[3:]
        self.position_error = self.error[:3]
        self.orientation_error = self.error[3:]
        self._rotation_error = RotationError()

    def _relative_pose(self) -> None:
        np.subtract(self.frame.position, self.root.position, out=self._offset)
        self._offset.dot(self.root.rotation, self.position)  # dᵀR_r = (R_rᵀd)ᵀ
        self.root.rotation.T.dot(self.frame.rotation, self.rotation)

    def set_target(self, position, rotation, linear_velocity=None, angular_velocity=None) -> None:
        """Desired pose of ``frame`` in ``root`` coordinates (``rotation`` a 3x3 matrix or
        a w-x-y-z unit quaternion), and its feed-forward twist (root coordinates).

        Raises:
            InvalidInput: a wrong shape, NaN/inf, or a matrix that is no rotation.
        """
        self.target_position[:] = target_vector(position, 3, "target position")
        self.target_rotation[:] = rotation_matrix(rotation)
        self.target_linear_velocity[:] = 0.0 if linear_velocity is None else target_vector(linear_velocity, 3, "target linear velocity")
        self.target_angular_velocity[:] = 0.0 if angular_velocity is None else target_vector(angular_velocity, 3, "target angular velocity")

    def set_target_transform(self, transform, linear_velocity=None, angular_velocity=None) -> None:
        """Desired pose in ``root`` coordinates as a homogeneous 4x4 transform."""
        position, rotation = homogeneous_transform(transform)
        self.set_target(position, rotation, linear_velocity, angular_velocity)

    def set_target_from_configuration(self) -> None:
        """Desired pose: the relative pose at the robot's current configuration."""
        self.robot.ensure_kinematics()
        self._relative_pose()
        self.set_target(self.position, self.rotation)

    def update(self) -> None:
        jf, jr, moved = self._jac_frame, self._jac_root, self._moved
        self.frame.jacobian(jf[:3], jf[3:])
        self.root.jacobian(jr[:3], jr[3:])
        self._relative_pose()
        d, wr, row = self._offset, jr[3:], self._row
        # J_pf − J_pr + d × (each column of J_ωr), the cross product written out per row.
        np.subtract(jf[:3], jr[:3], out=moved)
        for i, j, k in ((0, 1, 2), (1, 2, 0), (2, 0, 1)):
            moved[i] += np.multiply(d[j], wr[k], out=row)
            moved[i] -= np.multiply(d[k], wr[j], out=row)
        Rt = self.root.rotation.T
        Rt.dot(moved, self.jacobian[:3])
        np.subtract(jf[3:], wr, out=moved)
        Rt.dot(moved, self.jacobian[3:])
        self._errors()

    def update_target_velocity(self) -> None:
        """Errors and v only (what a law without the Jacobian needs)."""
        self._relative_pose()
        self._errors()

    def _errors(self) -> None:
        np.subtract(self.target_position, self.position, out=self.position_error)
        self._rotation_error.world(self.target_rotation, self.rotation, out=self.orientation_error)
        self._track(self._twist)
